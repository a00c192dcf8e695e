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

from sim import dexel_store as ds
from sim.checks.arrays import distinct
from sim.checks.findings import Finding
from sim.checks.where import deepest_cut, first_contact, line_entry, tip_at
from sim.errors import InputError
from sim.gcode.moves import MoveKind, Plane

#: move kinds that move the tool
MOTION_KINDS = (MoveKind.RAPID, MoveKind.FEED, MoveKind.ARC_CW, MoveKind.ARC_CCW, MoveKind.PROBE)
AXES = "XYZABC"
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


def _runs_of(ids: np.ndarray) -> list[slice]:
    """Slices of ``ids`` split where the ids stop being consecutive."""
    if ids.size == 0:
        return []
    d = np.diff(ids)
    cuts = [0, *(np.nonzero((d < 0) | (d > 1))[0] + 1).tolist(), int(ids.size)]
    return [slice(a, b) for a, b in zip(cuts[:-1], cuts[1:])]


def _where(lines) -> str:
    return f"line {lines[0]}" if len(lines) == 1 else f"lines {lines[0]}-{lines[-1]}"


def travel_limits(moves: np.ndarray, limits: dict, move_ids=None, chord: float = 0.01) -> list[Finding]:
    """Controlled-point positions outside the machine's travel.

    ``limits``: axis letter -> (min, max) machine coords. Lines are checked at both ends,
    arcs along the arc (within ``chord``). One finding per run of consecutive offending
    moves and axis side, at the move furthest past the limit, with that distance as
    ``depth`` (what :func:`merge_findings` makes of one finding per move).
    """
    moves = np.asarray(moves)
    ids = move_ids_of(moves, move_ids)
    out: list[Finding] = []
    axes = [(axis, AXES.index(axis.upper()), lo, hi) for axis, (lo, hi) in limits.items()]
    if not axes:
        return out
    motion_rows = np.nonzero(is_motion(moves))[0]
    if any(ax < 3 for _, ax, _, _ in axes):
        p0, p1, row = path_polyline(moves, chord, which="machine")
    for axis, ax, lo, hi in axes:
        if ax < 3:
            v0, v1, vrow = p0[:, ax], p1[:, ax], row
            pts0, pts1 = p0, p1
        else:  # rotary axes move linearly between the row's ends
            v0 = moves["start"][motion_rows, ax]
            v1 = moves["end"][motion_rows, ax]
            vrow = motion_rows
            pts0 = moves["start"][motion_rows, :3]
            pts1 = moves["end"][motion_rows, :3]
        for side, lim in (("-", lo), ("+", hi)):
            past0, past1 = (lim - v0, lim - v1) if side == "-" else (v0 - lim, v1 - lim)
            past = np.maximum(past0, past1)
            bad = np.nonzero(past > 0)[0]
            if bad.size == 0:
                continue
            # each offending row's piece furthest past the limit (the first of equals)
            o = np.lexsort((-past[bad], vrow[bad]))
            q_sorted = bad[o]
            first = np.ones(q_sorted.size, bool)
            first[1:] = vrow[q_sorted][1:] != vrow[q_sorted][:-1]
            worst_q = q_sorted[first]
            worst_k = vrow[worst_q]
            name = f"{axis}{'min' if side == '-' else 'max'}"
            for run in _runs_of(ids[worst_k]):
                qs, ks = worst_q[run], worst_k[run]
                w = int(np.argmax(past[qs]))
                q, k = int(qs[w]), int(ks[w])
                pos = pts1[q] if past1[q] >= past0[q] else pts0[q]
                lines = distinct(moves["line"][ks]).tolist()
                msg = (f"travel limit: {name} {lim:g} exceeded by {float(past[q]):.3f} at line "
                       f"{int(moves['line'][k])}")
                if ks.size > 1:
                    msg += f" ({_where(lines)}, {ks.size} moves)"
                out.append(Finding(
                    kind="travel_limit", line=int(moves["line"][ks[0]]), worst_line=int(moves["line"][k]),
                    lines=tuple(lines), stage=int(ids[k]),
                    stages=tuple(ids[ks].tolist()), position=tuple(pos), depth=float(past[q]),
                    message=msg, detail={"group": f"{axis}{side}", "axis": axis, "limit": lim},
                ))
    return out


# --- spindle --------------------------------------------------------------------------------

