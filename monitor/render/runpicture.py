"""Top-view pictures of a recorded run at any stage, coloured by meaning (replay, report).

A :class:`RunPictures` holds what every picture of one run shares: the frame cropped to
the stock (so the part fills the picture), the stock's top before the first cut (depth
of cut), the design cast on that frame (deviation map) and the tolerance, the tool, and
a headless :class:`monitor.render.live.LiveView` that draws the same overlay as the live
view: axes and work origin, the path near the stage (feeds solid, rapids dashed), the
tool and its holder, findings ringed and labelled with their line, and a strip with the
stage, line, machine time, position, feed, tool and the colour bar in mm.
"""

from __future__ import annotations

import numpy as np

from monitor.render.live import LiveView, finding_marks
from sim.errors import InputError

#: moves drawn around the stage's move: this many before it and after it
PATH_BEFORE, PATH_AFTER = 40, 80
#: the crop keeps this much around the stock (mm) beyond the tool's radius
CROP_MARGIN_MM = 2.0


def tool_text(tool) -> str:
    """``T1 FLAT 6`` / ``BALL 6`` for a ``sim.tools.Tool`` (empty when None or only a
    radius)."""
    if tool is None or not hasattr(tool, "kind"):
        return ""
    num = f"T{tool.number} " if getattr(tool, "number", None) else ""
    return f"{num}{tool.kind} {tool.diameter:g}".upper()


def run_start_time(view) -> float:
    """The machine time (s, the states' clock) the run's times are told from: its first
    recorded state, else 0 (a run written without states stamps cuts from 0)."""
    try:
        if view.reader.state_count():
            return float(view.reader.states()["t"][0])
    except Exception:  # noqa: BLE001 - a run without a states table tells times from 0
        pass
    return 0.0


def finding_moments(view, findings: list[dict]) -> list[tuple[int | None, float | None]]:
    """(stage, machine time s since the run's start) of each finding: its ``stage`` (else
    the stage where its first line was cut) and the recorded time of that stage's cut;
    without one, its program time ``time_s`` (s from the program start, which a finding
    predicted but never reached carries)."""
    tab = view.stage_table
    t0 = run_start_time(view)
    out = []
    for f in findings:
        stage = f.get("stage") if isinstance(f.get("stage"), int) else None
        line = f.get("line")
        secs = None
        if stage is None and tab.size and isinstance(line, int) and line > 0:
            hit = np.nonzero(tab["line"] == line)[0]
            stage = int(tab["stage"][hit[0]]) if hit.size else None
        if stage is not None and tab.size:
            k = int(np.searchsorted(tab["stage"], stage, side="right")) - 1
            if k >= 0 and np.isfinite(tab["t"][k]):
                secs = float(tab["t"][k]) - t0
        if secs is None and isinstance(f.get("time_s"), (int, float)) and np.isfinite(f["time_s"]):
            secs = float(f["time_s"])
        out.append((stage, secs))
    return out


def stage_at_line(view, line: int) -> int:
    """The stage after the last cut of program ``line`` (InputError naming the lines cut)."""
    tab = view.stage_table
    hit = np.nonzero(tab["line"] == int(line))[0] if tab.size else np.zeros(0, int)
    if hit.size == 0:
        cut = np.unique(tab["line"][tab["line"] > 0]) if tab.size else []
        span = f"{cut[0]}..{cut[-1]}" if len(cut) else "none"
        raise InputError(f"line {line} cut nothing in this run (lines cut: {span})", "--line")
    return int(tab["stage"][hit[-1]])


def stage_at_time(view, seconds: float) -> int:
    """The last stage cut at or before ``seconds`` of machine time since the run's start."""
    tab = view.stage_table
    if not tab.size or not np.isfinite(tab["t"]).any():
        raise InputError("the run recorded no cut times", "--time")
    t = tab["t"] - run_start_time(view)
    if not np.isfinite(seconds) or seconds < 0:
        raise InputError(f"expected a machine time >= 0 s, got {seconds}", "--time")
    k = np.nonzero(np.isfinite(t) & (t <= seconds + 1e-9))[0]
    return int(tab["stage"][k[-1]]) if k.size else view.first_stage


