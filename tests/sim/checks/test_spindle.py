"""Cutting with the spindle stopped, and the cause each finding names."""

import numpy as np

from sim.checks import spindle
from tests.sim.checks.helpers import polyline


def test_spindle_stopped_cutting_needs_removed_material_and_a_stopped_spindle():
    m = polyline([(0, 0, 5), (0, 0, -1), (10, 0, -1), (20, 0, -1)])
    m["spindle_dir"][1:] = 0
    out = spindle.spindle_stopped_cutting(m, np.array([0.0, 4.0, 0.0]))
    assert [(f.kind, f.line, f.volume) for f in out] == [("spindle_stopped_cutting", 20, 4.0)]


def test_spindle_stopped_names_where_it_stopped_or_that_it_never_started():
    m = polyline([(0, 0, 5), (0, 0, 1), (10, 0, 1), (10, 0, -1), (20, 0, -1)])
    m["spindle_dir"][2:] = 0  # M5 between line 20 (the last move it ran for) and line 30
    (f,) = spindle.spindle_stopped_cutting(m, np.array([0.0, 0.0, 0.0, 4.0]))
    assert f.line == 40 and f.detail["cause"] == "spindle off after line 20"
    m["spindle_dir"][:] = 0  # never started
    (f,) = spindle.spindle_stopped_cutting(m, np.array([0.0, 0.0, 0.0, 4.0]))
    assert f.detail["cause"] == "spindle off: never started"
    # the same across batches: the carry holds the last line it ran for
    m["spindle_dir"][:2] = 1
    carry = tuple(spindle.spindle_off_from(m[:3])[-1])
    (f,) = spindle.spindle_stopped_cutting(m[3:], np.array([4.0]), move_ids=[4], carry=carry)
    assert f.detail["cause"] == "spindle off after line 20" and f.detail["off_from_move"] == 3
