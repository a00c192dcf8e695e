"""Arcs: centre from I J K or R (LinuxCNC's and GRBL's rules), and arc geometry of move rows.

Planes are taken as ordered axis triples (first, second, normal): G17 (X, Y, Z),
G18 (Z, X, Y), G19 (Y, Z, X). Each is right-handed, so counter-clockwise (G3) is a
positive rotation about the normal axis in every plane, as LinuxCNC defines it.
"""

from __future__ import annotations

import math

import numpy as np

from sim.gcode.errors import LineError
from sim.gcode.moves import MoveKind

#: (first, second, normal) axis indices for Plane 0 (XY), 1 (XZ), 2 (YZ)
PLANE_AXES_BY_CODE = ((0, 1, 2), (2, 0, 1), (1, 2, 0))
FULL_CIRCLE_EPS = 1e-9  # rad: a sweep smaller than this is a full circle (start == end)
TWO_PI = 2.0 * math.pi

# rs274's arc tolerances (interp_internal.hh), in program units: inches in G20, mm in G21.
#: how far R may fall short of half the chord (arc_data_r), and the smallest I J K radius
RADIUS_TOLERANCE = {"in": 0.00005, "mm": 0.00005 * 25.4}
#: how much the end's radius may differ from the start's (arc_data_ijk): 2 * 0.01 * sqrt 2
#: mm, 2 * 0.001 * sqrt 2 in, what rounding the end and centre to 0.01 mm / 0.001 in makes;
#: more only when it is within SPIRAL_RELATIVE_TOLERANCE of the radius, and never more than
#: SPIRAL_CAP times the absolute tolerance. The arc is then a spiral to the programmed end.
SPIRAL_ABS_TOLERANCE = {"in": 2 * 0.001 * math.sqrt(2), "mm": 2 * 0.01 * math.sqrt(2)}
SPIRAL_RELATIVE_TOLERANCE = 0.001
SPIRAL_CAP = 100.0


def arc_rows_geometry(moves: np.ndarray):
    """Geometry of arc rows.

    Parameters
    ----------
    moves : MOVE_DTYPE array (n,), rows of kind ARC_CW / ARC_CCW.

    Returns
    -------
    radius : (n,) float64 mm; start_angle : (n,) rad; sweep : (n,) rad (+ CCW);
    axes : (n, 3) int64 (first, second, normal) axis indices.
    """
    n = len(moves)
    axes = np.array(PLANE_AXES_BY_CODE, dtype=np.int64)[moves["plane"].astype(np.int64)]
    rows = np.arange(n)
    s = moves["start"][:, :3]
    e = moves["end"][:, :3]
    c = moves["center"]
    s1 = s[rows, axes[:, 0]] - c[rows, axes[:, 0]]
    s2 = s[rows, axes[:, 1]] - c[rows, axes[:, 1]]
    e1 = e[rows, axes[:, 0]] - c[rows, axes[:, 0]]
    e2 = e[rows, axes[:, 1]] - c[rows, axes[:, 1]]
    radius = np.hypot(s1, s2)
    a0 = np.arctan2(s2, s1)
    a1 = np.arctan2(e2, e1)
    cw = moves["kind"] == MoveKind.ARC_CW
    turns = np.maximum(moves["turns"].astype(np.float64), 1.0)
    d = a1 - a0
    ccw_sweep = np.mod(d, TWO_PI)
    ccw_sweep = np.where(ccw_sweep < FULL_CIRCLE_EPS, TWO_PI, ccw_sweep)
    cw_sweep = np.mod(-d, TWO_PI)
    cw_sweep = np.where(cw_sweep < FULL_CIRCLE_EPS, TWO_PI, cw_sweep)
    sweep = np.where(cw, -(cw_sweep + (turns - 1) * TWO_PI), ccw_sweep + (turns - 1) * TWO_PI)
    return radius, a0, sweep, axes


def _sweep(a0: float, a1: float, cw: bool, turns: int) -> float:
    d = (-(a1 - a0)) % TWO_PI if cw else (a1 - a0) % TWO_PI
    if d < FULL_CIRCLE_EPS:
        d = TWO_PI
    d += (turns - 1) * TWO_PI
    return -d if cw else d


