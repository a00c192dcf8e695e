"""Checks on the motion itself: travel limits, cutting with the spindle stopped, axial
depth of cut, and plunges with a tool that does not cut at its centre.

All positions are machine coordinates in mm. Travel limits apply to the controlled point
(what the controller calls MPos); depth of cut and plunges to the tool tip
(``sim.gcode.moves.tip_positions``).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from sim.checks.findings import Finding
from sim.errors import InputError
from sim.gcode.moves import MoveKind, Plane

#: move kinds that move the tool
MOTION_KINDS = (MoveKind.RAPID, MoveKind.FEED, MoveKind.ARC_CW, MoveKind.ARC_CCW, MoveKind.PROBE)
AXES = "XYZABC"
# plane -> (first, second, normal) axes such that a positive angle is counter-clockwise
_PLANE_AXES = {int(Plane.XY): (0, 1, 2), int(Plane.XZ): (2, 0, 1), int(Plane.YZ): (1, 2, 0)}


def is_motion(moves: np.ndarray) -> np.ndarray:
    """bool (n,): rows that move the tool."""
    return np.isin(moves["kind"], np.array([int(k) for k in MOTION_KINDS], np.uint8))


def move_ids_of(moves: np.ndarray, move_ids=None) -> np.ndarray:
    """int64 (n,): the id of each row (default row index + 1, as ``Cutter`` numbers them)."""
    if move_ids is None:
        return np.arange(1, len(moves) + 1, dtype=np.int64)
    ids = np.asarray(move_ids, np.int64)
    if ids.shape != (len(moves),):
        raise InputError(f"expected {len(moves)} move ids, got {ids.shape}")
    return ids


# --- geometry of the path -------------------------------------------------------------

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
    t1 = math.atan2(end[b] - c[b], end[a] - c[a])
    turns = max(int(row["turns"]), 1)
    if int(row["kind"]) == MoveKind.ARC_CCW:
        sweep = (t1 - t0) % (2 * math.pi)
        if sweep <= 1e-12:
            sweep = 2 * math.pi
        sweep += 2 * math.pi * (turns - 1)
    else:
        sweep = (t0 - t1) % (2 * math.pi)
        if sweep <= 1e-12:
            sweep = 2 * math.pi
        sweep = -(sweep + 2 * math.pi * (turns - 1))
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
    arc = motion & np.isin(moves["kind"], [int(MoveKind.ARC_CW), int(MoveKind.ARC_CCW)])
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


# --- travel limits ----------------------------------------------------------------------

def parse_limits(text: str) -> dict[str, tuple[float, float]]:
    """``"X0:300,Y0:200,Z-100:0"`` -> ``{"X": (0, 300), ...}`` (machine coords, mm / deg).

    Raises :class:`InputError` naming the bad item.
    """
    out: dict[str, tuple[float, float]] = {}
    for item in str(text).split(","):
        item = item.strip()
        if not item:
            continue
        axis = item[0].upper()
        try:
            lo, hi = (float(v) for v in item[1:].split(":"))
        except ValueError:
            raise InputError(f"limits item {item!r}: expected AXISmin:max, e.g. X0:300",
                             where="--limits") from None
        if axis not in AXES or not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise InputError(f"limits item {item!r}: expected an axis of {AXES} and min <= max",
                             where="--limits")
        out[axis] = (lo, hi)
    if not out:
        raise InputError("no limits given; expected e.g. X0:300,Y0:200,Z-100:0", where="--limits")
    return out


def travel_limits(moves: np.ndarray, limits: dict, move_ids=None, chord: float = 0.01) -> list[Finding]:
    """Controlled-point positions outside the machine's travel.

    ``limits``: axis letter -> (min, max) machine coords. Lines are checked at both ends,
    arcs along the arc (within ``chord``). One finding per run of consecutive offending
    moves and axis side, with the distance past the limit as ``depth``.
    """
    moves = np.asarray(moves)
    ids = move_ids_of(moves, move_ids)
    p0, p1, row = path_polyline(moves, chord, which="machine")
    motion_rows = np.nonzero(is_motion(moves))[0]
    out: list[Finding] = []
    for axis, (lo, hi) in limits.items():
        ax = AXES.index(axis.upper())
        if ax < 3:
            v0, v1, vrow = p0[:, ax], p1[:, ax], row
            pts0, pts1 = p0, p1
        else:  # rotary axes move linearly between the row's ends
            v0 = moves["start"][motion_rows, ax]
            v1 = moves["end"][motion_rows, ax]
            vrow = motion_rows
            pts0 = np.array(moves["start"][motion_rows, :3])
            pts1 = np.array(moves["end"][motion_rows, :3])
        for side, past0, past1 in (("-", lo - v0, lo - v1), ("+", v0 - hi, v1 - hi)):
            past = np.maximum(past0, past1)
            bad = np.nonzero(past > 0)[0]
            worst: dict[int, int] = {}  # row -> its piece furthest past the limit
            for q in bad:
                k = int(vrow[q])
                if k not in worst or past[q] > past[worst[k]]:
                    worst[k] = q
            for k, q in worst.items():
                at_end = past1[q] >= past0[q]
                pos = pts1[q] if at_end else pts0[q]
                lim = lo if side == "-" else hi
                out.append(Finding(
                    kind="travel_limit", line=int(moves["line"][k]), stage=int(ids[k]),
                    position=tuple(pos), depth=float(past[q]),
                    message=(f"travel limit: {axis}{'min' if side == '-' else 'max'} {lim:g} exceeded by "
                             f"{float(past[q]):.3f} at line {int(moves['line'][k])}"),
                    detail={"group": f"{axis}{side}", "axis": axis, "limit": lim},
                ))
    return out


# --- spindle --------------------------------------------------------------------------------

def spindle_stopped_cutting(moves: np.ndarray, removed, move_ids=None, min_volume: float = 1e-6) -> list[Finding]:
    """Moves that removed (or would remove) material with the spindle stopped.

    ``removed``: float64 (n,) mm^3 per row (from ``Cutter.cut_moves`` or
    ``probe_moves``). Rapids are left to the rapid check.
    """
    moves = np.asarray(moves)
    ids = move_ids_of(moves, move_ids)
    removed = np.asarray(removed, np.float64)
    stopped = (moves["spindle_dir"] == 0) | (moves["spindle"] <= 0)
    bad = np.nonzero(stopped & (removed > min_volume) & is_motion(moves)
                     & (moves["kind"] != MoveKind.RAPID))[0]
    out = []
    for k in bad:
        tip = np.array(moves["end"][k, :3], np.float64)
        tip[2] -= moves["tool_length"][k]
        out.append(Finding(kind="spindle_stopped_cutting", line=int(moves["line"][k]), stage=int(ids[k]),
                           position=tuple(tip), volume=float(removed[k])))
    return out


# --- depth of cut and plunges -------------------------------------------------------------

@nb.njit(cache=True)
def _engage(top, x0, y0, sp, nu, nv, p0, p1, row, env_d, env_h, R, core, n_rows, doc, core_depth):
    """Walk the pieces in order on the top-surface heights ``top`` (nv*nu float64, NaN =
    no material), lowering it under the tool's lower envelope ``env_h(env_d)`` and
    recording per row the largest material thickness cut at any ray (``doc``) and at
    rays within ``core`` of the axis path (``core_depth``)."""
    nenv = env_d.size
    dstep = env_d[1] - env_d[0]
    for q in range(p0.shape[0]):
        k = row[q]
        ax, ay, az = p0[q, 0], p0[q, 1], p0[q, 2]
        bx, by, bz = p1[q, 0], p1[q, 1], p1[q, 2]
        dx, dy = bx - ax, by - ay
        L2 = dx * dx + dy * dy
        i0 = max(int(np.ceil((min(ax, bx) - R - x0) / sp)), 0)
        i1 = min(int(np.floor((max(ax, bx) + R - x0) / sp)), nu - 1)
        j0 = max(int(np.ceil((min(ay, by) - R - y0) / sp)), 0)
        j1 = min(int(np.floor((max(ay, by) + R - y0) / sp)), nv - 1)
        for j in range(j0, j1 + 1):
            py = y0 + j * sp
            for i in range(i0, i1 + 1):
                r = j * nu + i
                t_old = top[r]
                if np.isnan(t_old):
                    continue
                px = x0 + i * sp
                # lowest tool point over this ray: the nearest axis position, and the ends
                best = np.inf
                dmin = np.inf
                for c in range(3):
                    if c == 0:
                        if L2 > 0.0:
                            t = ((px - ax) * dx + (py - ay) * dy) / L2
                            t = min(max(t, 0.0), 1.0)
                        else:
                            t = 1.0 if bz < az else 0.0
                    elif c == 1:
                        t = 0.0
                    else:
                        t = 1.0
                    cx = ax + t * dx
                    cy = ay + t * dy
                    cz = az + t * (bz - az)
                    d = np.sqrt((px - cx) ** 2 + (py - cy) ** 2)
                    if d < dmin:
                        dmin = d
                    if d > R:
                        continue
                    f = d / dstep
                    m = int(f)
                    if m >= nenv - 1:
                        h = env_h[nenv - 1]
                    else:
                        h = env_h[m] + (env_h[m + 1] - env_h[m]) * (f - m)
                    if cz + h < best:
                        best = cz + h
                if best == np.inf or best >= t_old:
                    continue
                cut = t_old - best
                if cut > doc[k]:
                    doc[k] = cut
                if dmin <= core and cut > core_depth[k]:
                    core_depth[k] = cut
                top[r] = best


class Engagement:
    """Follows the top surface of the stock seen from above and measures, per move, the
    axial depth of cut (thickest column of material cut at any ray, mm) and the
    material cut under the tool centre (rays within ``core`` mm of the axis path).

    A top-view estimate for monitoring (multi-segment rays count from their top): it keeps
    its own height map, so it can run before or after the real cut. ``top`` is the stock's
    heights (``DexelGrid.top()``, (nv, nu), NaN where empty); the frame must look along +Z.
    """

    def __init__(self, frame, top, tool, chord: float = 0.01):
        if not frame.is_top:
            raise InputError("depth-of-cut and plunge checks need a top-view grid (rays along +Z)")
        self.frame = frame
        self.top = np.array(top, np.float64).reshape(-1)
        self.tool = tool
        self.chord = chord
        R = float(tool.cutting_radius)
        self.R = R
        self.env_d = np.linspace(0.0, R, 257)
        self.env_h = np.nan_to_num(np.asarray(tool.lowest_height(self.env_d), np.float64), nan=0.0)
        self.core = max(0.75 * frame.spacing, 0.05 * R)

    def run(self, moves: np.ndarray):
        """Advance through ``moves``; returns ``(doc, core_depth)``, float64 (n,) mm each."""
        moves = np.asarray(moves)
        n = len(moves)
        doc = np.zeros(n)
        core = np.zeros(n)
        p0, p1, row = path_polyline(moves, self.chord, which="tip")
        if row.size:
            f = self.frame
            _engage(self.top, float(f.origin[0]), float(f.origin[1]), f.spacing, f.nu, f.nv,
                    np.ascontiguousarray(p0), np.ascontiguousarray(p1), row, self.env_d, self.env_h,
                    self.R, self.core, n, doc, core)
        return doc, core


def depth_of_cut(moves: np.ndarray, doc, limit: float, move_ids=None) -> list[Finding]:
    """Moves whose axial depth of cut ``doc`` (float64 (n,) mm) is over ``limit`` mm."""
    moves = np.asarray(moves)
    ids = move_ids_of(moves, move_ids)
    out = []
    for k in np.nonzero(np.asarray(doc) > limit)[0]:
        tip = np.array(moves["end"][k, :3], np.float64)
        tip[2] -= moves["tool_length"][k]
        out.append(Finding(kind="depth_of_cut", line=int(moves["line"][k]), stage=int(ids[k]),
                           position=tuple(tip), depth=float(doc[k]),
                           message=f"depth of cut {float(doc[k]):.3f} mm over the {limit:g} mm limit "
                                   f"at line {int(moves['line'][k])}",
                           detail={"limit": limit}))
    return out


def plunges(moves: np.ndarray, core_depth, tool, max_ramp_deg: float = 10.0, min_depth: float = 0.01,
            move_ids=None) -> list[Finding]:
    """Entries into material steeper than ``max_ramp_deg`` (degrees below horizontal)
    that cut under the tool centre (``core_depth`` > ``min_depth`` mm), for a tool that
    does not cut at its centre (``tool.center_cutting`` False); none otherwise."""
    if getattr(tool, "center_cutting", True):
        return []
    moves = np.asarray(moves)
    ids = move_ids_of(moves, move_ids)
    s = np.array(moves["start"][:, :3], np.float64)
    e = np.array(moves["end"][:, :3], np.float64)
    drop = s[:, 2] - e[:, 2]
    run = np.hypot(e[:, 0] - s[:, 0], e[:, 1] - s[:, 1])
    angle = np.degrees(np.arctan2(drop, run))
    bad = np.nonzero((np.asarray(core_depth) > min_depth) & (drop > 0) & (angle > max_ramp_deg)
                     & is_motion(moves))[0]
    out = []
    for k in bad:
        tip = e[k].copy()
        tip[2] -= moves["tool_length"][k]
        out.append(Finding(kind="non_center_cutting_plunge", line=int(moves["line"][k]), stage=int(ids[k]),
                           position=tuple(tip), depth=float(core_depth[k]),
                           message=(f"plunge at {angle[k]:.0f} deg into material with a tool that does not "
                                    f"cut at its centre, line {int(moves['line'][k])}"),
                           detail={"angle_deg": float(angle[k])}))
    return out
