"""GRBL's motion formulas (junction speed, arc segments) against analytic oracles."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.virtual.motion_math import arc_points, junction_speed_sqr
from sim.gcode.moves import Plane


def test_junction_speed_formula():
    # 90 degree corner, equal axes: a_j = a / cos(45), sin(theta/2) = sqrt(1/2)
    acc = np.array([10.0, 10, 10, np.inf, np.inf, np.inf])
    ux = np.array([1.0, 0, 0, 0, 0, 0])
    uy = np.array([0.0, 1, 0, 0, 0, 0])
    s = math.sqrt(0.5)
    expected = (10 / s) * 0.01 * s / (1 - s)
    assert junction_speed_sqr(ux, uy, acc, 0.01) == pytest.approx(expected)
    assert junction_speed_sqr(ux, ux, acc, 0.01) > 1e20  # straight on
    assert junction_speed_sqr(ux, -ux, acc, 0.01) == 0.0  # reversal


def test_arc_points_within_tolerance_and_exact_end():
    start = np.array([10.0, 0, 0, 0, 0, 0])
    end = np.array([-10.0, 0, 5, 0, 0, 0])
    pts = arc_points(start, end, np.array([0.0, 0, 0]), Plane.XY, False, 1, 0.002)
    r = np.hypot(pts[:, 0], pts[:, 1])
    np.testing.assert_allclose(r, 10.0, atol=1e-9)
    np.testing.assert_array_equal(pts[-1], end)
    assert np.all(np.diff(np.arctan2(pts[:, 1], pts[:, 0])[:-1]) > 0)  # CCW: angle grows
    # chord sagitta within tolerance
    chord = np.linalg.norm(np.diff(np.vstack([start, pts])[:, :2], axis=0), axis=1)
    sag = 10 - np.sqrt(100 - (chord / 2) ** 2)
    assert sag.max() <= 0.002 + 1e-12
    np.testing.assert_allclose(np.diff(pts[:, 2]), 5 / len(pts), atol=1e-9)  # helix: linear Z
