"""Look-ahead: cut the program ahead of the spindle on a scratch model and check it.

Everything here is in the job's *work coordinates* (the coordinates the program, stock,
fixtures and design are written in): the move table is turned into a work-coordinate
table whose tip is ``end_work`` (:func:`work_moves`), and the dexel frame covers the stock
and fixtures.

:class:`Lookahead` keeps a scratch model, a copy of the live stock taken when the session
anchors, onto which the program rows ahead are cut *once each*, as the horizon reaches
them. Before a chunk of rows is cut, shank and holder are probed against it and every
body against the fixtures; after, the removed volume per row gives rapids into stock and
cutting with the spindle stopped, and the changed rays are assessed against the design
(gouges). The live model is never touched. When the machine leaves the program (a jump),
the session re-anchors the scratch model on the live one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from monitor.job import Job, JobError, Solid
from monitor.sync import ProgramPath
from sim.checks.findings import Finding
from sim.errors import InputError
from sim.frame import Frame
from sim.gcode.moves import MoveKind
from sim.grid import DexelGrid
from sim.tolerance import Tolerance

#: removed / touched volume below this is numerical noise, mm^3
MIN_VOLUME = 1e-3


def work_moves(moves: np.ndarray) -> np.ndarray:
    """A copy of a move table with ``start/end`` replaced by the work coordinates of the tip.

    ``tool_length`` becomes 0 (work coordinates are the tip's) and arc centres are shifted
    into the work system of their row, so the cutter sweeps the tip where the program put it.
    """
    out = moves.copy()
    shift = np.asarray(moves["start_work"][:, :3], np.float64) - np.asarray(moves["start"][:, :3], np.float64)
    shift[:, 2] += moves["tool_length"]  # machine Z of the controlled point = tip + length
    out["start"] = moves["start_work"]
    out["end"] = moves["end_work"]
    out["center"] = moves["center"] + shift
    out["tool_length"] = 0.0
    return out


def machine_moves(moves_work: np.ndarray, wco) -> np.ndarray:
    """Controlled-point machine coordinates for travel limits: work tip + ``wco`` (6,) mm.

    ``wco`` is the controller's work coordinate offset (G5x + G92 + tool length offset).
    """
    out = moves_work.copy()
    w = np.asarray(wco, np.float64).reshape(-1)[:6]
    w6 = np.zeros(6)
    w6[:w.size] = w
    out["start"] = moves_work["start"] + w6
    out["end"] = moves_work["end"] + w6
    out["center"] = moves_work["center"] + w6[:3]
    return out


# --- the workpiece ------------------------------------------------------------------------

def _load_mesh(solid: Solid, what: str):
    from sim.solids import load_mesh

    mesh, _ = load_mesh(solid.stl)
    mesh = mesh.copy()
    mesh.apply_translation(solid.offset)
    return mesh


def _bounds(solid: Solid, what: str):
    b = solid.bounds()
    if b is not None:
        return np.array(b[0], float), np.array(b[1], float), None
    mesh = _load_mesh(solid, what)
    return np.asarray(mesh.bounds[0], float), np.asarray(mesh.bounds[1], float), mesh


def _solid_grid(frame: Frame, solid: Solid, mesh, tol: Tolerance) -> DexelGrid:
    from sim import solids

    if solid.kind == "box":
        lo, hi = solid.bounds()
        return solids.box_grid(frame, lo, hi, tol=tol)
    if solid.kind == "cylinder":
        cx, cy, r, z0, z1 = solid.cylinder
        o = solid.offset
        return solids.cylinder_grid(frame, (cx + o[0], cy + o[1], z0 + o[2]), (0, 0, 1), r, z1 - z0, tol=tol)
    return solids.mesh_grid(frame, mesh, tol=tol)


def build_tools(job: Job, tool_numbers) -> tuple[dict[int, object], object]:
    """``({tool number: sim.tools.Tool}, default Tool)`` for the numbers the program uses.

    Inline ``[tools]`` entries win over the tool table; numbers in neither take the
    job's default tool. Raises :class:`JobError` naming the tool that is missing.
    """
    from sim.tools import Body, parse_tool_spec, with_bodies
    from sim.tooltable import read_tool_table, tool_from_entry

    table = read_tool_table(job.tool_table) if job.tool_table else {}
    where = str(job.source or "command line")

    def make(td):
        try:
            tool = parse_tool_spec(td.spec, job.tolerance)
        except InputError as exc:
            raise JobError(f"tool {td.number}: {exc}", where) from None
        if td.shank or td.holder:
            shank = Body.cylinder("shank", td.shank[0], tool.flute_length, td.shank[1]) if td.shank else tool.shank
            base = shank.top if shank is not None else tool.flute_length
            holder = Body.cylinder("holder", td.holder[0], base, td.holder[1]) if td.holder else tool.holder
            tool = with_bodies(tool, shank, holder)
        return tool

    tools = {}
    for n in sorted({int(x) for x in tool_numbers}):
        td = job.tools.get(n)
        if td is not None:
            tools[n] = make(td)
        elif n in table:
            tools[n] = tool_from_entry(table[n])
        elif job.default_tool is not None:
            tools[n] = make(job.default_tool)
    default = make(job.default_tool) if job.default_tool is not None else (
        next(iter(tools.values()), None))
    if default is None:
        raise JobError("no tool for this program: give [tools] (or a tool table) or --tool", where)
    missing = sorted(set(int(x) for x in tool_numbers) - set(tools) - {0})
    if missing:
        raise JobError(f"tool T{missing[0]} is used by the program but not in [tools] or the tool table",
                       where)
    return tools, default


@dataclass
class Workpiece:
    """Live stock model, fixtures and design on one top frame, in work coordinates (mm)."""

    frame: Frame
    stock: DexelGrid
    fixtures: DexelGrid | None
    design: object | None  # sim.checks.error_map.DesignModel
    tools: dict
    default_tool: object
    tol: Tolerance
    fixture_names: list[str] = field(default_factory=list)

    def tool(self, number: int):
        return self.tools.get(int(number), self.default_tool)


def build_workpiece(job: Job, moves: np.ndarray) -> Workpiece:
    """Stock, fixtures and design of ``job`` as dexel models on a frame covering them all."""
    from sim.boolean import union
    from sim.checks.error_map import DesignModel

    if job.stock is None:
        raise JobError("no stock: give [stock] in the job file or --stock", str(job.source or "command line"))
    tools, default = build_tools(job, np.unique(moves["tool"]) if len(moves) else [])
    reach = max([t.radius for t in tools.values()] + [default.radius])
    for t in list(tools.values()) + [default]:
        for b in (t.shank, t.holder):
            if b is not None:
                reach = max(reach, b.max_radius)
    lo, hi, stock_mesh = _bounds(job.stock, "[stock]")
    fixture_meshes = []
    for f in job.fixtures:
        flo, fhi, fm = _bounds(f, "[[fixtures]]")
        lo, hi = np.minimum(lo, flo), np.maximum(hi, fhi)
        fixture_meshes.append(fm)
    margin = reach + 2 * job.resolution
    frame = Frame.top(lo[0] - margin, lo[1] - margin, hi[0] + margin, hi[1] + margin, job.resolution)
    stock = _solid_grid(frame, job.stock, stock_mesh, job.tolerance)
    fixtures = None
    for f, fm in zip(job.fixtures, fixture_meshes):
        g = _solid_grid(frame, f, fm, job.tolerance)
        fixtures = g if fixtures is None else union(fixtures, g)
    design = None
    if job.design is not None:
        if job.design.kind == "stl":
            design = DesignModel(frame, job.design.stl, offset=job.design.offset, name=str(job.design.stl))
        else:
            import trimesh

            blo, bhi = job.design.bounds()
            mesh = trimesh.creation.box(bounds=[blo, bhi])
            design = DesignModel(frame, mesh, name="design box")
    return Workpiece(frame, stock, fixtures, design, tools, default, job.tolerance,
                     [f.name or f"fixture {k + 1}" for k, f in enumerate(job.fixtures)])


# --- the look-ahead -----------------------------------------------------------------------------

class Lookahead:
    """Cut and check the program ahead of the spindle on a scratch copy of the live stock.

    Parameters
    ----------
    wp : Workpiece
    moves : MOVE_DTYPE (n,) in work coordinates (:func:`work_moves`)
    path : ProgramPath of the same table (program time per row)
    horizon_s, horizon_mm : how far ahead to look (program seconds; and/or mm of path)
    limits : {axis: (lo, hi)} machine travel limits (optional), checked with ``wco``
    """

    def __init__(self, wp: Workpiece, moves: np.ndarray, path: ProgramPath, horizon_s: float = 5.0,
                 horizon_mm: float | None = None, limits: dict | None = None):
        from sim.checks.error_map import ErrorMap

        self.wp = wp
        self.moves = moves
        self.path = path
        self.horizon_s = float(horizon_s)
        self.horizon_mm = horizon_mm
        self.limits = {k.upper(): v for k, v in (limits or {}).items()}
        self.move_lines = np.concatenate([[0], moves["line"]]).astype(np.int64)
        self.model: DexelGrid | None = None
        self.next_row = 0
        self.errmap = ErrorMap(wp.frame) if wp.design is not None else None
        self.wco = np.zeros(6)
        self.rows_checked = 0

    def anchor(self, live: DexelGrid, row: int, wco=None) -> None:
        """Restart the scratch model from the live one, predicting from ``row`` on."""
        self.model = live.copy()
        self.next_row = int(row)
        if wco is not None:
            self.wco = np.asarray(wco, np.float64)

    def horizon_end(self, progress: float) -> float:
        """Program time up to which rows are predicted."""
        end = progress + self.horizon_s
        if self.horizon_mm is not None:
            end = min(end, self.path.progress_at_length(self.path.length_at(progress) + self.horizon_mm))
        return end

    def advance(self, progress: float) -> list[Finding]:
        """Predict every row that starts before the horizon end; return their findings."""
        if self.model is None:
            raise RuntimeError("Lookahead.anchor() first")
        end = self.horizon_end(progress)
        hi = int(np.searchsorted(self.path.row_t0, end, side="left"))
        hi = min(max(hi, self.next_row), len(self.moves))
        if hi <= self.next_row:
            return []
        lo, self.next_row = self.next_row, hi
        return self.check_rows(lo, hi)

    def check_rows(self, lo: int, hi: int) -> list[Finding]:
        """Probe, cut and assess rows ``lo..hi-1`` on the scratch model."""
        from sim.checks.motion import spindle_stopped_cutting, travel_limits
        from sim.cut import Cutter

        sub = self.moves[lo:hi]
        ids = np.arange(lo + 1, hi + 1, dtype=np.int32)
        self.rows_checked += hi - lo
        out: list[Finding] = []
        motion = np.isin(sub["kind"], (MoveKind.RAPID, MoveKind.FEED, MoveKind.ARC_CW, MoveKind.ARC_CCW))
        if not motion.any():
            return out
        wp = self.wp
        for tnum in np.unique(sub["tool"]):
            rows = np.nonzero((sub["tool"] == tnum) & motion)[0]
            tool = wp.tool(int(tnum))
            part = sub[rows]
            probe = Cutter(self.model, tool, wp.tol)
            for body, kind in ((tool.shank, "shank_contact"), (tool.holder, "holder_contact")):
                if body is not None:
                    out += _volume_findings(kind, probe.probe_moves(part, body=body), part, ids[rows],
                                            f"{body.name} touches the stock")
            if wp.fixtures is not None:
                fx = Cutter(wp.fixtures, tool, wp.tol)
                bodies = [("tool", tool)] + [(b.name, b) for b in (tool.shank, tool.holder) if b is not None]
                for name, body in bodies:
                    out += _volume_findings("fixture_collision", fx.probe_moves(part, body=body), part,
                                            ids[rows], f"{name} enters a fixture", {"body": name})
        cutter = Cutter(self.model, wp.default_tool, wp.tol, tools=wp.tools)
        res = cutter.cut_moves(sub, move_ids=ids)
        rapid = (sub["kind"] == MoveKind.RAPID) & (res.removed > MIN_VOLUME)
        if rapid.any():
            out += _volume_findings("rapid_into_stock", np.where(rapid, res.removed, 0.0), sub, ids,
                                    "rapid (G0) through material")
        out += spindle_stopped_cutting(sub, res.removed, ids, min_volume=MIN_VOLUME)
        if self.errmap is not None and res.changed_rays.size:
            rays = np.unique(res.changed_rays)
            with np.errstate(invalid="ignore"):  # rays missing the design give inf * 0
                self.errmap.update(self.model, wp.design, rays, wp.tol)
            g = self.errmap.gouge[rays]
            if np.any(np.nan_to_num(-g, nan=-1.0) > wp.tol.gouge):
                out += self.errmap.findings(wp.tol, self.move_lines, rays=rays, undercut=False)
        if self.limits:
            out += travel_limits(machine_moves(sub, self.wco), self.limits, ids)
        return out


def _volume_findings(kind: str, volume: np.ndarray, rows: np.ndarray, ids: np.ndarray, what: str,
                     detail: dict | None = None) -> list[Finding]:
    """One finding per row whose volume exceeds :data:`MIN_VOLUME` (position: the row's end tip)."""
    out = []
    for k in np.nonzero(np.asarray(volume) > MIN_VOLUME)[0]:
        tip = tuple(float(v) for v in rows["end"][k, :3])
        line = int(rows["line"][k])
        out.append(Finding(kind=kind, line=line, stage=int(ids[k]), position=tip,
                           volume=float(volume[k]), message=f"{kind.replace('_', ' ')}: {what} at line {line}",
                           detail=dict(detail or {})))
    return out


def lead_time(finding: Finding, path: ProgramPath, progress: float, feed_override: float = 100.0) -> float:
    """Predicted seconds until the spindle reaches the finding's move (0 if already there).

    Program time from the current progress to the start of the offending row, scaled by
    the feed override (a 200 % override halves it).
    """
    row = int(finding.stage) - 1
    if row < 0 or row >= path.row_t0.size:
        return 0.0
    scale = 100.0 / feed_override if feed_override and feed_override > 0 else 1.0
    return max(float(path.row_t0[row]) - float(progress), 0.0) * scale


def finding_record(f: Finding, lead: float, t: float | None = None, predicted: bool = True) -> dict:
    """The JSON object of one finding: ``Finding.to_json()`` + ``lead_time_s`` (+ ``t``)."""
    d = f.to_json()
    d["lead_time_s"] = round(float(lead), 3) if math.isfinite(lead) else None
    d["predicted"] = bool(predicted)
    if t is not None:
        d["t"] = float(t)
    return d
