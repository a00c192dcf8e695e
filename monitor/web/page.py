"""The page: the 3-D view, the timeline (scrub and play), the program listing with the
current line (click a line to go there), the findings (click to jump) and, for a running
job, the machine's state, position, line and the next predicted finding.

Everything here runs on the trame server's thread.
"""

from __future__ import annotations

import asyncio
import math
import threading
from pathlib import Path

import numpy as np

#: playback: pictures a second, and at most this many pictures from the first stage to the last
PLAY_FPS = 10.0
PLAY_PICTURES = 200

#: the page's own style sheet (served from this package, nothing from outside)
STATIC = Path(__file__).resolve().parent / "static"


class Page:
    """The page of one trame ``server`` on one :class:`monitor.web.scene.Scene`.

    ``model`` (:class:`monitor.web.runmodel.RunModel`) gives the stages of a recorded run
    and the timeline over them; a running job has none (the page shows
    :meth:`update_live`'s figures) until its run file is loaded (:meth:`load_run`).
    """

    def __init__(self, server, scene, title: str, model=None, program_lines: list[str] | None = None):
        self.server = server
        self.scene = scene
        self.model = model
        self.program_lines = program_lines if program_lines is not None else (model.program_lines if model else [])
        self._play_task = None   # kept: the loop holds only a weak reference to a task
        self._live_line = None
        #: a running job's model as last given (heights, tip, row): shown again when the
        #: user goes back to the machine from a finding's stage
        self._live_picture = None
        #: a running job: ``stage_of(finding record) -> (heights, tip, row, stage) or a
        #: sentence saying why its stage cannot be shown`` (set by the live feed)
        self.live_stage = None
        #: set when a page has opened in a browser
        self.opened = threading.Event()
        server.enable_module({"serve": {"dexmon": str(STATIC)}, "styles": ["dexmon/page.css"]})
        state = server.state
        state.update({"title": title, "has_run": False, "first": 0, "last": 0, "stage": 0, "playing": False,
                      "stage_text": "", "listing": [], "findings": [], "at_finding": -1, "live": None,
                      "finding_note": "", "pinned": False})
        state.change("stage")(self._on_stage)
        self.view = self._layout()
        if model is not None:
            self.load_run(model)

    # -- the layout
    def _layout(self):
        from trame.ui.vuetify3 import SinglePageLayout
        from trame.widgets import client, html
        from trame.widgets import vtk as vtk_widgets
        from trame.widgets import vuetify3 as v3

        with SinglePageLayout(self.server, full_height=True) as layout:
            layout.title.set_text(self.server.state.title)
            layout.icon.hide()
            client.ClientTriggers(mounted=lambda *_, **__: self.opened.set())
            with layout.content:
                with v3.VContainer(fluid=True, classes="pa-2"):
                    with v3.VRow(dense=True):
                        with v3.VCol(cols=8):
                            self._live_panel(html, v3)
                            with html.Div(id="view", style="height: 68vh; position: relative;"):
                                view = vtk_widgets.VtkRemoteView(self.scene.render_window, ref="view",
                                                                 interactive_ratio=0.5, still_quality=90)
                            self._timeline(html, v3)
                        with v3.VCol(cols=4):
                            self._findings_panel(html, v3)
                            self._listing_panel(html, v3)
        self.layout = layout
        return view

    def _live_panel(self, html, v3):
        with v3.VCard(v_if=("live",), id="live", classes="mb-2 pa-2 dexmon-live", variant="outlined"):
            html.Div("{{ live.state }} · line {{ live.line }} · work X {{ live.x }} Y {{ live.y }} Z {{ live.z }} mm"
                     " · {{ live.findings }} finding(s)",
                     id="live-status")
            html.Div("{{ live.next || 'no finding predicted ahead' }}", id="live-next")
            html.Div("{{ live.note }}", id="live-note", v_if=("live.note",))

    def _timeline(self, html, v3):
        with html.Div(v_if=("has_run",), classes="d-flex align-center mt-1", id="timeline"):
            v3.VBtn("{{ playing ? 'Pause' : 'Play' }}", id="play", click=self.toggle_play, size="small",
                    classes="mr-3")
            v3.VSlider(v_model=("stage",), min=("first",), max=("last",), step=1, hide_details=True,
                       id="stage-slider", classes="flex-grow-1")
        html.Div("{{ stage_text }}", id="stage-text", classes="text-body-2 mt-1")

    def _findings_panel(self, html, v3):
        with v3.VCard(classes="mb-2", variant="outlined"):
            v3.VCardTitle("Findings ({{ findings.length }})", classes="text-subtitle-1")
            with html.Div(id="findings", style="max-height: 28vh; overflow: auto;"):
                html.Div("{{ f.text }}", v_for="f in findings", key="f.i", id=("'finding-' + f.i",),
                         classes=("'dexmon-finding' + (f.i === at_finding ? ' at' : '')",),
                         click=(self.go_finding, "[f.i]"))
                html.Div("no findings", v_if=("!findings.length",), classes="pa-2")
            with html.Div(v_if=("finding_note",), classes="pa-2 text-body-2 dexmon-note"):
                html.Span("{{ finding_note }}", id="finding-note")
                v3.VBtn("Back to the machine", v_if=("pinned",), id="live-back", click=self.back_to_machine,
                        size="small", classes="ml-2")

    def _listing_panel(self, html, v3):
        with v3.VCard(variant="outlined"):
            v3.VCardTitle("Program", classes="text-subtitle-1")
            with html.Div(id="listing", classes="dexmon-listing", style="max-height: 40vh;"):
                html.Div("{{ String(l.n).padStart(5) }}  {{ l.text }}", v_for="l in listing", key="l.n",
                         id=("'line-' + l.n",), classes=("l.current ? 'line current-line' : 'line'",),
                         click=(self.go_line, "[l.n]"))

    # -- a recorded run
    def load_run(self, model) -> None:
        """Show ``model``'s run: timeline over its stages, its findings, the last stage."""
        self.model = model
        self.program_lines = model.program_lines
        with self.server.state as state:
            state.update({"has_run": True, "first": model.first, "last": model.last,
                          "findings": model.findings, "finding_note": "", "pinned": False})
            state.stage = model.last
        self._on_stage(model.last)

    def _on_stage(self, stage=None, **_):
        if self.model is None or stage is None:
            return
        stage = min(max(int(stage), self.model.first), self.model.last)
        row = self.model.at(stage)
        self.scene.show(self.model.heights(stage), row.tip, self.model.row(stage))
        state = self.server.state
        state.stage_text = stage_text(stage, self.model.last, row.line, row.t)
        state.listing = self.model.listing_around(row.line)
        state.at_finding = next((f["i"] for f in self.model.findings if f["stage"] == stage), -1)
        self.push_picture()

    def push_picture(self) -> None:
        """Send the scene's picture to the page."""
        self.view.update()

    def go_line(self, line) -> None:
        """The first stage cut on ``line`` (or after it); the listing still moves to the line."""
        if self.model is None:
            self.server.state.listing = _listing(self.program_lines, int(line))
            return
        stage = self.model.stage_of_line(int(line))
        if stage is not None:
            self.server.state.stage = stage
        self.server.state.listing = _listing(self.program_lines, int(line))

    def go_finding(self, i) -> None:
        """The stage at which finding ``i`` happened (a running job: its line in the
        listing and, when the run file holds it, its stage, else why not)."""
        if self.model is None:
            self._go_live_finding(int(i))
            return
        f = self.model.findings[int(i)]
        if f["stage"] is not None:
            self.server.state.stage = f["stage"]

    def toggle_play(self) -> None:
        state = self.server.state
        if state.playing:
            state.playing = False
            return
        if self.model is None:
            return
        state.playing = True
        if int(state.stage) >= self.model.last:
            state.stage = self.model.first
        self._play_task = asyncio.ensure_future(self._play())

    async def _play(self) -> None:
        state = self.server.state
        step = max(1, math.ceil((self.model.last - self.model.first) / PLAY_PICTURES))
        while state.playing and int(state.stage) < self.model.last:
            with state:
                state.stage = min(int(state.stage) + step, self.model.last)
            await asyncio.sleep(1.0 / PLAY_FPS)
        with state:
            state.playing = False

    # -- a running job
    def _go_live_finding(self, i: int) -> None:
        """Finding ``i`` of a running job: its line in the listing, and the model at the
        stage it happened (the live picture held until :meth:`back_to_machine`) when the
        run file holds that stage; else a sentence on the page says why not."""
        state = self.server.state
        f = state.findings[i]
        state.at_finding = i
        if isinstance(f.get("line"), int):
            state.listing = _listing(self.program_lines, f["line"])
        shown = self.live_stage(f) if self.live_stage is not None else "this job is not recorded: no stages to show"
        if isinstance(shown, str):
            state.finding_note = f"Finding {i + 1}: {shown}."
            return
        heights, tip, row, stage = shown
        state.pinned = True
        state.finding_note = (f"Showing stage {stage}, where finding {i + 1} happened; "
                              "the machine goes on (the status above is live).")
        self.scene.show(heights, tip, row)
        self.push_picture()

    def back_to_machine(self) -> None:
        """Leave a finding's stage: the running machine's model again."""
        state = self.server.state
        state.pinned, state.finding_note, state.at_finding = False, "", -1
        if self._live_picture is not None:
            self.scene.show(*self._live_picture)
            self.push_picture()

    def update_live(self, figures: dict, heights=None, tip=None, findings: list | None = None,
                    row: int | None = None) -> None:
        """Show a running machine: ``figures`` (state, line, x, y, z, next, note), the
        model's ``heights`` and the tool at ``tip`` (None: unchanged) with the path round
        program ``row``, ``findings`` (raw finding records) when they changed."""
        with self.server.state as state:
            state.live = figures
            line = figures.get("line")
            if isinstance(line, int) and line > 0 and line != self._live_line:
                # only when the machine's line changes: a line the user went to stays shown
                self._live_line = line
                state.listing = _listing(self.program_lines, line)
            if findings is not None:
                from monitor.web.runmodel import finding_item

                state.findings = [finding_item(i, f) for i, f in enumerate(findings)]
                shown = [f for f in state.findings if f["position"] is not None]
                self.scene.set_findings([f["position"] for f in shown], [f["label"] for f in shown])
        if heights is not None:
            self._live_picture = (heights, tip, row)
            if not self.server.state.pinned:   # a finding's stage stays until the user leaves it
                self.scene.show(heights, tip, row)
                self.push_picture()


def _listing(lines: list[str], line: int) -> list[dict]:
    from monitor.web.runmodel import listing_window

    return listing_window(lines, line)


def stage_text(stage: int, last: int, line: int, t: float) -> str:
    """``stage 12 / 45 · line 22 · t 19.0 s`` (what is known of them)."""
    parts = [f"stage {stage} / {last}"]
    if line > 0:
        parts.append(f"line {line}")
    if np.isfinite(t):
        parts.append(f"t {t:.1f} s")
    return " · ".join(parts)