def _stopped(moves: np.ndarray) -> np.ndarray:
    """bool (n,): rows run with the spindle stopped."""
    return (moves["spindle_dir"] == 0) | (moves["spindle"] <= 0)


def spindle_off_from(moves: np.ndarray, move_ids=None, carry=None):
    """Per row, int64 (n, 2): for a row run with the spindle stopped, ``(move id, line)``:
    the first row of its stopped span and the line of the last row run with the spindle
    on before it (0: none, it was never started) - the M5 (or S0) lies after that line, and
    the table has no row of its own for it; for a row run with the spindle on, ``(0, its
    line)``. ``carry``: the last row's pair of the previous batch (None: no batch before)."""
    moves = np.asarray(moves)
    ids = move_ids_of(moves, move_ids)
    stopped = _stopped(moves)
    out = np.zeros((len(moves), 2), np.int64)
    cur = carry if carry is not None and carry[0] else None
    last_on = int(carry[1]) if carry is not None else 0
    for k in range(len(moves)):  # spans are few; rows are walked once
        if not stopped[k]:
            cur = None
            last_on = int(moves["line"][k])
            out[k] = (0, last_on)
            continue
        if cur is None:
            cur = (int(ids[k]), last_on)
        out[k] = cur
    return out


def spindle_stopped_cutting(moves: np.ndarray, removed, move_ids=None, min_volume: float = 1e-6,
                            carry=None, cut=None, grid=None) -> list[Finding]:
    """Moves that removed (or would remove) material with the spindle stopped.

    ``removed``: float64 (n,) mm^3 per row (from ``Cutter.cut_moves`` or
    ``probe_moves``). Rapids are left to the rapid check. Every hit names its cause, the
    span of rows run with the spindle stopped (``detail["cause"]``: after which line it
    stopped, or that it never started; ``carry``: the last row's pair of the previous
    batch, see :func:`spindle_off_from`), so that :func:`merge_findings` makes one finding of a
    program that never starts the spindle, not one per move. Position: with ``cut`` (the
    batch's CutResult) and ``grid`` (the model after it), where the move first met
    material (:func:`sim.checks.where.first_contact`); else the move's end.
    """
    moves = np.asarray(moves)
    ids = move_ids_of(moves, move_ids)
    removed = np.asarray(removed, np.float64)
    bad = np.nonzero(_stopped(moves) & (removed > min_volume) & is_motion(moves)
                     & (moves["kind"] != int(MoveKind.RAPID)))[0]
    if bad.size == 0:
        return []
    span = spindle_off_from(moves, ids, carry)
    out = []
    for k in bad:
        tip = _met_at(moves, k, first_contact, cut, grid)
        first_id, on_line = (int(v) for v in span[k])
        since = f"spindle off after line {on_line}" if on_line > 0 else "spindle off: never started"
        out.append(Finding(kind="spindle_stopped_cutting", line=int(moves["line"][k]), stage=int(ids[k]),
                           position=tuple(tip), volume=float(removed[k]),
                           detail={"cause": since, "off_from_move": first_id}))
    return out


def _met_at(moves, k, where, cut, grid) -> np.ndarray:
    """``where(moves, k, cut, grid)`` (a :mod:`sim.checks.where` point) when the cut is
    known and the move changed a ray, else row ``k``'s end tip."""
    met = where(moves, k, cut, grid) if cut is not None and grid is not None else None
    return tip_at(moves, k) if met is None else met


# --- depth of cut and plunges -------------------------------------------------------------

#: lower-envelope shapes with a closed form (anything else uses the sampled envelope)
SHAPE_TABLE, SHAPE_BALL, SHAPE_FLAT = 0, 1, 2  # literal ints: numba folds them


@nb.njit(cache=True, inline="always", error_model="numpy")
def _env(d, inv_dstep, env_h):
    # the tool's lower envelope at distance d from the axis (linear in the table)
    nenv = env_h.size
    f = d * inv_dstep
    m = int(f)
    if m >= nenv - 1:
        return env_h[nenv - 1]
    return env_h[m] + (env_h[m + 1] - env_h[m]) * (f - m)


