"""The tool's path in a move table: which rows move, their move ids, arcs as points and
tangents, and the whole path as straight pieces - the geometry the checks on the motion
(:mod:`.travel`, :mod:`.spindle`, :mod:`.engagement`, :mod:`.collisions`) share.

All positions are machine coordinates in mm: ``which="tip"`` takes the G43 length
offset off Z (``sim.gcode.moves.tip_positions``), ``"machine"`` keeps the controlled
point (what the controller calls MPos).
"""

from __future__ import annotations

import math

import numpy as np

from sim.errors import InputError
from sim.gcode.moves import MoveKind, Plane

#: move kinds that move the tool
MOTION_KINDS = (MoveKind.RAPID, MoveKind.FEED, MoveKind.ARC_CW, MoveKind.ARC_CCW, MoveKind.PROBE)
# plane -> (first, second, normal) axes such that a positive angle is counter-clockwise
_PLANE_AXES = {int(Plane.XY): (0, 1, 2), int(Plane.XZ): (2, 0, 1), int(Plane.YZ): (1, 2, 0)}


_MOTION_LUT = np.zeros(256, bool)
_MOTION_LUT[[int(k) for k in MOTION_KINDS]] = True
_ARC_LUT = np.zeros(256, bool)
_ARC_LUT[[int(MoveKind.ARC_CW), int(MoveKind.ARC_CCW)]] = True


def is_motion(moves: np.ndarray) -> np.ndarray:
    """bool (n,): rows that move the tool."""
    return _MOTION_LUT[moves["kind"]]


def is_arc(moves: np.ndarray) -> np.ndarray:
    """bool (n,): arc and helix rows (G2 / G3)."""
    return _ARC_LUT[moves["kind"]]


def move_ids_of(moves: np.ndarray, move_ids=None) -> np.ndarray:
    """int64 (n,): the id of each row (default row index + 1, as ``Cutter`` numbers them)."""
    if move_ids is None:
        return np.arange(1, len(moves) + 1, dtype=np.int64)
    ids = np.asarray(move_ids, np.int64)
    if ids.shape != (len(moves),):
        raise InputError(f"expected {len(moves)} move ids, got {ids.shape}")
    return ids


# --- geometry of the path -------------------------------------------------------------

def _arc_sweep(row) -> float:
    """Signed angle (rad, + counter-clockwise) an arc row turns through, turns included."""
    start, end, c = row["start"], row["end"], row["center"]
    a, b, _ = _PLANE_AXES.get(int(row["plane"]), (0, 1, 2))
    t0 = math.atan2(start[b] - c[b], start[a] - c[a])
    t1 = math.atan2(end[b] - c[b], end[a] - c[a])
    turns = max(int(row["turns"]), 1)
    if int(row["kind"]) == MoveKind.ARC_CCW:
        sweep = (t1 - t0) % (2 * math.pi)
        if sweep <= 1e-12:
            sweep = 2 * math.pi
        return sweep + 2 * math.pi * (turns - 1)
    sweep = (t0 - t1) % (2 * math.pi)
    if sweep <= 1e-12:
        sweep = 2 * math.pi
    return -(sweep + 2 * math.pi * (turns - 1))


def arc_points(row, chord: float, which: str = "tip") -> np.ndarray:
    """Points along one arc row (float64 (k, 3) mm, start and end included), spaced so
    the chords stay within ``chord`` mm of the arc; helices interpolate the normal axis.

    ``which="tip"`` takes the G43 length offset off Z; ``"machine"`` keeps the
    controlled point.
    """
    start = np.array(row["start"][:3], np.float64)
    end = np.array(row["end"][:3], np.float64)
    c = np.array(row["center"], np.float64)
    a, b, n = _PLANE_AXES.get(int(row["plane"]), (0, 1, 2))
    r0 = math.hypot(start[a] - c[a], start[b] - c[b])
    r1 = math.hypot(end[a] - c[a], end[b] - c[b])
    t0 = math.atan2(start[b] - c[b], start[a] - c[a])
    sweep = _arc_sweep(row)
    r = max(r0, r1, 1e-9)
    step = 2.0 * math.acos(max(-1.0, min(1.0, 1.0 - chord / r))) if chord < r else math.pi / 2
    k = max(int(math.ceil(abs(sweep) / max(step, 1e-6))), 1)
    k = min(k, 100_000)
    f = np.linspace(0.0, 1.0, k + 1)
    ang = t0 + sweep * f
    rad = r0 + (r1 - r0) * f
    pts = np.empty((k + 1, 3))
    pts[:, a] = c[a] + rad * np.cos(ang)
    pts[:, b] = c[b] + rad * np.sin(ang)
    pts[:, n] = start[n] + (end[n] - start[n]) * f
    pts[0], pts[-1] = start, end
    if which == "tip":
        pts[:, 2] -= float(row["tool_length"])
    return pts


