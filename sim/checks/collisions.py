"""Collision checks: material met by a rapid, by the shank, the holder or the tool above
its flutes, and any part of the tool entering a fixture.

Volumes come from the cutter: ``Cutter.cut_moves(...).removed`` for what the cutting part
really removed, ``Cutter.probe_moves(moves, body)`` for what a swept body would meet
without changing the grid.
"""

from __future__ import annotations

import numpy as np

from sim.checks.findings import Finding
from sim.checks.motion import is_arc, is_motion, move_ids_of
from sim.checks.where import contact_point, first_contact, tip_at
from sim.errors import InputError
from sim.gcode.moves import MoveKind
from sim.grid import DexelGrid
from sim.tools import DEFAULT_SHANK_LENGTH, Body, Tool

#: finding kind of each non-cutting body name
BODY_KINDS = {"shank": "shank_contact", "holder": "holder_contact", "above_flutes": "above_flute_contact"}


def rapid_into_stock(moves: np.ndarray, removed, move_ids=None, min_volume: float = 1e-6,
                     cut=None, grid=None) -> list[Finding]:
    """Rapid rows that removed (or would remove) more than ``min_volume`` mm^3.

    Position: with ``cut`` (the :class:`~sim.cut.CutResult` of ``moves``) and ``grid``
    (the model after the cut), the point where the rapid first entered material - of the
    rays it changed, the material top it met that comes first along the move
    (:func:`sim.checks.where.first_contact`) - since a machinist looks there; else the
    move's end.
    """
    moves = np.asarray(moves)
    ids = move_ids_of(moves, move_ids)
    removed = np.asarray(removed, np.float64)
    bad = np.nonzero((moves["kind"] == int(MoveKind.RAPID)) & (removed > min_volume))[0]
    out = []
    for k in bad:
        pos = tip_at(moves, k)
        if cut is not None and grid is not None and cut.changed_rays.size:
            entry = first_contact(moves, k, cut, grid)
            if entry is not None:
                pos = entry
        out.append(Finding(kind="rapid_into_stock", line=int(moves["line"][k]), stage=int(ids[k]),
                           position=tuple(float(v) for v in pos), volume=float(removed[k]),
                           message=f"rapid (G0) into material at line {int(moves['line'][k])}: "
                                   f"{float(removed[k]):.3f} mm^3"))
    return out


def instance_slivers(cut, rows: np.ndarray, floor: float) -> np.ndarray:
    """bool (n,): which of ``rows`` (bool (n,), rows cut by instances of motion) took at
    most ``floor`` mm off every ray they changed (``cut``: their CutResult, depths kept).

    Instances of motion leave cusps between two poses no thicker than the step between
    them; a later move through the same place (a retract up a tilted plunge) shaves them.
    Such slivers are the model's sampling, not material the machine meets."""
    out = np.zeros(rows.size, bool)
    ptr = cut.changed_ptr
    if not cut.changed_depth.size:
        return out
    for k in np.nonzero(rows)[0]:
        lo, hi = ptr[k], ptr[k + 1]
        out[k] = hi > lo and float(cut.changed_depth[lo:hi].max()) <= floor
    return out


def above_flute_body(tool: Tool, length: float = DEFAULT_SHANK_LENGTH) -> Body | None:
    """The tool body between the top of the flutes and the shank (or ``length`` mm of it
    when no shank is declared): a cylinder of the tool diameter that does not cut.
    None when the shank starts right at the flute top."""
    top = tool.shank.bottom if tool.shank is not None else tool.flute_length + length
    if top - tool.flute_length <= 1e-9:
        return None
    return Body.cylinder("above_flutes", tool.diameter, tool.flute_length, top - tool.flute_length)


#: non-cutting bodies are probed this much (mm) thinner, so that a shank of the cutting
#: diameter sliding down a hole its own flutes just cut (tangent to the wall on the
#: boundary rays) is not reported as contact
CONTACT_CLEARANCE = 0.01