def end_radius(moves: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """Distance (n,) mm from the centre to the end of arc rows, in their plane (``axes`` as
    :func:`arc_rows_geometry` gives them). rs274 accepts an end a little off the start's
    circle; the arc is then a spiral whose radius goes evenly from start to end."""
    rows = np.arange(len(moves))
    e, c = moves["end"], moves["center"]
    return np.hypot(e[rows, axes[:, 0]] - c[rows, axes[:, 0]], e[rows, axes[:, 1]] - c[rows, axes[:, 1]])


def _spiral_error(r1: float, r2: float, unit: str) -> str | None:
    """Why rs274 refuses an I J K arc whose start and end radii (program units) are ``r1``
    and ``r2`` (interp_arc.cc arc_data_ijk), or None when it takes it."""
    abs_err = abs(r1 - r2)
    rel_err = abs_err / max(r1, r2)
    tol = SPIRAL_ABS_TOLERANCE[unit]
    if abs_err > SPIRAL_CAP * tol:
        return f"they differ by {abs_err:.4g} {unit}, more than {SPIRAL_CAP * tol:.3g} {unit} (LinuxCNC's limit)"
    if rel_err > SPIRAL_RELATIVE_TOLERANCE and abs_err > tol:
        return (f"they differ by {abs_err:.4g} {unit} ({100 * rel_err:.3f} %), more than {tol:.3g} {unit} "
                f"and {100 * SPIRAL_RELATIVE_TOLERANCE:g} % of the radius (LinuxCNC's limits)")
    return None


def arc_motion(it, cw: bool, explicit: bool, words, cols, used, has_axes: bool) -> None:
    """Execute G2/G3 for interpreter ``it`` (see :mod:`sim.gcode.interpreter`)."""
    from sim.gcode.interpreter import PLANE_AXES, PLANE_OFFSET_WORDS

    grbl = it.grbl
    if it.arc_not_allowed:
        raise LineError("the move just after G40 (cutter compensation off) must be straight, not an arc",
                        cols.get("G", 1))
    a1, a2, ax = PLANE_AXES[it.plane]
    n1, n2, nn = PLANE_OFFSET_WORDS[it.plane]
    plane_name = {170: "XY", 180: "XZ", 190: "YZ"}[it.plane]
    letters = "XYZABC"
    col = min([cols[k] for k in "XYZABCIJKR@^" if k in cols] or [1])
    if grbl and not has_axes:
        return  # GRBL: an arc with no axis words moves nothing (its I/J/K stay unused)
    if grbl and letters[a1] not in words and letters[a2] not in words:
        raise LineError(f"G{3 if not cw else 2} needs at least one {plane_name}-plane axis word", col, 32)
    f = it.factor
    cur = it.work()
    target = it._axis_values(words, cols, used)
    has_r = "R" in words
    offs = [k for k in "IJK" if k in words]
    if has_r and offs:
        raise LineError("arc given both R and I/J/K words: use one form", cols["R"], 36)
    if nn in words and not has_r:
        raise LineError(f"{nn} word given for an arc in the {plane_name} plane", cols[nn], 36)
    if not has_r and n1 not in words and n2 not in words:
        raise LineError(
            f"arc needs R or the {n1}/{n2} centre words in the {plane_name} plane (G{17 + it.plane // 10 - 17})",
            col, 35 if grbl else None)
    turns = 1
    if "P" in words:
        if grbl:
            raise LineError("GRBL arcs take no P word", cols["P"], 36)
        p = words["P"]
        if p != int(p) or p < 1:
            raise LineError(f"arc P (turns) must be a positive integer, got {p:g}", cols["P"])
        if p > it.limits.max_arc_turns:
            raise LineError(f"arc P{p:.0f}: at most {it.limits.max_arc_turns} turns in one arc", cols["P"])
        turns = int(p)
        used.add("P")
    unit = "in" if it.units == 200 else "mm"
    s1, s2 = cur[a1], cur[a2]
    e1, e2 = target[a1], target[a2]
    u = f  # reporting in program units
    if has_r:
        used.add("R")
        R = words["R"] * f
        if grbl:
            x, y = e1 - s1, e2 - s2
            if x == 0.0 and y == 0.0:
                raise LineError("R arc with the same start and end point", cols["R"], 33)
            # gcode.c: 4 R^2 < d^2 (R0 included) is "arc radius error" (34), not 33
            if R == 0.0:
                raise LineError("arc radius is zero", cols["R"], 34)
            h = 4.0 * R * R - x * x - y * y
            if h < 0.0:
                raise LineError(f"arc radius R{words['R']:g} is too small to reach the end point", cols["R"], 34)
            h = -math.sqrt(h) / math.hypot(x, y)
            if not cw:
                h = -h
            if R < 0:
                h = -h
            c1 = s1 + 0.5 * (x - y * h)
            c2 = s2 + 0.5 * (y + x * h)
        else:
            if e1 == s1 and e2 == s2:
                raise LineError("R arc with the same start and end point (a full circle needs I/J/K)", cols["R"])
            absr = abs(R)
            m1, m2 = (e1 + s1) / 2.0, (e2 + s2) / 2.0
            half = math.hypot(m1 - e1, m2 - e2)
            if (half - absr) / u > RADIUS_TOLERANCE[unit]:
                raise LineError(
                    f"arc radius R{words['R']:g} is too small to reach the end point "
                    f"(half the chord is {half / u:.5f}; LinuxCNC lets R fall short of it by "
                    f"{RADIUS_TOLERANCE[unit]:g} {unit} at most)", cols["R"])
            if absr == 0.0 or half / absr > 1.0 - 1e-12:
                half = absr
            if (cw and R > 0) or (not cw and R < 0):
                theta = math.atan2(e2 - s2, e1 - s1) - math.pi / 2
            else:
                theta = math.atan2(e2 - s2, e1 - s1) + math.pi / 2
            t2 = math.asin(half / absr) if absr > 0 else 0.0
            off = absr * math.cos(t2)
            c1 = m1 + off * math.cos(theta)
            c2 = m2 + off * math.sin(theta)
    else:
        o1 = words.get(n1, 0.0) * f
        o2 = words.get(n2, 0.0) * f
        used.update(k for k in (n1, n2) if k in words)
        if it.arc_distance == 901 and not grbl and not (n1 in words and n2 in words):
            # G90.1: a missing centre word is not 0 but an error (rs274)
            raise LineError(f"{n1 if n1 not in words else n2} word missing in absolute center arc (G90.1)", col)
        if it.arc_distance == 901:
            c1, c2 = o1, o2
        else:
            c1, c2 = s1 + o1, s2 + o2
        r1 = math.hypot(c1 - s1, c2 - s2)
        r2 = math.hypot(c1 - e1, c2 - e2)
        if grbl:
            if r1 == 0.0:
                raise LineError("arc radius is zero", col, 33)
            dr = abs(r2 - r1)
            if dr > 0.005 and (dr > 0.5 or dr > 0.001 * r1):
                raise LineError(f"arc end is not on the circle (radii {r1:.4f} and {r2:.4f} mm)", col, 33)
        else:
            if min(r1, r2) / u < RADIUS_TOLERANCE[unit]:
                raise LineError("zero radius arc", col)
            why = _spiral_error(r1 / u, r2 / u, unit)
            if why is not None:
                L = letters
                raise LineError(
                    "radius to end of arc differs from radius to start: "
                    f"start=({L[a1]}{s1 / u:.4f},{L[a2]}{s2 / u:.4f}) center=({L[a1]}{c1 / u:.4f},{L[a2]}{c2 / u:.4f}) "
                    f"end=({L[a1]}{e1 / u:.4f},{L[a2]}{e2 / u:.4f}) r1={r1 / u:.4f} r2={r2 / u:.4f}: {why}", col)
    if it.comp_engine is not None:
        it.comp_engine.arc(cw, target, (c1, c2), turns, col, words)
        return
    end = it.to_machine(target)
    off = it.offsets()
    center = [0.0, 0.0, 0.0]
    center[a1] = c1 + off[a1]
    center[a2] = c2 + off[a2]
    center[ax] = it.pos[ax]
    a_start = math.atan2(s2 - c2, s1 - c1)
    a_end = math.atan2(e2 - c2, e1 - c1)
    sweep = _sweep(a_start, a_end, cw, turns)
    r = math.hypot(s1 - c1, s2 - c2)
    length = math.hypot(r * sweep, target[ax] - cur[ax])
    feed, inv = it._feed_rate(col, words, length)
    start = list(it.pos)
    it.emit(MoveKind.ARC_CW if cw else MoveKind.ARC_CCW, start, end, tuple(center), turns, feed, inv)
    it.pos = end
