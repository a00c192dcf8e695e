"""The path geometry the motion checks share."""

import math

import numpy as np
import pytest

from sim.checks import motion
from sim.gcode.moves import MoveKind, Plane
from tests.sim.checks.helpers import table


def test_arc_points_stay_on_the_circle_within_chord():
    m = table([(MoveKind.ARC_CW, (10, 0, 0), (10, 0, -3), {"center": (0, 0, 0), "plane": int(Plane.XY), "turns": 2})])
    pts = motion.arc_points(m[0], 0.001)
    r = np.hypot(pts[:, 0], pts[:, 1])
    assert np.allclose(r, 10.0)
    mid = (pts[1:] + pts[:-1]) / 2
    assert (10.0 - np.hypot(mid[:, 0], mid[:, 1])).max() <= 0.001 + 1e-9
    ang = np.unwrap(np.arctan2(pts[:, 1], pts[:, 0]))
    assert ang[-1] - ang[0] == pytest.approx(-4 * math.pi)  # two full clockwise turns
    assert pts[-1, 2] == pytest.approx(-3.0)
