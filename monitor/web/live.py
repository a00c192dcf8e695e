"""A running job on the page: the session posts what each state changed (as it does to the
live window, :meth:`monitor.session.Session.attach_view`), the page's thread draws it at
most ``fps`` times a second with the machine's state, position, line and the next
predicted finding with its countdown; when the run ends the page turns into the view of
its run file (timeline, findings)."""

from __future__ import annotations

import asyncio
import threading

import numpy as np

#: pictures a second at most while the machine runs
LIVE_FPS = 5.0


class LiveFeed:
    """Feeds ``session``'s live model to ``app`` (a :class:`monitor.web.app.WebApp`).

    :meth:`post` runs on the session loop's thread and costs a lock and two appends; the
    page's thread applies the posted ray tops to its own copy of the heights, so it never
    reads the model the loop is cutting.
    """

    def __init__(self, session, app, fps: float = LIVE_FPS):
        self.session = session
        self.app = app
        self.period = 1.0 / float(fps)
        self.heights = np.array(session.live.top(), np.float32).reshape(-1)
        self._lock = threading.Lock()
        self._rays: list[np.ndarray] = []
        self._tops: list[np.ndarray] = []
        self._tip = None
        self._posted = self._drawn = 0
        self._shown_findings = None   # (status, stage) of each finding last sent
        self._task = None
        self._ended = False
        #: pictures sent to the page
        self.frames = 0
        self.error: BaseException | None = None
        self._runview = None
        self._stage_view = None   # the run file opened to show a finding's stage
        app.page.live_stage = self.stage_of
        app.server.call_soon(self._start)

    # -- the session loop's side
    def post(self, rays, tops, tip=None, tool=None, progress=None, findings=None, wco=None, stage=None) -> None:
        with self._lock:
            if rays is not None and tops is not None and len(rays):
                self._rays.append(np.asarray(rays, np.int64))
                self._tops.append(np.asarray(tops, np.float32))
            if tip is not None:
                self._tip = np.asarray(tip, np.float64).copy()
            self._posted += 1

    # -- the page's thread
    def _start(self) -> None:
        self._task = asyncio.ensure_future(self._run())

    async def _run(self) -> None:
        while not self._ended:
            try:
                self._draw()
            except Exception as exc:  # noqa: BLE001 - the run goes on without the page
                self.error = exc
                return
            await asyncio.sleep(self.period)

    def _draw(self) -> None:
        with self._lock:
            if self._posted == self._drawn:
                return
            rays, tops, tip = self._rays, self._tops, self._tip
            self._rays, self._tops, self._drawn = [], [], self._posted
        for r, t in zip(rays, tops):
            self.heights[r] = t
        findings = list(self.session.findings)
        # a finding predicted then happened changes in place: its status and stage count too
        seen = [(f.get("status"), f.get("stage")) for f in findings]
        changed = seen != self._shown_findings
        self._shown_findings = seen
        sync = self.session.last_sync
        self.app.page.update_live(live_figures(self.session, tip), self.heights.reshape(self.session.live.frame.shape),
                                  tip, findings if changed else None, row=None if sync is None else int(sync.row))
        self.frames += 1

    def stage_of(self, finding: dict):
        """``(heights, tip, row, stage)`` of the model at the stage where ``finding`` (a
        page item) happened, read from the run file being written; or a sentence saying
        why it cannot be shown (predicted and not cut yet, not recorded, not in the file
        yet)."""
        from monitor.trace_io import RunView
        from monitor.web.runmodel import RunModel

        stage = finding.get("stage")
        line = finding.get("line")
        if finding.get("predicted") or not isinstance(stage, int):
            return (f"predicted at line {line}, not cut yet: there is no model of it until the machine "
                    "has cut it (its stage can be shown then)")
        run = getattr(self.session, "run", None)
        if run is None:
            return "this job is not recorded (no run file): its stage cannot be shown until a run file is kept"
        if self._stage_view is not None:
            self._stage_view.close()
        # opened again on each click: the file grows as the machine runs
        self._stage_view = view = RunView(run.path)
        held = view.last_stage
        if stage > held:
            return (f"happened at stage {stage}, which the run file does not hold yet (it holds stages up "
                    f"to {held}; the model is written about every quarter second): click it again in a moment")
        model = RunModel(view)
        heights = np.array(model.heights(stage), np.float32)
        return heights, model.at(stage).tip, model.row(stage), stage

    # -- the end
    def finished(self, run_path, summary: dict) -> None:
        """The run is over (its file closed): say so and show the run file's timeline."""
        done = threading.Event()

        def show():
            try:
                self._ended = True
                self._draw()
                self._show_run(run_path, summary)
            finally:
                done.set()
        self.app.server.call_soon(show)
        done.wait(60.0)

    def _show_run(self, run_path, summary: dict) -> None:
        from monitor.trace_io import RunView
        from monitor.web.runmodel import RunModel

        figures = {**live_figures(self.session, self._tip), "state": f"ended ({summary.get('ended', '')})",
                   "next": "", "note": f"{summary.get('findings', 0)} finding(s); run file {run_path}"}
        self.app.page.update_live(figures)
        try:
            self._runview = RunView(run_path)
            self.app.page.load_run(RunModel(self._runview))
        except Exception as exc:  # noqa: BLE001 - a run without a trace: the live picture stays
            self.app.page.update_live({**figures, "note": f"{figures['note']}; no timeline: {exc}"})

    def close(self) -> None:
        """Stop serving the page, then close the run file it showed."""
        self._ended = True
        self.app.close()
        for view in (self._runview, self._stage_view):
            if view is not None:
                view.close()


def live_figures(session, tip) -> dict:
    """What the page shows of a running machine: its state, line, work position (mm) and
    the next predicted finding with its countdown."""
    from monitor.status import next_finding

    state, sync = session.last, session.last_sync
    ok = tip is not None and bool(np.all(np.isfinite(tip)))
    x, y, z = (f"{v:.3f}" for v in tip[:3]) if ok else ("-", "-", "-")
    upcoming = ""
    if sync is not None and state is not None:
        ovr = state.overrides[0] if state.overrides else 100
        upcoming = next_finding(session.findings, session.path.row_t0, sync.progress, ovr)
    return {"state": state.state.value if state is not None else "waiting for the machine",
            "line": int(sync.line) if sync is not None else None, "x": x, "y": y, "z": z,
            "next": upcoming, "note": "", "findings": len(session.findings)}


def start_live_page(address: str | None, session, program_text: str, as_json: bool, console=None) -> LiveFeed:
    """Serve the page on ``address`` (``--web``'s HOST:PORT), say where, and attach it to
    ``session``; returns the feed (:meth:`LiveFeed.close` when done)."""
    from monitor.web.address import parse_address
    from monitor.web.app import announce, start_app
    from monitor.web.scene import Scene

    host, port = parse_address(address, "--web")
    wp = session.wp
    tool = wp.tool(int(session.moves["tool"][0])) if len(session.moves) else wp.default_tool
    scene = Scene(wp.frame, session.live.top(), moves=session.moves, tool=tool)
    name = session.job.program.name if session.job.program else "job"
    app = start_app(f"dexmon {name} (live)", scene, host, port, program_lines=program_text.splitlines(),
                    where="--web")
    announce(app, host, as_json, console)
    feed = LiveFeed(session, app)
    session.attach_view(feed)
    return feed