def _thinner(body: Body, clearance: float) -> Body:
    p = np.array(body.profile, np.float64)
    p[:, 1] = np.maximum(p[:, 1] - clearance, 1e-6)
    return Body(body.name, p)


def contact_bodies(tool: Tool, clearance: float = CONTACT_CLEARANCE) -> list[tuple[str, Body]]:
    """``(finding kind, body)`` for every non-cutting body of ``tool``, lowest first, each
    ``clearance`` mm thinner than declared."""
    out = []
    above = above_flute_body(tool)
    if above is not None:
        out.append((BODY_KINDS["above_flutes"], above))
    if tool.shank is not None:
        out.append((BODY_KINDS["shank"], tool.shank))
    if tool.holder is not None:
        out.append((BODY_KINDS["holder"], tool.holder))
    return [(kind, _thinner(body, clearance)) for kind, body in out]


def body_findings(moves: np.ndarray, kind: str, volumes, move_ids=None, min_volume: float = 1e-6,
                  what: str = "", present=None, cutter=None, body=None) -> list[Finding]:
    """One finding per motion row whose body met more than ``min_volume`` mm^3
    (``present``, default ``volumes``); its volume is ``volumes`` (what it met first).
    Its position: with ``cutter`` (on the material ``present`` was measured on) and
    ``body``, where the body first met that material along the move
    (:func:`sim.checks.where.contact_point`); else the move's end."""
    moves = np.asarray(moves)
    ids = move_ids_of(moves, move_ids)
    volumes = np.asarray(volumes, np.float64)
    present = volumes if present is None else np.asarray(present, np.float64)
    bad = np.nonzero((present > min_volume) & is_motion(moves))[0]
    label = what or kind.replace("_", " ")

    def where(k):
        met = contact_point(cutter, moves, k, body) if cutter is not None else None
        return tip_at(moves, k) if met is None else met

    return [Finding(kind=kind, line=int(moves["line"][k]), stage=int(ids[k]), position=tuple(where(k)),
                    volume=float(volumes[k]),
                    message=f"{label} at line {int(moves['line'][k])}: {float(volumes[k]):.3f} mm^3",
                    detail={"group": what} if what else {})
            for k in bad]


def max_top(grid: DexelGrid) -> float:
    """Highest material point of a top-view grid along the rays (s), -inf when empty."""
    t = grid.top()
    return float(np.nanmax(t)) if np.isfinite(t).any() else -np.inf


def reachable(moves: np.ndarray, body_bottom: float, top: float, kinematics=None, origin=None,
              body=None, step: float = 1.0, tool_lengths=None) -> np.ndarray:
    """bool (n,): rows where a body starting ``body_bottom`` mm above the tip can get
    down to material whose highest point is ``top`` (top-view grids): a cheap filter that
    spares probing bodies that pass above everything. Rows a rotary of ``kinematics``
    turns (:func:`turned_rows`; ``origin`` as the Cutter takes it) are judged by where
    the tilted ``body`` (a Tool or Body) really goes (:func:`tilted_reach`; all kept
    without one): its rim reaches below its bottom on the axis. ``tool_lengths``: as
    :class:`sim.cut.Cutter` takes them."""
    zs = np.minimum(moves["start"][:, 2], moves["end"][:, 2]) - moves["tool_length"]
    near = zs + body_bottom < top
    if kinematics is not None:
        turned = turned_rows(moves, kinematics, origin)
        if turned.any():
            k = np.nonzero(turned)[0]
            near[k] = True if body is None else tilted_reach(moves[k], body, top, kinematics, origin, step,
                                                             tool_lengths)
    return near & is_motion(moves)