def path_polyline(moves: np.ndarray, chord: float = 0.01, which: str = "tip"):
    """The path of the motion rows as straight pieces.

    Returns ``(p0, p1, row)``: float64 (m, 3) start and end of every piece (mm) and
    int64 (m,) the move-table row it belongs to. Lines give one piece, arcs as many chords
    as ``chord`` (mm) needs; non-motion rows give none.
    """
    moves = np.asarray(moves)
    motion = is_motion(moves)
    arc = motion & is_arc(moves)
    line = motion & ~arc
    zoff = moves["tool_length"] if which == "tip" else np.zeros(len(moves))
    p0s, p1s, rows = [], [], []
    li = np.nonzero(line)[0]
    if li.size:
        s = np.array(moves["start"][li, :3], np.float64)
        e = np.array(moves["end"][li, :3], np.float64)
        s[:, 2] -= zoff[li]
        e[:, 2] -= zoff[li]
        p0s.append(s)
        p1s.append(e)
        rows.append(li)
    for k in np.nonzero(arc)[0]:
        pts = arc_points(moves[k], chord, which)
        p0s.append(pts[:-1])
        p1s.append(pts[1:])
        rows.append(np.full(len(pts) - 1, k))
    if not rows:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.int64)
    row = np.concatenate(rows).astype(np.int64)
    o = np.argsort(row, kind="stable")
    return np.concatenate(p0s)[o], np.concatenate(p1s)[o], row[o]


def descent_deg(d: np.ndarray) -> np.ndarray:
    """Angle (deg) below horizontal of directions ``d`` (k, 3): 90 straight down."""
    return np.degrees(np.arctan2(-d[:, 2], np.hypot(d[:, 0], d[:, 1])))


def arc_tangents(arcs: np.ndarray, t: np.ndarray) -> np.ndarray:
    """d(position)/dt (k, 3) mm of arc rows ``arcs`` (k,) at parameters ``t`` (k,) in [0, 1],
    the path :func:`arc_points` follows: the angle and the radius (a spiral's) evenly in t,
    the normal axis linearly."""
    axes = np.array([_PLANE_AXES.get(int(p), (0, 1, 2)) for p in arcs["plane"]], np.int64).reshape(-1, 3)
    rows = np.arange(len(arcs))
    s, e, c = arcs["start"][:, :3], arcs["end"][:, :3], arcs["center"]
    a, b, nrm = axes[:, 0], axes[:, 1], axes[:, 2]
    r0 = np.hypot(s[rows, a] - c[rows, a], s[rows, b] - c[rows, b])
    r1 = np.hypot(e[rows, a] - c[rows, a], e[rows, b] - c[rows, b])
    sweep = np.array([_arc_sweep(row) for row in arcs])
    ang = np.arctan2(s[rows, b] - c[rows, b], s[rows, a] - c[rows, a]) + sweep * t
    rad = r0 + (r1 - r0) * t
    d = np.zeros((len(arcs), 3))
    d[rows, a] = (r1 - r0) * np.cos(ang) - rad * sweep * np.sin(ang)
    d[rows, b] = (r1 - r0) * np.sin(ang) + rad * sweep * np.cos(ang)
    d[rows, nrm] = e[rows, nrm] - s[rows, nrm]
    return d