def run_tools(view, job=None) -> tuple[dict, object]:
    """``({tool number: sim.tools.Tool}, default Tool or None)`` of the run: the job's
    tools (with shank and holder) for the numbers its moves use, else the run's one tool."""
    moves = view.moves
    if job is not None:
        try:
            from monitor.workpiece import build_tools

            numbers = np.unique(moves["tool"]) if moves is not None and len(moves) else []
            return build_tools(job, numbers)
        except Exception:  # noqa: BLE001 - a picture without the job's tools still shows the run
            pass
    return {}, view.tool()


def load_design(view, frame, design_path=None, tol=None):
    """(DesignModel on ``frame`` or None, Tolerance): the design given, else the run's job's
    (when its file is still found), with the job's tolerance unless ``tol`` is given."""
    from sim.checks.error_map import DesignModel
    from sim.tolerance import DEFAULT

    job = view.job
    tol = tol or (job.tolerance if job is not None else DEFAULT)
    if design_path is not None:
        return DesignModel(frame, design_path, name=str(design_path)), tol
    if job is None or job.design is None:
        return None, tol
    if job.design.kind == "stl":
        return DesignModel(frame, job.design.stl, offset=job.design.offset, name=str(job.design.stl)), tol
    import trimesh

    lo, hi = job.design.bounds()
    return DesignModel(frame, trimesh.creation.box(bounds=[lo, hi]), name="design box"), tol


def _has_position(f) -> bool:
    """Whether :func:`monitor.render.live.finding_marks` keeps finding ``f``."""
    p = f.get("position")
    try:
        return p is not None and len(p) >= 3 and bool(np.all(np.isfinite([float(v) for v in p[:3]])))
    except (TypeError, ValueError):
        return False


def crop_box(heights: np.ndarray, margin_rays: int) -> tuple[int, int, int, int]:
    """(j0, j1, i0, i1), end exclusive: the rays with material grown by ``margin_rays``."""
    j, i = np.nonzero(np.isfinite(heights))
    nv, nu = heights.shape
    if j.size == 0:
        return 0, nv, 0, nu
    return (max(int(j.min()) - margin_rays, 0), min(int(j.max()) + margin_rays + 1, nv),
            max(int(i.min()) - margin_rays, 0), min(int(i.max()) + margin_rays + 1, nu))


def path_near(moves, row: int | None) -> dict | None:
    """The moves of table ``moves`` around program ``row`` (PATH_BEFORE before it,
    PATH_AFTER after it; None: the program's first PATH_AFTER) as ``{"start", "end",
    "rapid"}`` (mm, the table's coordinates): the path every picture draws near its stage.
    None when there is no table."""
    if moves is None or not len(moves):
        return None
    from sim.gcode.moves import MoveKind

    lo = 0 if row is None else max(int(row) - PATH_BEFORE, 0)
    hi = min(len(moves), (PATH_AFTER if row is None else int(row) + PATH_AFTER + 1))
    part = moves[lo:hi]
    moving = np.isin(part["kind"], (MoveKind.RAPID, MoveKind.FEED, MoveKind.ARC_CW, MoveKind.ARC_CCW))
    part = part[moving]
    return {"start": part["start"][:, :3], "end": part["end"][:, :3], "rapid": part["kind"] == MoveKind.RAPID}


