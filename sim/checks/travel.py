"""Travel limits: where the controlled point (what the controller calls MPos, machine
coordinates in mm / deg) goes outside the machine's travel.
"""

from __future__ import annotations

import math

import numpy as np

from sim.checks.arrays import distinct, runs_of
from sim.checks.findings import Finding, line_span
from sim.checks.motion import is_motion, move_ids_of, path_polyline
from sim.errors import InputError

AXES = "XYZABC"


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
            for run in runs_of(ids[worst_k]):
                qs, ks = worst_q[run], worst_k[run]
                w = int(np.argmax(past[qs]))
                q, k = int(qs[w]), int(ks[w])
                pos = pts1[q] if past1[q] >= past0[q] else pts0[q]
                lines = distinct(moves["line"][ks]).tolist()
                msg = (f"travel limit: {name} {lim:g} exceeded by {float(past[q]):.3f} at line "
                       f"{int(moves['line'][k])}")
                if ks.size > 1:
                    msg += f" ({line_span(lines)}, {ks.size} moves)"
                out.append(Finding(
                    kind="travel_limit", line=int(moves["line"][ks[0]]), worst_line=int(moves["line"][k]),
                    lines=tuple(lines), stage=int(ids[k]),
                    stages=tuple(ids[ks].tolist()), position=tuple(pos), depth=float(past[q]),
                    message=msg, detail={"group": f"{axis}{side}", "axis": axis, "limit": lim},
                ))
    return out