@nb.njit(cache=True, error_model="numpy")
def _piece_frames(p0, p1):
    """Per straight tip piece (m, 3) -> (m, 8) float64: start x y z (the lower end's z
    for a vertical piece), unit XY direction ux uy, slope dz/dxy, sin of the descent
    angle, XY length (0 for a vertical piece)."""
    out = np.empty((p0.shape[0], 8))
    for q in range(p0.shape[0]):
        x0, y0, z0 = p0[q, 0], p0[q, 1], p0[q, 2]
        dx, dy, dz = p1[q, 0] - x0, p1[q, 1] - y0, p1[q, 2] - z0
        ell = np.sqrt(dx * dx + dy * dy)
        if ell > 1e-9:
            out[q, 3] = dx / ell
            out[q, 4] = dy / ell
            out[q, 5] = dz / ell
            out[q, 6] = dz / np.sqrt(ell * ell + dz * dz)
            out[q, 7] = ell
        else:  # vertical: the lowest tip position is all that counts
            z0 = min(z0, z0 + dz)
            out[q, 3] = 1.0
            out[q, 4] = 0.0
            out[q, 5] = 0.0
            out[q, 6] = 0.0
            out[q, 7] = 0.0
        out[q, 0] = x0
        out[q, 1] = y0
        out[q, 2] = z0
    return out


@nb.njit(cache=True, inline="always", error_model="numpy")
def _bottom(shape, rx, ry, z0, ux, uy, m, sin_t, ell, R, R2, slack, inv_dstep, env_h, h_min, monotone):
    """Lowest point of the tool over a ray for one straight piece, and the ray's squared
    XY distance to the axis path: ``(s, d2)``, ``s = inf`` when the tool misses the ray.

    ``(rx, ry)``: the ray relative to the piece's start (mm); the piece frame as made by
    :func:`_piece_frames`. Ball and flat ends are exact (the lowest point over the ray of
    the swept sphere / disc, as the cutter sweeps them); other tools try the nearest
    axis position and the lower end on the sampled envelope ``env_h``. Rays up to
    ``slack`` mm outside the tool's reach count as reached at its rim (the cutter rounds
    differently on the boundary; a ray it cut must not keep its old height here).
    """
    a = rx * ux + ry * uy       # along the piece
    e = -rx * uy + ry * ux      # across it
    ac = min(max(a, 0.0), ell) - a
    d2 = e * e + ac * ac
    qc = R2 - e * e
    if shape == SHAPE_BALL or shape == SHAPE_FLAT:
        rho = np.sqrt(max(qc, 0.0))
        s_lo = max(a - rho, 0.0)
        s_hi = min(a + rho, ell)
        if shape == SHAPE_BALL:
            s = min(max(a - rho * sin_t, s_lo), max(s_hi, s_lo))
            w = a - s
            v = z0 + m * s + R - np.sqrt(max(rho * rho - w * w, 0.0))
        else:
            v = z0 + min(m * s_lo, m * max(s_hi, s_lo))
        return (v if (qc >= -2.0 * R * slack) & (s_lo <= s_hi + slack) else np.inf), d2
    if d2 > R2 + 2.0 * R * slack:
        return np.inf, d2
    t = min(max(a, 0.0), ell)
    best = z0 + m * t + _env(np.sqrt(d2), inv_dstep, env_h)
    # an end lower than best by less than the envelope's floor cannot win; with a
    # monotone envelope only the lower end can win at all
    for c in range(2):
        if c == 0:
            if monotone and m > 0.0:
                continue
            tc = 0.0
        else:
            if monotone and m <= 0.0:
                continue
            tc = ell
        zc = z0 + m * tc
        if zc + h_min >= best:
            continue
        e2 = (a - tc) * (a - tc) + e * e
        if e2 > R2 + 2.0 * R * slack:
            continue
        z = zc + _env(np.sqrt(e2), inv_dstep, env_h)
        if z < best:
            best = z
    return best, d2