def tilted_reach(moves: np.ndarray, body, top: float, kinematics, origin=None, step: float = 1.0,
                 tool_lengths=None) -> np.ndarray:
    """bool (n,): rows whose ``body`` (a Tool or Body), carried by ``kinematics`` from the
    row's start pose to its end (machine axes linear, as the Cutter cuts them), gets
    below ``top`` (mm, the part frame's z) at some point. The body is placed at instances
    of motion no point of it moves more than ``step`` mm between
    (:meth:`Kinematics.instance_counts`), and its lowest point at each (a body of
    revolution: the lower rim of its bottom or top disc) less ``step`` is compared with
    ``top``. Arc rows are always kept (their path leaves the chord). ``tool_lengths``
    ({tool: mm}): the G43 lengths a head places the tools by, for a table of tips (see
    :class:`sim.cut.Cutter`); default each row's ``tool_length``."""
    from sim import sweep
    from sim.rotary_plan import placing_lengths

    n = len(moves)
    if n == 0 or not np.isfinite(top):
        return np.full(n, n > 0 and top > -np.inf)
    prof = sweep.body_profile(body)
    h_lo, h_hi, radius = float(prof[0, 0]), float(prof[-1, 0]), float(prof[:, 1].max())
    o = np.zeros(6) if origin is None else np.asarray(origin, np.float64).reshape(6)
    start = np.asarray(moves["start"], np.float64) + o
    end = np.asarray(moves["end"], np.float64) + o
    lengths = placing_lengths(moves, tool_lengths)
    counts = np.asarray(kinematics.instance_counts(start, end, lengths, h_hi, radius, step), np.int64)
    # every row's poses in one table: count + 1 equal steps of each row, both ends exact
    per_row = counts + 1
    first = np.concatenate([[0], np.cumsum(per_row)[:-1]])
    row = np.repeat(np.arange(n), per_row)
    t = (np.arange(int(per_row.sum())) - first[row]) / counts[row]
    poses = start[row] + t[:, None] * (end - start)[row]
    tips, axes = kinematics.forward(poses, lengths[row])
    az = axes[:, 2]
    side = radius * np.sqrt(np.maximum(1.0 - az * az, 0.0))
    low = tips[:, 2] - o[2] + np.minimum(h_lo * az, h_hi * az) - side
    return (np.minimum.reduceat(low, first) - step < top) | is_arc(moves)


def turned_rows(moves: np.ndarray, kinematics, origin=None) -> np.ndarray:
    """bool (n,): rows a rotary axis of ``kinematics`` turns: its machine angle (the row's
    plus ``origin``'s, (6,) X Y Z A B C) is not 0 at the row's start or end."""
    from sim.kinematics import ROTARY_COLUMN

    out = np.zeros(len(moves), bool)
    if kinematics is None or not kinematics.rotaries:
        return out
    cols = np.array([ROTARY_COLUMN[r] for r in kinematics.rotaries])
    o = np.zeros(6) if origin is None else np.asarray(origin, np.float64).reshape(6)
    a0 = moves["start"][:, cols] + o[cols]
    a1 = moves["end"][:, cols] + o[cols]
    return (a0 != 0.0).any(axis=1) | (a1 != 0.0).any(axis=1)


