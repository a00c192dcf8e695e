"""Correct a whole move table (Huang & Oliver 1994, section 4) on the tool tips.

:func:`correct_moves` walks the table in order. Each straight row (rapid or feed) runs
from where the corrected path stands to its programmed end and goes through
:func:`sim.correct.kernels.correct_move`: left alone when it does not gouge beyond the
tolerance, else its end moved by the guide vector and the row split where its sweep still
gouges. Arcs, probes and the like are never changed here: one that gouges, or whose start
the correction moved, is *refused* (the caller names its line), unless the table was
linearised first.

The correction's tool stands upright on the unturned part (3-axis). A row that a rotary
axis turns (A, B or C not 0 at either end: a turned table, or a head that tilts the tool)
is therefore never reshaped, split or retimed: it is left as written
(:func:`turned_rows`, :data:`TURNED_WHY`) and treated like an arc (refused when its start
moved); the check of the written program, which places tools as ``simulate`` does, says
whether it gouges.

Where the table's tip jumps between two rows without a motion (a G43 / G49 change, a tool
change: the machine stays, the tip moves by the change), the corrected path jumps with it.

All positions are tool tips (the table's ``start``/``end`` less ``tool_length``) in the
design's world coordinates, mm.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sim.correct import kernels as K
from sim.correct.gouge import GougeProbe
from sim.gcode.moves import MoveKind, tip_positions
from sim.tolerance import Tolerance

#: rows the correction may reshape
STRAIGHT = (MoveKind.RAPID, MoveKind.FEED)
#: rows that move the tool but are never reshaped (an arc is another arc from another start)
FIXED_MOTION = (MoveKind.ARC_CW, MoveKind.ARC_CCW, MoveKind.PROBE)
#: two tips closer than this are the same point, mm
SAME_POINT = 1e-7
#: most points one row may become
MAX_POINTS_PER_ROW = K.MAX_POINTS
#: why a turned row is left as written (the reports say it with its lines)
TURNED_WHY = "turned by A/B/C: correction works on 3-axis lines only"


@dataclass
class Refusal:
    """A row the correction would have to change but may not: ``row`` index, why."""

    row: int
    reason: str


@dataclass
class Correction:
    """The corrected path.

    ``start`` / ``end`` (n, 3): the tip where each row starts and ends on the corrected
    path (rows without motion: where the path stands). ``points[k]``: the tips row ``k``
    visits, last = ``end[k]`` (None: the row as programmed, one point). ``changed`` (n,)
    bool: rows whose points differ from the program's. ``orig_start`` / ``orig_end``: the
    programmed tips. ``turned`` (n,) bool: rows left as written because a rotary axis
    turns them (:func:`turned_rows`). ``refused``: rows that needed a
    change the correction may not make. Stats: ``poses`` positions looked at, ``corrected``
    poses moved, ``guide_steps``, ``splits``, ``lifts``; ``largest_shift`` (mm, the
    farthest a corrected point lies from its programmed move), ``added_length`` (mm of
    path added), ``worst_gouge`` (mm, the deepest gouge a row had before correction).
    """

    start: np.ndarray
    end: np.ndarray
    points: list
    changed: np.ndarray
    orig_start: np.ndarray = None
    orig_end: np.ndarray = None
    turned: np.ndarray = None
    refused: list = field(default_factory=list)
    poses: int = 0
    corrected: int = 0
    guide_steps: int = 0
    splits: int = 0
    lifts: int = 0
    largest_shift: float = 0.0
    added_length: float = 0.0
    worst_gouge: float = 0.0


def correct_moves(moves: np.ndarray, probe: GougeProbe, tools: dict, default_tool, tol: Tolerance,
                  min_segment: float = 0.02, margin: float = 0.5, max_iter: int = 30,
                  kinematics=None, origin=None) -> Correction:
    """Correct every straight row of ``moves`` (MOVE_DTYPE, coordinates of ``probe``'s
    design) so that no sweep gouges the design deeper than ``tol.gouge``. Rows a rotary
    axis turns are left as written (``Correction.turned``; ``kinematics``, ``origin``: see
    :func:`turned_rows`).

    ``tools``: {tool number: Tool}; rows use ``tools[row.tool]`` or ``default_tool``.
    ``min_segment`` (mm): pieces shorter than this are lifted rather than split.
    ``margin``: corrected poses and pieces are freed to ``margin * tol.gouge`` so that
    rounding the coordinates to the program's decimals keeps them within the tolerance.
    """
    n = len(moves)
    p_start = np.ascontiguousarray(tip_positions(moves, "start"))
    p_end = np.ascontiguousarray(tip_positions(moves, "end"))
    kinds = moves["kind"]
    codes = np.full(n, K.ROW_STILL, np.int8)
    codes[np.isin(kinds, STRAIGHT)] = K.ROW_STRAIGHT
    codes[np.isin(kinds, FIXED_MOTION)] = K.ROW_FIXED
    turned = turned_rows(moves, kinematics, origin)
    codes[turned] = K.ROW_FIXED
    # one parameter row per tool the straight rows use
    numbers = sorted(set(int(t) for t in moves["tool"][codes == K.ROW_STRAIGHT]))
    by_number = {num: tools.get(num, default_tool) for num in numbers}
    tps = np.array([probe.params(by_number[num]) for num in numbers] or [np.zeros(7)], np.float64)
    lut = {num: i for i, num in enumerate(numbers)}
    tool_idx = np.array([lut.get(int(t), 0) for t in moves["tool"]], np.int64) if n else np.zeros(0, np.int64)
    start = np.empty((n, 3))
    end = np.empty((n, 3))
    offs = np.zeros(n + 1, np.int64)
    status = np.zeros(n, np.int8)
    before = np.zeros(n)
    shift = np.zeros(n)
    stats = np.zeros(4, np.int64)
    pts = np.empty((2 * n + 1024, 3))
    t_l = float(tol.gouge)
    while n:
        stats[:] = 0
        done = K.correct_rows(codes, tool_idx, tps, p_start, p_end, probe.frame_tuple, probe.arrays, t_l,
                              margin * t_l, probe.search, float(min_segment), int(max_iter), start, end, pts, offs,
                              status, before, shift, stats)
        if done == n:
            break
        pts = np.empty((2 * pts.shape[0], 3))  # more points than room: again with twice the room
    points: list = [None] * n
    changed = np.zeros(n, bool)
    out = Correction(start, end, points, changed, orig_start=p_start, orig_end=p_end, turned=turned)
    for k in np.flatnonzero(codes == K.ROW_STRAIGHT):
        k = int(k)
        st = int(status[k])
        if st == K.FULL:
            out.refused.append(Refusal(k, f"correcting it needs more than {MAX_POINTS_PER_ROW} points"))
        elif st == K.NOT_CLEAN:
            out.refused.append(Refusal(k, "no position near it clears the design"))
        elif offs[k + 1] - offs[k] > 1 or np.abs(end[k] - p_end[k]).max() > SAME_POINT:
            points[k] = pts[offs[k]:offs[k + 1]].copy()
            changed[k] = True
    for k in np.flatnonzero(status == K.MOVED_FIXED):
        why = f", and it is {TURNED_WHY}" if turned[k] else ""
        out.refused.append(Refusal(int(k), f"it starts where the correction moved the tool "
                                           f"({_fmt(start[k])} instead of {_fmt(p_start[k])}){why}"))
    out.refused.sort(key=lambda r: r.row)
    out.poses = int((codes == K.ROW_STRAIGHT).sum())
    out.corrected, out.guide_steps, out.splits, out.lifts = (int(v) for v in stats)
    out.worst_gouge = float(before.max()) if n else 0.0
    out.largest_shift = float(shift.max()) if n else 0.0
    out.added_length = _path_length(out, codes == K.ROW_STRAIGHT) - float(
        np.linalg.norm(p_end[codes == K.ROW_STRAIGHT] - p_start[codes == K.ROW_STRAIGHT], axis=1).sum())
    return out


def turned_rows(moves: np.ndarray, kinematics=None, origin=None) -> np.ndarray:
    """bool (n,): the rows of ``moves`` that move the tool turned by a rotary axis. With a
    machine's ``kinematics`` (and ``origin``, as the check and the Cutter take them): those
    its rotaries turn (:func:`sim.checks.collisions.turned_rows`, the check's own reading);
    without: those with A, B or C not 0 at either end."""
    from sim.checks.collisions import turned_rows as machine_turned

    motion = np.isin(moves["kind"], STRAIGHT + FIXED_MOTION)
    if kinematics is not None:
        return motion & machine_turned(moves, kinematics, origin)
    rotary = (moves["start"][:, 3:6] != 0.0).any(axis=1) | (moves["end"][:, 3:6] != 0.0).any(axis=1)
    return motion & rotary


def _path_length(c: Correction, rows: np.ndarray) -> float:
    """Length (mm) of the corrected path over ``rows`` (bool (n,)): each row from where it
    starts through its points."""
    total = float(np.linalg.norm(c.end[rows] - c.start[rows], axis=1).sum())
    for k in np.flatnonzero(rows & c.changed):
        pts = np.vstack([c.start[k][None], c.points[k]])
        total += float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()) - float(np.linalg.norm(c.end[k] - c.start[k]))
    return total


def correct_span(moves: np.ndarray, a: int, b: int, probe: GougeProbe, tools: dict, default_tool, tol: Tolerance,
                 **kw) -> Correction:
    """Correct rows ``a <= k < b`` only: the path before them as programmed, the row after
    them starting where the corrected span ends (a look-ahead's proposal for one gouge).
    Keywords as :func:`correct_moves`."""
    n = len(moves)
    p_start = tip_positions(moves, "start")
    p_end = tip_positions(moves, "end")
    out = Correction(p_start.copy(), p_end.copy(), [None] * n, np.zeros(n, bool), orig_start=p_start,
                     orig_end=p_end, turned=turned_rows(moves, kw.get("kinematics"), kw.get("origin")))
    sub = correct_moves(moves[a:b], probe, tools, default_tool, tol, **kw)
    out.start[a:b] = sub.start
    out.end[a:b] = sub.end
    out.points[a:b] = sub.points
    out.changed[a:b] = sub.changed
    out.refused = [Refusal(r.row + a, r.reason) for r in sub.refused]
    for name in ("poses", "corrected", "guide_steps", "splits", "lifts", "largest_shift", "added_length",
                 "worst_gouge"):
        setattr(out, name, getattr(sub, name))
    later = np.flatnonzero(np.isin(moves["kind"][b:], STRAIGHT + FIXED_MOTION))
    if later.size and b > a:
        nxt = b + int(later[0])
        moved = sub.end[-1] - p_end[b - 1]
        # where the table's tip jumps between the rows (a tool length change), it jumps from there
        out.start[nxt] = p_start[nxt] + moved if np.abs(moved).max() > 0 else p_start[nxt]
    return out


def check_fixed_rows(moves: np.ndarray, probe: GougeProbe, tools: dict, default_tool, tol: Tolerance,
                     chord: float, kinematics=None, origin=None) -> list[Refusal]:
    """Arcs that gouge the design deeper than ``tol.gouge`` (their chords within ``chord``
    mm, checked like straight moves): they need a correction only ``--linearize`` allows.
    A turned arc is left as written (:func:`turned_rows`), never refused."""
    from sim.gcode.linearize import linearize

    arcs = np.isin(moves["kind"], (MoveKind.ARC_CW, MoveKind.ARC_CCW))
    arcs = np.flatnonzero(arcs & ~turned_rows(moves, kinematics, origin))
    out = []
    for k in arcs:
        tool = tools.get(int(moves["tool"][k]), default_tool)
        chords = linearize(moves[k:k + 1], chord)
        a = tip_positions(chords, "start")
        b = tip_positions(chords, "end")
        worst = max(probe.move(tool, p, q, tol.gouge).depth for p, q in zip(a, b))
        if worst > 0:
            out.append(Refusal(int(k), f"the arc gouges the design by {worst:.3f} mm"))
    return out


def _fmt(p) -> str:
    return "X{:.4f} Y{:.4f} Z{:.4f}".format(*(float(v) for v in p[:3]))


__all__ = ["TURNED_WHY", "Correction", "Refusal", "check_fixed_rows", "correct_moves", "correct_span",
           "turned_rows"]