class RunPictures:
    """Pictures of the stages of a :class:`monitor.trace_io.RunView`.

    size : the picture's long side at most this many pixels (small grids are enlarged by
        whole pixels per ray up to it, large ones strided down to it).
    color_by : ``"auto"`` (deviation against the design when there is one, else depth of
        cut), ``"deviation"``, ``"depth"`` or ``"move"``.
    design : an STL path overriding the run's job's design. tool : a ``sim.tools.Tool``
        overriding the run's.
    """

    def __init__(self, view, size: int = 800, color_by: str = "auto", design=None, tool=None, tol=None,
                 findings: bool = True):
        self.view = view
        full = view.frame
        self.tools, self.tool = ({}, tool) if tool is not None else run_tools(view, view.job)
        h0, _ = view.state_at(view.first_stage)
        reach = float(getattr(self.tool, "cutting_radius", 0.0) or 0.0) + CROP_MARGIN_MM
        self.box = j0, j1, i0, i1 = crop_box(h0, int(np.ceil(reach / full.spacing)))
        sp = full.spacing
        self.frame = full.__class__(full.origin + (i0 * full.u + j0 * full.v) * sp, full.direction, full.u, sp,
                                    i1 - i0, j1 - j0)
        self.stock_top = np.array(h0[j0:j1, i0:i1], np.float32)
        if color_by not in ("auto", "deviation", "depth", "move"):
            raise InputError(f"expected auto, deviation, depth or move, got {color_by!r}", "--color-by")
        self.design, self.tol = (None, tol) if color_by in ("depth", "move") else \
            load_design(view, self.frame, design, tol)
        if color_by == "deviation" and self.design is None:
            raise InputError("colour by deviation needs a design: give --design STL (the run's job has none, "
                             "or its file is not found)", "--color-by")
        self.color_by = "deviation" if self.design is not None else ("move" if color_by == "move" else "depth")
        self.marks = finding_marks(view.findings) if findings else []
        # a finding is ringed from the stage it was found at (before it: unknown yet)
        moments = finding_moments(view, view.findings) if findings else []
        found = [m[0] for f, m in zip(view.findings, moments) if _has_position(f)]
        self.mark_stages = np.array([view.first_stage if s is None else s for s in found], np.int64)
        self.t0 = run_start_time(view)
        moves = view.moves
        self.moves = moves if moves is not None and len(moves) else None
        self.live = LiveView(self.frame, tool=self.tool, headless=True, max_size=size, min_size=size,
                             color_by=self.color_by, tol=self.tol, stock_top=self.stock_top, axes=True)

    def crop(self, a: np.ndarray) -> np.ndarray:
        j0, j1, i0, i1 = self.box
        return a[j0:j1, i0:i1]

    def errors(self, heights: np.ndarray) -> np.ndarray | None:
        """The deviation (nv, nu) mm of the cropped ``heights`` against the design, or None."""
        from monitor.render.meaning import top_deviation

        return None if self.design is None else top_deviation(self.design, heights, self.tol)

    def status(self, stage: int) -> tuple[dict, np.ndarray | None, int | None]:
        """(strip status, tool tip or None, program row or None) at ``stage``."""
        info = self.view.stage_info(stage)
        tip = info.get("tip")
        tip = tip if tip is not None and np.all(np.isfinite(tip)) and stage > self.view.first_stage else None
        t = info.get("t")
        row = info.get("move_id", 0) - 1 if info.get("move_id", 0) > 0 else None
        feed = None
        tool = self.tool
        if self.moves is not None and row is not None and row < len(self.moves):
            feed = float(self.moves["feed"][row]) if "feed" in self.moves.dtype.names else None
            tool = self.tools.get(int(self.moves["tool"][row]), self.tool)
        self.live.tool = tool
        status = {"stage": stage, "line": info.get("line") if stage > self.view.first_stage else None,
                  "time": None if t is None or not np.isfinite(t) else t - self.t0, "feed": feed,
                  "tool": tool_text(tool)}
        return status, tip, row

    def picture(self, stage: int, heights: np.ndarray | None = None, ids: np.ndarray | None = None) -> np.ndarray:
        """RGB uint8 (rows, cols, 3) of ``stage``: the model and its overlay, the strip below."""
        if heights is None:
            heights, ids = self.view.state_at(stage)
        h = np.ascontiguousarray(self.crop(heights), np.float32)
        status, tip, row = self.status(stage)
        marks = [m for m, s in zip(self.marks, self.mark_stages) if s <= stage]
        img = self.live.render(h, tip, findings=marks, ids=None if ids is None else self.crop(ids),
                               status=status, errors=self.errors(h), moves=path_near(self.moves, row))
        return img.copy()   # the view draws the next picture into the same buffer

    def frames(self, first: int, last: int, max_frames: int = 120):
        """Yield (stage, picture) from ``first`` to ``last`` (backwards when last < first),
        at most ``max_frames`` frames, each with its own overlay."""
        from monitor.render.animate import stage_steps

        tr = self.view.trace
        if tr.t is None:
            raise InputError("the run has no time-trace: animations need it")
        step = stage_steps(first, last, max_frames)
        for stage, heights, ids in tr.t.frames(int(first), int(last), step):
            yield stage, self.picture(stage, heights, ids)