class Fixture:
    """A clamp, vise jaw or table: a dexel grid the tool must never enter.

    ``grid`` may have its own frame (a box grid over just the fixture).
    ``kinematics``, ``origin``, ``tool_lengths``: how the tool meets the fixture on a
    machine with rotaries, as :class:`~sim.cut.Cutter` takes them: the machine's whole
    kinematics for a fixture on the rotary table (it turns with the part), only its head
    for one fixed to the machine (:func:`sim.kinematics.head_only`); None (the default):
    3-axis, A B C turn nothing."""

    def __init__(self, name: str, grid: DexelGrid, kinematics=None, origin=None, tool_lengths=None):
        self.name = name
        self.grid = grid
        self.kinematics = kinematics if kinematics is not None and kinematics.rotaries else None
        self.origin = origin
        self.tool_lengths = tool_lengths
        self._top = max_top(grid) if grid.frame.is_top else np.inf

    @classmethod
    def box(cls, lo, hi, spacing: float, name: str | None = None) -> "Fixture":
        """A box fixture ``lo``..``hi`` (machine coords, mm) on its own top-view grid."""
        from sim.frame import Frame
        from sim.solids import box_grid

        lo = np.asarray(lo, np.float64)
        hi = np.asarray(hi, np.float64)
        if not np.all(hi > lo):
            raise InputError(f"fixture box must have lo < hi on every axis, got {lo.tolist()} .. {hi.tolist()}")
        frame = Frame.top(lo[0], lo[1], hi[0], hi[1], spacing)
        return cls(name or f"box {lo.tolist()}..{hi.tolist()}", box_grid(frame, lo, hi))

    def check(self, moves: np.ndarray, tool: Tool, move_ids=None, min_volume: float = 1e-6,
              left: dict | None = None) -> list[Finding]:
        """Moves whose tool (cutting part, shank, holder, body above the flutes) meets the
        fixture; one finding per move and part.

        ``left``: {part name: the fixture grid with what that part already touched taken
        away}, kept by the caller across batches (filled here on first use). With it each
        move's volume is what it touches first, so the volumes of a finding's moves add up
        to the union of what they touched (a holder rubbing a clamp over many moves never
        weighs more than the clamp); without it, what each move's part would sweep."""
        moves = np.asarray(moves)
        if len(moves) == 0:
            return []
        ids = move_ids_of(moves, move_ids)
        out: list[Finding] = []
        parts = [("tool", tool, 0.0)] + [(b.name, b, b.bottom) for _, b in contact_bodies(tool)]
        # a turned part or tool: the programmed X Y Z say nothing of where it meets the fixture
        turned = turned_rows(moves, self.kinematics, self.origin)
        for name, body, bottom in parts:
            near = reachable(moves, bottom, self._top, self.kinematics, self.origin, body=body,
                             step=self.grid.frame.spacing, tool_lengths=self.tool_lengths)
            rows = np.nonzero(near)[0]
            rows = rows[_near_xy(moves[rows], self.grid, _radius(body)) | turned[rows]]
            if rows.size == 0:
                continue
            vol = present = self._cutter(self.grid, tool).probe_moves(moves[rows], body=body)
            if left is not None and (present > min_volume).any():
                grid = left.get(name)
                if grid is None:
                    grid = left[name] = self.grid.copy()
                vol = self._cutter(grid, tool).cut_moves(moves[rows], record_changes=False, body=body).removed
            for f in body_findings(moves[rows], "fixture_collision", vol, ids[rows], min_volume,
                                   what=f"{name} in fixture {self.name}", present=present,
                                   cutter=self._cutter(self.grid, tool) if (present > min_volume).any() else None,
                                   body=body):
                out.append(f)
        return out

    def _cutter(self, grid: DexelGrid, tool: Tool):
        from sim.cut import Cutter

        return Cutter(grid, tool, kinematics=self.kinematics, origin=self.origin, tool_lengths=self.tool_lengths)


def _radius(body) -> float:
    return float(body.cutting_radius if isinstance(body, Tool) else body.max_radius)


def _near_xy(moves, grid: DexelGrid, radius: float) -> np.ndarray:
    """bool (n,): rows whose XY box, grown by ``radius``, overlaps the grid's XY box."""
    if len(moves) == 0 or not grid.frame.is_top:
        return np.ones(len(moves), bool)
    f = grid.frame
    x0, y0 = f.origin[0], f.origin[1]
    x1, y1 = x0 + (f.nu - 1) * f.spacing, y0 + (f.nv - 1) * f.spacing
    s, e = moves["start"], moves["end"]
    lo_x = np.minimum(s[:, 0], e[:, 0]) - radius
    hi_x = np.maximum(s[:, 0], e[:, 0]) + radius
    lo_y = np.minimum(s[:, 1], e[:, 1]) - radius
    hi_y = np.maximum(s[:, 1], e[:, 1]) + radius
    arc = is_arc(moves)
    return arc | ((hi_x >= x0) & (lo_x <= x1) & (hi_y >= y0) & (lo_y <= y1))
