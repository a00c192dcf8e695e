"""Arcs -> chords within a chordal tolerance, vectorised."""

from __future__ import annotations

import math

import numpy as np

from sim.gcode.arcs import arc_rows_geometry, end_radius
from sim.gcode.moves import MOVE_DTYPE, MoveKind
from sim.tolerance import DEFAULT, Tolerance

MAX_CHORD_ANGLE = math.pi / 2  # never more than a quarter turn per chord, whatever the tolerance


def chord_counts(radius: np.ndarray, sweep: np.ndarray, tolerance: float) -> np.ndarray:
    """Chords per arc so the sagitta ``r (1 - cos(dtheta / 2))`` stays <= ``tolerance``.

    radius (n,) mm, sweep (n,) rad (signed) -> (n,) int64 >= 1.
    """
    ratio = np.clip(1.0 - tolerance / np.maximum(radius, 1e-300), -1.0, 1.0)
    step = np.minimum(2.0 * np.arccos(ratio), MAX_CHORD_ANGLE)
    step = np.where(step > 0, step, MAX_CHORD_ANGLE)
    return np.maximum(np.ceil(np.abs(sweep) / step - 1e-12).astype(np.int64), 1)


def arc_points(moves: np.ndarray, t: np.ndarray, src: np.ndarray) -> np.ndarray:
    """Machine positions (k, 6) at parameters ``t`` (k,) in [0, 1] of arc rows ``moves[src]``."""
    arcs = moves[src]
    radius, a0, sweep, axes = arc_rows_geometry(arcs)
    # an end off the start's circle (rs274 takes a little): a spiral, the radius going evenly
    # from the start's to the end's, as LinuxCNC's motion makes it
    radius = radius + t * (end_radius(arcs, axes) - radius)
    ang = a0 + t * sweep
    pts = arcs["start"] + (arcs["end"] - arcs["start"]) * t[:, None]  # normal axis and ABC: linear
    rows = np.arange(len(arcs))
    pts[rows, axes[:, 0]] = arcs["center"][rows, axes[:, 0]] + radius * np.cos(ang)
    pts[rows, axes[:, 1]] = arcs["center"][rows, axes[:, 1]] + radius * np.sin(ang)
    return pts


def linearize(moves: np.ndarray, tolerance=None) -> np.ndarray:
    """Replace every arc row by FEED chords within ``tolerance`` of the arc.

    Parameters
    ----------
    moves : MOVE_DTYPE array (n,)
    tolerance : float (mm), :class:`sim.tolerance.Tolerance` (its ``chord``) or None (default).

    Returns
    -------
    MOVE_DTYPE array (m,), m >= n: non-arc rows unchanged, arcs as consecutive FEED rows
    keeping their file, line, feed, spindle, tool ...; the last chord ends exactly at the
    arc's end.
    """
    if tolerance is None:
        tol = DEFAULT.chord
    elif isinstance(tolerance, Tolerance):
        tol = tolerance.chord
    else:
        tol = float(tolerance)
    if not tol > 0:
        raise ValueError(f"chordal tolerance must be > 0 mm, got {tol}")
    moves = np.asarray(moves, dtype=MOVE_DTYPE)
    is_arc = (moves["kind"] == MoveKind.ARC_CW) | (moves["kind"] == MoveKind.ARC_CCW)
    if not is_arc.any():
        return moves.copy()
    counts = np.ones(len(moves), dtype=np.int64)
    radius, _a0, sweep, _axes = arc_rows_geometry(moves[is_arc])
    counts[is_arc] = chord_counts(radius, sweep, tol)
    src = np.repeat(np.arange(len(moves)), counts)
    out = moves[src].copy()
    # k-th chord (1-based) of its arc
    first = np.cumsum(counts) - counts
    k = np.arange(len(src)) - first[src] + 1
    sel = is_arc[src]
    if sel.any():
        s_src = src[sel]
        n = counts[s_src].astype(np.float64)
        t1 = k[sel] / n
        t0 = (k[sel] - 1) / n
        p1 = arc_points(moves, t1, s_src)
        p0 = arc_points(moves, t0, s_src)
        last = k[sel] == counts[s_src]
        p1[last] = moves["end"][s_src[last]]
        p0[k[sel] == 1] = moves["start"][s_src[k[sel] == 1]]
        out["start"][sel] = p0
        out["end"][sel] = p1
        out["kind"][sel] = MoveKind.FEED
        out["center"][sel] = np.nan
        out["turns"][sel] = 0
    return out