@nb.njit(cache=True, inline="always", error_model="numpy")
def _cut_run(top, r0, n, rx0, ry, sp, shape, z0, ux, uy, m, sin_t, ell, R, R2, slack, inv_dstep, env_h,
             h_min, monotone, core2):
    """Lower ``n`` consecutive rays of one grid row (``top[r0:r0 + n]``, the first at
    ``rx0, ry`` from the piece start) under one piece; ``(thickest cut, thickest cut
    within the core)``. One loop per shape, branch-free, so that it vectorises."""
    dk = 0.0
    ck = 0.0
    if shape == SHAPE_BALL:
        for q in range(n):
            v, d2 = _bottom(SHAPE_BALL, rx0 + q * sp, ry, z0, ux, uy, m, sin_t, ell, R, R2, slack, inv_dstep,
                            env_h, h_min, monotone)
            t_old = top[r0 + q]
            cut = t_old - v
            good = cut > 0.0  # False for empty rays (NaN) and rays the tool misses (inf)
            top[r0 + q] = v if good else t_old
            c = cut if good else 0.0
            dk = max(dk, c)
            ck = max(ck, c if d2 <= core2 else 0.0)
    elif shape == SHAPE_FLAT:
        for q in range(n):
            v, d2 = _bottom(SHAPE_FLAT, rx0 + q * sp, ry, z0, ux, uy, m, sin_t, ell, R, R2, slack, inv_dstep,
                            env_h, h_min, monotone)
            t_old = top[r0 + q]
            cut = t_old - v
            good = cut > 0.0
            top[r0 + q] = v if good else t_old
            c = cut if good else 0.0
            dk = max(dk, c)
            ck = max(ck, c if d2 <= core2 else 0.0)
    else:
        for q in range(n):
            v, d2 = _bottom(SHAPE_TABLE, rx0 + q * sp, ry, z0, ux, uy, m, sin_t, ell, R, R2, slack, inv_dstep,
                            env_h, h_min, monotone)
            t_old = top[r0 + q]
            cut = t_old - v
            good = cut > 0.0
            top[r0 + q] = v if good else t_old
            c = cut if good else 0.0
            dk = max(dk, c)
            ck = max(ck, c if d2 <= core2 else 0.0)
    return dk, ck


@nb.njit(cache=True, inline="always")
def _piece_box(x0, y0, sp, nu, nv, pf, q, R):
    """``(i0, i1, j0, j1)``: the grid columns and rows under piece ``q`` widened by ``R``."""
    ax, ay = pf[q, 0], pf[q, 1]
    bx = ax + pf[q, 3] * pf[q, 7]
    by = ay + pf[q, 4] * pf[q, 7]
    i0 = max(int(np.ceil((min(ax, bx) - R - x0) / sp)), 0)
    i1 = min(int(np.floor((max(ax, bx) + R - x0) / sp)), nu - 1)
    j0 = max(int(np.ceil((min(ay, by) - R - y0) / sp)), 0)
    j1 = min(int(np.floor((max(ay, by) + R - y0) / sp)), nv - 1)
    return i0, i1, j0, j1


@nb.njit(cache=True, inline="always")
def _enters(v, d2, t_old, core2):
    """A piece whose tool bottom ``v`` over a ray ``d2`` (squared) from its axis path
    cuts that ray's material (top ``t_old``, NaN empty) under the tool centre."""
    return d2 <= core2 and v < t_old


@nb.njit(cache=True, error_model="numpy")
def _entry_top(top, x0, y0, sp, nu, nv, pf, q, shape, R, R2, slack, inv_dstep, env_h, h_min, monotone, core2):
    """The highest material top (mm) that piece ``q`` cuts under the tool centre (where it
    enters material), NaN when it cuts none there; ``top`` is not changed."""
    i0, i1, j0, j1 = _piece_box(x0, y0, sp, nu, nv, pf, q, R)
    hi = np.nan
    for j in range(j0, j1 + 1):
        for i in range(i0, i1 + 1):
            r = j * nu + i
            v, d2 = _bottom(shape, x0 + i * sp - pf[q, 0], y0 + j * sp - pf[q, 1], pf[q, 2], pf[q, 3], pf[q, 4],
                            pf[q, 5], pf[q, 6], pf[q, 7], R, R2, slack, inv_dstep, env_h, h_min, monotone)
            if _enters(v, d2, top[r], core2) and not top[r] <= hi:
                hi = top[r]
    return hi


