"""GRBL 1.1's motion formulas the virtual machine plans with (:mod:`drivers.virtual.machine`):
the per-axis limit of a value along a direction, the junction-deviation corner speed and
the chord segments of an arc. Pure functions of numpy arrays; positions mm (A B C
degrees, treated like mm), speeds mm/s, accelerations mm/s^2.
"""

from __future__ import annotations

import math

import numpy as np

from sim.gcode.moves import Plane

#: GRBL's ARC_ANGULAR_TRAVEL_EPSILON (rad)
ARC_ANGLE_EPS = 5e-7
#: lengths below this (mm) are no motion (an arc of a smaller radius is a point: straight
#: to its end); the machine's planner and stepper use it too
LEN_EPS = 1e-9

_HUGE_SPEED_SQR = 1e30


def limit_by_axis(limits: np.ndarray, unit: np.ndarray) -> float:
    """GRBL ``limit_value_by_axis_maximum``: the largest value along ``unit`` whose
    per-axis components stay within ``limits`` (both shape (6,))."""
    nz = np.abs(unit) > 1e-12
    if not nz.any():
        return float("inf")
    return float(np.min(limits[nz] / np.abs(unit[nz])))


def junction_speed_sqr(prev_unit: np.ndarray, unit: np.ndarray, accel: np.ndarray, deviation: float) -> float:
    """Maximum speed squared (mm^2/s^2) through the corner between two unit vectors,
    GRBL 1.1's junction-deviation formula. ``accel`` is per-axis mm/s^2, shape (6,)."""
    cos_theta = -float(np.dot(prev_unit, unit))
    if cos_theta > 0.999999:  # full reversal
        return 0.0
    if cos_theta < -0.999999:  # straight on
        return _HUGE_SPEED_SQR
    jvec = unit - prev_unit
    jvec = jvec / np.linalg.norm(jvec)
    a = limit_by_axis(accel, jvec)
    sin_half = math.sqrt(0.5 * (1.0 - cos_theta))
    return max(0.0, a * deviation * sin_half / (1.0 - sin_half))



def arc_points(start: np.ndarray, end: np.ndarray, center: np.ndarray, plane: int, clockwise: bool,
               turns: int, tolerance: float) -> np.ndarray:
    """End points of the chord segments of an arc (GRBL ``mc_arc``), shape (n, 6), mm;
    the chord error stays within ``tolerance`` (mm).

    ``start``/``end`` shape (6,) machine coords; ``center`` shape (3,) (X Y Z). The axis
    normal to ``plane`` and the A B C axes move linearly (helix). The last point is
    exactly ``end``.
    """
    ax0, ax1, lin = {Plane.XY: (0, 1, 2), Plane.XZ: (2, 0, 1), Plane.YZ: (1, 2, 0)}[Plane(plane)]
    c0, c1 = float(center[ax0]), float(center[ax1])
    r0, r1 = start[ax0] - c0, start[ax1] - c1
    rt0, rt1 = end[ax0] - c0, end[ax1] - c1
    radius = math.hypot(r0, r1)
    travel = math.atan2(r0 * rt1 - r1 * rt0, r0 * rt0 + r1 * rt1)
    if clockwise:
        if travel >= -ARC_ANGLE_EPS:
            travel -= 2 * math.pi
    elif travel <= ARC_ANGLE_EPS:
        travel += 2 * math.pi
    extra = (turns - 1) * 2 * math.pi
    travel += -extra if clockwise else extra
    if radius <= LEN_EPS:
        return end[None, :].copy()
    denom = math.sqrt(tolerance * (2 * radius - tolerance)) if 2 * radius > tolerance else radius
    # GRBL floors this count, which lets the chord error exceed $12 by ~1 %; ceil keeps it within
    n = int(math.ceil(abs(0.5 * travel * radius) / denom))
    n = max(n, 1)
    k = np.arange(1, n + 1) / n
    ang = travel * k
    pts = start[None, :] + (end - start)[None, :] * k[:, None]  # linear axes
    cos_a, sin_a = np.cos(ang), np.sin(ang)
    pts[:, ax0] = c0 + r0 * cos_a - r1 * sin_a
    pts[:, ax1] = c1 + r0 * sin_a + r1 * cos_a
    pts[-1] = end
    return pts
