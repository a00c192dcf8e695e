"""The path's stepover and the scallop it leaves (sim.checks.scallop)."""

import math

import numpy as np
import pytest

from sim.checks import scallop


def zigzag(step, n=8, angle_deg=0.0):
    """Tip segments (m, 6) of ``n`` passes 40 mm long, ``step`` mm apart, linked at the ends."""
    a = math.radians(angle_deg)
    u, v = np.array([math.cos(a), math.sin(a)]), np.array([-math.sin(a), math.cos(a)])
    segs = []
    for k in range(n):
        p0, p1 = k * step * v, k * step * v + 40 * u
        if k % 2:
            p0, p1 = p1, p0
        segs.append((*p0, 0.0, *p1, 0.0))
        if k < n - 1:
            segs.append((*p1, 0.0, *(p1 + step * v), 0.0))
    return np.array(segs)


@pytest.mark.parametrize("angle", [0.0, 30.0, 90.0, 135.0])
def test_a_zigzag_raster_gives_its_stepover(angle):
    r = scallop.raster_of(zigzag(0.75, angle_deg=angle))
    assert r is not None and r.passes == 8 and r.stepover == pytest.approx(0.75, abs=1e-9)
    assert abs(abs(np.dot(r.along, [math.cos(math.radians(angle)), math.sin(math.radians(angle))])) - 1) < 1e-9


def test_a_contour_is_no_raster():
    square = np.array([(0, 0, 0, 20, 0, 0), (20, 0, 0, 20, 20, 0), (20, 20, 0, 0, 20, 0), (0, 20, 0, 0, 0, 0)], float)
    assert scallop.raster_of(square) is None


def test_cusp_of_a_ball():
    assert scallop.cusp(3.0, 1.5) == pytest.approx(3 - math.sqrt(9 - 0.75**2))
    assert scallop.cusp(3.0, 7.0) == 3.0  # passes further apart than the ball: nothing meets