@nb.njit(cache=True, error_model="numpy")
def _engage(top, x0, y0, sp, nu, nv, pf, row, piece_ptr, shape, R, slack, env_d, env_h, core, doc, core_depth,
            entry_q, entry_top):
    """Walk the pieces in order on the top-surface heights ``top`` (nv*nu float64, NaN =
    no material), lowering it under the tool and recording per row the largest material
    thickness cut at any ray (``doc``) and at rays within ``core`` of the axis path
    (``core_depth``). Every ray under each piece's box is looked at (used without a cut
    result). ``pf``: piece frames (:func:`_piece_frames`). For an arc (more than one
    piece, ``piece_ptr`` as in :func:`_engage_changed`) the first piece that cuts under
    the tool centre and the highest top it cuts there are ``entry_q[k]``/``entry_top[k]``
    (-1 / NaN on entry: where the arc enters material)."""
    inv_dstep = 1.0 / (env_d[1] - env_d[0])
    h_min = env_h.min()
    monotone = np.all(env_h[1:] >= env_h[:-1])
    R2 = R * R
    core2 = core * core
    for q in range(pf.shape[0]):
        k = row[q]
        if entry_q[k] < 0 and piece_ptr[k + 1] - piece_ptr[k] > 1:
            t_in = _entry_top(top, x0, y0, sp, nu, nv, pf, q, shape, R, R2, slack, inv_dstep, env_h, h_min,
                              monotone, core2)
            if not np.isnan(t_in):
                entry_q[k] = q
                entry_top[k] = t_in
        i0, i1, j0, j1 = _piece_box(x0, y0, sp, nu, nv, pf, q, R)
        for j in range(j0, j1 + 1):
            if i1 < i0:
                break
            r0 = j * nu + i0
            dk, ck = _cut_run(top, r0, i1 - i0 + 1, x0 + i0 * sp - pf[q, 0], y0 + j * sp - pf[q, 1], sp,
                              shape, pf[q, 2], pf[q, 3], pf[q, 4], pf[q, 5], pf[q, 6], pf[q, 7], R, R2,
                              slack, inv_dstep, env_h, h_min, monotone, core2)
            doc[k] = max(doc[k], dk)
            core_depth[k] = max(core_depth[k], ck)


@nb.njit(cache=True, error_model="numpy")
def _engage_changed(top, x0, y0, sp, nu, nv, pf, piece_ptr, shape, R, slack, env_d, env_h, core, chg_ptr,
                    chg_rays,
                    best_buf, dmin_buf, doc, core_depth, entry_q, entry_top):
    """Like :func:`_engage`, but row ``k`` looks only at the rays its real cut changed,
    ``chg_rays[chg_ptr[k]:chg_ptr[k + 1]]`` (sorted; a ray the tool did not change lost
    nothing), and a row's cut at a ray is measured against the lowest of all its pieces
    (an arc's entry, ``entry_q``/``entry_top``, as :func:`_engage` finds it).

    ``piece_ptr`` (n_rows + 1,): row ``k``'s pieces are ``piece_ptr[k]:piece_ptr[k + 1]``.
    ``best_buf`` / ``dmin_buf`` (n_rays,) float64 scratch, NaN on entry and on return.
    """
    inv_dstep = 1.0 / (env_d[1] - env_d[0])
    h_min = env_h.min()
    monotone = np.all(env_h[1:] >= env_h[:-1])
    R2 = R * R
    core2 = core * core
    for k in range(doc.size):
        qa = piece_ptr[k]
        qb = piece_ptr[k + 1]
        ca = chg_ptr[k]
        cb = chg_ptr[k + 1]
        if qa == qb or ca == cb:
            continue
        if qb - qa == 1:  # a line: through its changed rays, a row's run at a time
            dk = doc[k]
            ck = core_depth[k]
            m = ca
            while m < cb:
                r0 = chg_rays[m]
                j = r0 // nu
                i0 = r0 - j * nu
                e = m + 1
                while e < cb and chg_rays[e] == r0 + (e - m) and i0 + (e - m) < nu:
                    e += 1
                d1, c1 = _cut_run(top, r0, e - m, x0 + i0 * sp - pf[qa, 0], y0 + j * sp - pf[qa, 1], sp,
                                  shape, pf[qa, 2], pf[qa, 3], pf[qa, 4], pf[qa, 5], pf[qa, 6], pf[qa, 7], R, R2,
                                  slack, inv_dstep, env_h, h_min, monotone, core2)
                dk = max(dk, d1)
                ck = max(ck, c1)
                m = e
            doc[k] = dk
            core_depth[k] = ck
            continue
        # chords of an arc: mark the changed rays, let every chord lower its marks
        for m in range(ca, cb):
            r = chg_rays[m]
            best_buf[r] = np.inf
            dmin_buf[r] = np.inf
        for q in range(qa, qb):
            ax, ay = pf[q, 0], pf[q, 1]
            i0, i1, j0, j1 = _piece_box(x0, y0, sp, nu, nv, pf, q, R)
            # the heights are this row's before it: the first piece cutting under the
            # centre is where the arc enters material
            entering = entry_q[k] < 0 or entry_q[k] == q
            for j in range(j0, j1 + 1):
                for i in range(i0, i1 + 1):
                    r = j * nu + i
                    if np.isnan(best_buf[r]):
                        continue
                    v, d2 = _bottom(shape, x0 + i * sp - ax, y0 + j * sp - ay, pf[q, 2], pf[q, 3], pf[q, 4],
                                    pf[q, 5], pf[q, 6], pf[q, 7], R, R2, slack, inv_dstep, env_h, h_min,
                                    monotone)
                    if v < best_buf[r]:
                        best_buf[r] = v
                    if d2 < dmin_buf[r]:
                        dmin_buf[r] = d2
                    if entering and _enters(v, d2, top[r], core2) and not top[r] <= entry_top[k]:
                        entry_q[k] = q
                        entry_top[k] = top[r]
        for m in range(ca, cb):
            r = chg_rays[m]
            best = best_buf[r]
            d2 = dmin_buf[r]
            best_buf[r] = np.nan
            dmin_buf[r] = np.nan
            t_old = top[r]
            if np.isnan(t_old) or not best < t_old:
                continue
            cut = t_old - best
            if cut > doc[k]:
                doc[k] = cut
            if d2 <= core2 and cut > core_depth[k]:
                core_depth[k] = cut
            top[r] = best


