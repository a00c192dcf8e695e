"""sim.correct: the gouge of a pose and of a move on the rays, the guide vector of Huang &
Oliver's eq. 7, and the recursive subdivision of their Fig. 14, against analytic parts."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.checks.error_map import DesignModel
from sim.correct import kernels as K
from sim.correct.gouge import GougeProbe
from sim.frame import Frame
from sim.tolerance import Tolerance
from sim.tools import parse_tool_spec

TOL = Tolerance(gouge=0.002)
ALPHA = math.radians(30.0)


def sheet(sign: float, h: float = 0.0):
    """An open sheet over X, Y in [-10, 10]: ``z = h + sign * |y| tan(30 deg)`` (a V valley
    for sign +1, a roof for sign -1)."""
    import trimesh

    t = math.tan(ALPHA) * 10.0 * sign
    v = np.array([[-10, -10, h + t], [10, -10, h + t], [-10, 0, h], [10, 0, h], [-10, 10, h + t], [10, 10, h + t]],
                 float)
    f = np.array([[0, 1, 3], [0, 3, 2], [2, 3, 5], [2, 5, 4]])
    return trimesh.Trimesh(v, f, process=False)


def probe_of(mesh, spacing=0.05):
    frame = Frame.top(-10, -10, 10, 10, spacing)
    return GougeProbe(DesignModel(frame, mesh), TOL)


def test_a_flat_tool_below_a_flat_top_is_lifted_along_the_axis_by_its_gouge():
    import trimesh

    frame = Frame.top(-10, -10, 10, 10, 0.1)
    probe = GougeProbe(DesignModel(frame, trimesh.creation.box(bounds=[[-8, -8, -5], [8, 8, 0]])), TOL)
    tool = parse_tool_spec("flat:6")
    g = probe.pose(tool, (0, 0, -0.3), TOL.gouge)
    assert g.depth == pytest.approx(0.3, abs=1e-9) and g.rays > 100
    gx, gy, gz = g.guide
    assert abs(gx) < 1e-9 and abs(gy) < 1e-9 and gz > 0  # eq. 7: the top face's normals
    p = np.array([0.0, 0.0, -0.3])
    steps = K.correct_pose(probe.params(tool), p, probe.frame_tuple, probe.arrays, 0.001, probe.search, 30,
                           np.empty(K.G_SIZE))
    assert steps == 1 and np.allclose(p, [0, 0, 0], atol=1e-9)


def test_a_ball_in_a_v_valley_is_lifted_to_where_it_touches_both_flanks():
    probe = probe_of(sheet(+1.0))
    tool = parse_tool_spec("ball:8")
    p = np.array([0.0, 0.0, 0.0])  # tip in the valley: the 8 mm ball cuts both flanks
    assert probe.pose(tool, p, TOL.gouge).depth > 0.3
    K.correct_pose(probe.params(tool), p, probe.frame_tuple, probe.arrays, 0.001, probe.search, 30,
                   np.empty(K.G_SIZE))
    exact = 4.0 * (1.0 / math.cos(ALPHA) - 1.0)  # the tip of a ball resting on both flanks
    # the flanks' guide vectors cancel across the valley: the ball goes straight up
    assert abs(p[0]) < 1e-9 and abs(p[1]) < 0.01
    assert exact - 0.003 < p[2] < exact + 0.01
    assert probe.pose(tool, p, 0.001).rays == 0


def test_a_move_over_a_ridge_is_split_where_its_sweep_dips_and_every_piece_is_clean():
    probe = probe_of(sheet(-1.0, h=2.0))
    tool = parse_tool_spec("ball:6")
    tp = probe.params(tool)
    # both ends rest on the roof's flanks; the straight move between them cuts the ridge
    c = 3.0 / math.cos(ALPHA)  # the ball centre above a flank, along Z
    y0 = -4.0
    p0 = np.array([0.0, y0, 2.0 - abs(y0) * math.tan(ALPHA) + c - 3.0 + 0.0005])
    q = p0 * np.array([1.0, -1.0, 1.0])
    assert probe.pose(tool, p0, TOL.gouge).rays == 0 and probe.pose(tool, q, TOL.gouge).rays == 0
    dip = probe.move(tool, p0, q, TOL.gouge)
    assert dip.depth > 0.5 and abs(dip.point[1]) < 1.0
    out = np.empty((256, 3))
    stats = np.zeros(4, np.int64)
    n, status = K.correct_move(tp, p0.copy(), q.copy(), probe.frame_tuple, probe.arrays, TOL.gouge, 0.001,
                               probe.search, 0.02, 30, out, stats)
    assert status == K.OK and n >= 2 and stats[2] >= 1
    pts = np.vstack([p0, out[:n]])
    assert np.allclose(pts[-1], q)  # the end was clean: it stays
    for a, b in zip(pts[:-1], pts[1:]):
        assert probe.move(tool, a, b, 0.001).rays == 0
    # the split lands on the ridge, the ball resting on its crest
    top = pts[np.argmax(pts[:, 2])]
    assert abs(top[1]) < 0.05 and top[2] == pytest.approx(2.0, abs=0.01)


def test_a_move_that_does_not_gouge_is_left_alone():
    probe = probe_of(sheet(+1.0))
    tool = parse_tool_spec("ball:6")
    p0 = np.array([-5.0, 5.0, 10.0])
    q = np.array([5.0, 5.0, 10.0])
    out = np.empty((16, 3))
    stats = np.zeros(4, np.int64)
    n, status = K.correct_move(probe.params(tool), p0, q, probe.frame_tuple, probe.arrays, TOL.gouge, 0.001,
                               probe.search, 0.02, 30, out, stats)
    assert (n, status) == (1, K.OK) and np.array_equal(out[0], q) and not stats.any()


def test_lowest_instance_is_where_the_ball_passes_the_ray_lowest():
    tp = GougeProbe.params(parse_tool_spec("ball:6"))
    # a level move along X: the ray at x = 3 sees the ball lowest when the tip passes x = 3
    assert K.lowest_instance(tp, 0, 0, 0, 10, 0, 0, 3.0, 1.0) == pytest.approx(0.3, abs=1e-6)
    # descending: later (deeper) instances win as far as the ball still reaches the ray
    assert K.lowest_instance(tp, 0, 0, 0, 10, 0, -1, 3.0, 0.0) > 0.3


def _rows(*specs):
    """A move table of feed rows (start, end, tool_length, rotary end (A, B, C))."""
    from sim.gcode.moves import MoveKind, empty_moves

    moves = empty_moves(len(specs))
    for k, (a, b, length, abc) in enumerate(specs):
        moves["kind"][k] = MoveKind.FEED
        moves["line"][k] = k + 1
        moves["start"][k, :3] = a
        moves["end"][k, :3] = b
        moves["end"][k, 3:] = abc
        if k:
            moves["start"][k, 3:] = moves["end"][k - 1, 3:]
        moves["tool_length"][k] = length
    return moves


def test_a_row_a_rotary_axis_turns_is_left_as_written_and_a_3axis_one_is_corrected():
    """A plunge 1 mm under the valley's floor turned by A (and the lift turning A back)
    is left alone (``turned``); the same plunge unturned is reshaped. The tool length
    change between them (the tip 5 mm lower, no motion) is followed: the row after it
    starts where the table says and adds no path."""
    from sim.correct.path import correct_moves

    probe = probe_of(sheet(+1.0))
    tool = parse_tool_spec("ball:6")
    moves = _rows(([-5, 0, 5], [-1, 0, -1], 0.0, (10, 0, 0)),
                  ([-1, 0, -1], [-1, 0, 20], 0.0, (0, 0, 0)),   # A back to 0: turned at its start
                  ([-1, 0, 20], [5, 0, 20], 5.0, (0, 0, 0)),    # G43: tip 15
                  ([5, 0, 20], [8, 0, 4], 5.0, (0, 0, 0)))      # tip Z-1
    c = correct_moves(moves, probe, {}, tool, TOL)
    assert c.turned.tolist() == [True, True, False, False]
    assert c.changed.tolist() == [False, False, False, True] and not c.refused
    assert np.array_equal(c.start[:3], c.orig_start[:3]) and np.array_equal(c.end[:3], c.orig_end[:3])
    path = np.vstack([c.start[3], c.points[3]])
    reshaped = np.linalg.norm(np.diff(path, axis=0), axis=1).sum() - np.linalg.norm(c.orig_end[3] - c.orig_start[3])
    assert c.added_length == pytest.approx(reshaped, abs=1e-9)


def test_turned_rows_read_the_machine_as_the_check_does():
    """With the machine's kinematics, a row is turned where the check turns it: by the
    machine angle (the row's plus the work offset's), only on the machine's rotaries. A
    program read without a machine leaves every row naming A, B or C alone."""
    from sim.correct.path import turned_rows
    from sim.kinematics import FourthAxis, Trivial

    moves = _rows(([-5, 0, 5], [-1, 0, 5], 0.0, (0, 0, 0)),      # A 0 in work coordinates
                  ([-1, 0, 5], [3, 0, 5], 0.0, (0, 10, 0)))      # B, which an xyza machine lacks
    assert turned_rows(moves).tolist() == [False, True]
    # the work offset turns A by 30 degrees: every row is turned on the xyza machine
    assert turned_rows(moves, FourthAxis("A"), origin=(0, 0, 0, 30, 0, 0)).tolist() == [True, True]
    assert turned_rows(moves, FourthAxis("A")).tolist() == [False, False]
    assert turned_rows(moves, Trivial()).tolist() == [False, False]
