"""G5 / G5.1 B-splines, run on an interpreter (:mod:`sim.gcode.interpreter`) as feed chords."""

from __future__ import annotations

import math

import numpy as np

from sim.gcode.errors import LineError
from sim.gcode.moves import MoveKind

SPLINE_CHORD = 0.001  # mm: G5/G5.1 chords stay this close to the curve


def spline(it, motion: int, end: list, words, cols, used, col: int) -> None:
    """G5 (cubic) / G5.1 (quadratic) B-spline in the XY plane on interpreter ``it``, emitted as
    feed chords to ``end`` (machine mm/deg).

    The chords stay within ``SPLINE_CHORD`` mm of the curve: a Bezier segment of
    parameter length h deviates at most ``max|B''| h^2 / 8`` from its chord.
    """
    if it.plane != 170:
        raise LineError(f"G{motion / 10:g} splines need the XY plane (G17)", col)
    if it.comp != 400:
        raise LineError("splines cannot be used with cutter compensation on", col)
    f = it.factor
    p0 = np.array(it.work()[:2])
    p3 = np.array(it.work_of(end)[:2])
    if motion == 51:
        if "I" not in words and "J" not in words:
            raise LineError("G5.1 needs I and J (control point offsets)", col)
        c = p0 + np.array([words.get("I", 0.0), words.get("J", 0.0)]) * f
        used.update(k for k in ("I", "J") if k in words)
        bound = float(np.linalg.norm(2.0 * (p0 - 2.0 * c + p3)))
        ctrl = (p0, c, p3)
    else:
        if "P" not in words or "Q" not in words:
            raise LineError("G5 needs P and Q (second control point offsets)", col)
        if ("I" in words) != ("J" in words):
            raise LineError("G5 needs both I and J or neither", col)
        if "I" in words:
            c1 = p0 + np.array([words["I"], words["J"]]) * f
        elif it.last_spline_ctrl is not None:
            c1 = 2.0 * p0 - it.last_spline_ctrl
        else:
            raise LineError("the first G5 of a spline needs I and J", col)
        c2 = p3 + np.array([words["P"], words["Q"]]) * f
        used.update(k for k in ("I", "J", "P", "Q") if k in words)
        bound = 6.0 * max(float(np.linalg.norm(p0 - 2 * c1 + c2)), float(np.linalg.norm(c1 - 2 * c2 + p3)))
        ctrl = (p0, c1, c2, p3)
        it.last_spline_ctrl = c2
    n = max(1, int(math.ceil(math.sqrt(bound / (8.0 * SPLINE_CHORD)))))
    n = min(n, 10000)
    t = np.linspace(0.0, 1.0, n + 1)[1:, None]
    if len(ctrl) == 3:
        pts = (1 - t) ** 2 * ctrl[0] + 2 * (1 - t) * t * ctrl[1] + t**2 * ctrl[2]
    else:
        pts = ((1 - t) ** 3 * ctrl[0] + 3 * (1 - t) ** 2 * t * ctrl[1] + 3 * (1 - t) * t**2 * ctrl[2]
               + t**3 * ctrl[3])
    start_work = it.work()
    end_work = it.work_of(end)
    for k in range(n):
        w = list(end_work)
        frac = (k + 1) / n
        for i in range(2, 6):
            w[i] = start_work[i] + (end_work[i] - start_work[i]) * frac
        w[0], w[1] = float(pts[k, 0]), float(pts[k, 1])
        if k == n - 1:
            w = end_work
        target = it.to_machine(w)
        feed, inv = it._feed_rate(col, words, math.dist(it.pos[:3], target[:3]))
        it._line_to(target, MoveKind.FEED, feed, inv)