@nb.njit(cache=True)
def _resync_top(S, rays, top, mark):
    """``top[r]`` = the real model's top of every ray in ``rays`` (NaN where empty), each
    distinct ray once (``mark`` (n_rays,) float64 scratch, NaN on entry and on return)."""
    for m in range(rays.size):
        r = rays[m]
        if np.isnan(mark[r]):
            mark[r] = 0.0
            top[r] = ds.ray_top(S, r)
    for m in range(rays.size):
        mark[rays[m]] = np.nan


class Engagement:
    """Follows the top surface of the stock seen from above and measures, per move, the
    axial depth of cut (thickest column of material cut at any ray, mm) and the
    material cut under the tool centre (rays within ``core`` mm of the axis path).

    A top-view measure for monitoring (multi-segment rays count from their top): it keeps
    its own height map. Standalone, :meth:`run` walks every ray under the tool; after the
    real cut (the Checker's way) it looks only at the rays the cut changed, which costs a
    fraction of the cut. Ball and flat ends use the exact lowest point of the swept sphere
    or disc (the cutter's closed forms), other tools a sampled lower envelope.
    ``top`` is the stock's heights (``DexelGrid.top()``, (nv, nu), NaN where empty); the
    frame must look along +Z.
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
        ball = R - np.sqrt(np.maximum(R * R - self.env_d**2, 0.0))
        if np.all(self.env_h == 0.0):
            self.shape = SHAPE_FLAT
        elif np.allclose(self.env_h, ball, rtol=0.0, atol=1e-9):
            self.shape = SHAPE_BALL
        else:
            self.shape = SHAPE_TABLE
        # rays on the tool's boundary: the cutter's rounding may reach them where ours does not
        self.slack = 1e-6
        self._buf = None
        #: per row of the last :meth:`run`: the descent (deg below horizontal) of the path
        #: where it first cut under the tool centre, NaN where it did not, and for arcs the
        #: tip there ((n, 3) mm, NaN for lines and elsewhere) (:func:`entry_angles`)
        self.entry_deg = np.zeros(0)
        self.entry_at = np.zeros((0, 3))

    def run(self, moves: np.ndarray, cut=None, grid=None):
        """Advance through ``moves``; returns ``(doc, core_depth)``, float64 (n,) mm each.

        Without ``cut`` every ray under the tool is looked at. With ``cut`` (the
        :class:`sim.cut.CutResult` of cutting exactly these moves, changes recorded)
        only the rays each move really changed are, which costs a small fraction of the
        cut itself; with ``grid`` too (the grid that was cut) the heights of those rays
        are then taken from it, so the estimate follows the real model.
        """
        moves = np.asarray(moves)
        n = len(moves)
        doc = np.zeros(n)
        core = np.zeros(n)
        self.entry_deg = np.full(n, np.nan)
        self.entry_at = np.full((n, 3), np.nan)
        p0, p1, row = path_polyline(moves, self.chord, which="tip")
        if row.size == 0:
            return doc, core
        f = self.frame
        x0, y0 = float(f.origin[0]), float(f.origin[1])
        pf = _piece_frames(np.ascontiguousarray(p0), np.ascontiguousarray(p1))
        piece_ptr = np.searchsorted(row, np.arange(n + 1)).astype(np.int64)
        entry_q, entry_top = np.full(n, -1, np.int64), np.full(n, np.nan)
        if cut is None:
            _engage(self.top, x0, y0, f.spacing, f.nu, f.nv, pf, row, piece_ptr, self.shape, self.R, self.slack,
                    self.env_d, self.env_h, self.core, doc, core, entry_q, entry_top)
            self.entry_deg, self.entry_at = entry_angles(moves, p0, p1, piece_ptr, core, entry_q, entry_top)
            return doc, core
        chg_ptr = np.asarray(cut.changed_ptr, np.int64)
        chg_rays = np.asarray(cut.changed_rays, np.int64)
        if chg_ptr.size != n + 1:
            raise InputError(f"cut result covers {chg_ptr.size - 1} moves, expected {n} with changes recorded")
        arcs = bool(np.any(np.diff(piece_ptr) > 1))
        # ball and flat lines follow the cutter's own closed forms; sampled envelopes
        # and arc chords only approximate it, so those take the model's heights after
        resync = grid is not None and chg_rays.size > 0 and (self.shape == SHAPE_TABLE or arcs)
        if self._buf is None and (arcs or resync):  # per-ray scratch, only when needed
            self._buf = (np.full(f.n_rays, np.nan), np.full(f.n_rays, np.nan))
        buf = self._buf if self._buf is not None else (np.zeros(0), np.zeros(0))
        _engage_changed(self.top, x0, y0, f.spacing, f.nu, f.nv, pf, piece_ptr, self.shape, self.R, self.slack,
                        self.env_d, self.env_h, self.core, chg_ptr, chg_rays, buf[0], buf[1], doc, core, entry_q,
                        entry_top)
        if resync:
            _resync_top(grid.S, chg_rays, self.top, self._buf[0])
        self.entry_deg, self.entry_at = entry_angles(moves, p0, p1, piece_ptr, core, entry_q, entry_top)
        return doc, core


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


def entry_angles(moves, p0, p1, piece_ptr, core, entry_q, entry_top) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the descent (deg below horizontal) of the tip's path where it enters
    material under the tool centre, NaN where it cut nothing there; and for arcs the tip
    at that point ((n, 3) mm, NaN for lines).

    A line has one direction. An arc turns: its chord says nothing of how it enters (a
    full-turn helix has none, a dive and climb back a level one), so it is the tangent
    of the arc at the point where the piece ``entry_q`` that first cut under the centre
    crosses the top it cut there (``entry_top``, mm): the helix's pitch over its length
    for a helix, the circle's own slope for an arc in a vertical plane."""
    n = len(moves)
    out = np.full(n, np.nan)
    at = np.full((n, 3), np.nan)
    count = np.diff(piece_ptr)
    line = np.flatnonzero((count == 1) & (core > 0.0))
    out[line] = descent_deg(p1[piece_ptr[line]] - p0[piece_ptr[line]])
    arc = np.flatnonzero((count > 1) & (entry_q >= 0))
    if arc.size:
        q = entry_q[arc]
        z0, z1 = p0[q, 2], p1[q, 2]
        # the crossing of the entered top on the piece, by its tip's height (the start for a
        # piece that does not go down: it entered sideways)
        drop = z0 - z1
        within = np.clip(np.divide(z0 - entry_top[arc], drop, out=np.zeros(arc.size), where=drop > 0), 0.0, 1.0)
        t = (q - piece_ptr[arc] + within) / count[arc]
        out[arc] = descent_deg(arc_tangents(moves[arc], t))
        at[arc] = p0[q] + within[:, None] * (p1[q] - p0[q])
    return out, at


def depth_of_cut_of(cut) -> np.ndarray:
    """Axial depth of cut of each move, float64 (n,) mm, from a :class:`sim.cut.CutResult`
    with changes recorded: the largest ``changed_depth`` over the rays the move changed
    (how far it lowered a ray's material top, or the length it took off a ray where the
    top stayed - a cut below an overhang - or that it emptied); 0 where nothing changed.
    """
    ptr = np.asarray(cut.changed_ptr, np.int64)
    depth = np.asarray(cut.changed_depth)
    doc = np.zeros(ptr.size - 1)
    if depth.size == 0:
        return doc
    if depth.size != int(ptr[-1]):
        raise InputError(f"cut result holds {depth.size} depths for {int(ptr[-1])} changed rays")
    hit = np.nonzero(ptr[1:] > ptr[:-1])[0]
    # segments of consecutive non-empty moves tile the entries: reduceat over their starts
    doc[hit] = np.maximum.reduceat(depth, ptr[hit])
    return doc


def depth_of_cut(moves: np.ndarray, doc, limit: float, move_ids=None, cut=None, grid=None) -> list[Finding]:
    """Moves whose axial depth of cut ``doc`` (float64 (n,) mm) is over ``limit`` mm: one
    finding per run of consecutive offending moves, at the deepest (what
    :func:`merge_findings` makes of one finding per move). Position: with ``cut`` (the
    batch's CutResult) and ``grid`` (the model after it), the floor of the deepest cut of
    the deepest move (:func:`sim.checks.where.deepest_cut`); else that move's end."""
    moves = np.asarray(moves)
    ids = move_ids_of(moves, move_ids)
    doc = np.asarray(doc, np.float64)
    bad = np.nonzero(doc > limit)[0]
    out = []
    for run in _runs_of(ids[bad]):
        ks = bad[run]
        k = int(ks[int(np.argmax(doc[ks]))])
        tip = _met_at(moves, k, deepest_cut, cut, grid)
        lines = distinct(moves["line"][ks]).tolist()
        msg = f"depth of cut {float(doc[k]):.3f} mm over the {limit:g} mm limit at line {int(moves['line'][k])}"
        if ks.size > 1:
            msg += f" ({_where(lines)}, {ks.size} moves)"
        out.append(Finding(kind="depth_of_cut", line=int(moves["line"][ks[0]]), worst_line=int(moves["line"][k]),
                           lines=tuple(lines), stage=int(ids[k]),
                           stages=tuple(ids[ks].tolist()), position=tuple(tip), depth=float(doc[k]),
                           message=msg, detail={"limit": limit}))
    return out


def plunges(moves: np.ndarray, core_depth, tool, max_ramp_deg: float = 10.0, min_depth: float = 0.01,
            move_ids=None, entry_deg=None, entry_at=None, cut=None, grid=None, near: float = 0.0,
            rows=None) -> list[Finding]:
    """Entries into material steeper than ``max_ramp_deg`` (degrees below horizontal)
    that cut under the tool centre (``core_depth`` > ``min_depth`` mm), for a tool that
    does not cut at its centre (``tool.center_cutting`` False); none otherwise.
    ``entry_deg`` (n,): each row's descent where it entered material
    (:attr:`Engagement.entry_deg` of the run that measured ``core_depth``); where it is
    not given or NaN, the move's chord (right for lines only). Position: where the tip
    entered material: an arc's ``entry_at`` ((n, 3), :attr:`Engagement.entry_at`); a
    line's, with ``cut`` (the batch's CutResult) and ``grid`` (the model after it), at the
    highest top it met within ``near`` mm of its path (:func:`sim.checks.where.line_entry`);
    else the move's end. ``rows``: the rows of ``moves`` to check (default all; those
    ``tool`` cut)."""
    if getattr(tool, "center_cutting", True):
        return []
    moves = np.asarray(moves)
    ids = move_ids_of(moves, move_ids)
    s = np.array(moves["start"][:, :3], np.float64)
    e = np.array(moves["end"][:, :3], np.float64)
    chord = descent_deg(e - s)
    angle = chord if entry_deg is None else np.where(np.isnan(entry_deg), chord, entry_deg)
    bad = np.nonzero((np.asarray(core_depth) > min_depth) & (angle > max_ramp_deg) & is_motion(moves))[0]
    if rows is not None:
        bad = bad[np.isin(bad, rows)]
    out = []
    for k in bad:
        tip = entry_at[k] if entry_at is not None else np.full(3, np.nan)
        if not np.isfinite(tip).all():
            tip = _met_at(moves, k, lambda m, k_, c, g: line_entry(m, k_, c, g, near), cut, grid)
        out.append(Finding(kind="non_center_cutting_plunge", line=int(moves["line"][k]), stage=int(ids[k]),
                           position=tuple(tip), depth=float(core_depth[k]),
                           message=(f"plunge at {angle[k]:.0f} deg into material with a tool that does not "
                                    f"cut at its centre, line {int(moves['line'][k])}"),
                           detail={"angle_deg": float(angle[k])}))
    return out
