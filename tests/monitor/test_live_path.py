"""The live path between two polls: where the inserted program corners go and which row
owns what the tool's pose at a change of row touches.

The bug these pin down: a dry run of the two-station job sometimes reported a 1.5 mm^3
``rapid_into_stock`` on the retract after a slot (line 12, just before the G55 switch; or
line 17 at the second station) when two polls straddled the slot's end. The corner
inserted between them sat an ulp short of the program's corner (an interpolated
deviation), so the feed into it missed the three rays at exactly the tool radius from
the slot end (X+3, Y+-3: 3 x 0.25 mm^2 x 2 mm = 1.5 mm^3) and the retract, polled exactly
at X15, cut them. With a stale .var entry for G55 the deviation changes at the switch and
the same interpolation moved that corner by millimetres. The kernel itself decides those
tangent rays with arithmetic relative to a move's start, so even an exact corner could
leave them to the retract: the arrival pose is cut as the arriving row's own.

Everything here is driven by hand-made machine states (no controller, no clock).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from drivers.state import MachineState, RunState
from monitor.job import load_job
from monitor.predict import LiveChecks, arrival_poses
from monitor.program_moves import load_moves
from monitor.session import Session, hold_still_axes

DATA = Path(__file__).resolve().parent.parent / "data" / "fixtures2"
TWO = DATA / "two_station.toml"
#: machine offsets not the job's: G54 10 mm off in each axis, G55 35 mm right of G54 (not 40)
STALE_VAR = "5221 -210\n5222 -90\n5223 -40\n5241 -175\n5242 -90\n5243 -40\n"
SLOT_END_X = 15.0   # station 1, G54 (line 11 feeds there, line 12 retracts)
RADIUS = 3.0        # flat:6
FLOOR = -2.0


@pytest.fixture(scope="module")
def two():
    job = load_job(TWO)
    moves, program = load_moves(job)
    return job, moves, program


def _row(moves, line: int) -> int:
    return int(np.nonzero(moves["line"] == line)[0][0])


def _state(controller_moves, t: float, own_xyz, line: int) -> MachineState:
    """What a controller running ``controller_moves`` reports with the tip at ``own_xyz``
    (the row's own work coordinates) on ``line``: mpos = work + WCO (tool length in it)."""
    w = np.asarray(controller_moves["wco"][_row(controller_moves, line)], np.float64)
    mpos = np.concatenate([np.asarray(own_xyz, np.float64) + w[:3], w[3:]])
    return MachineState(t=t, mpos=tuple(mpos), wco=tuple(w), state=RunState.RUN, feed=600.0,
                        spindle=10000.0, line=line)


def _follow(session, controller_moves, polls) -> list[dict]:
    found = []
    for t, xyz, line in polls:
        found += session.step(_state(controller_moves, t, xyz, line)).new_findings
    return found


def _top_at(grid, x: float, y: float) -> float:
    f = grid.frame
    i, j = int(round((x - f.origin[0]) / f.spacing)), int(round((y - f.origin[1]) / f.spacing))
    return float(grid.top()[j, i])


# --- the regression, as the dry run polled it ---------------------------------------------------

def test_polls_straddling_the_slot_end_report_no_rapid_into_stock(two):
    """The two polls of the failing dry run (virtual clock at 23 Hz): on the feed 0.0125 mm
    before the slot end, then 0.018 mm up the retract. Before the fix: rapid_into_stock,
    line 12, 1.5 mm^3 at (18, 8, 0)."""
    job, moves, program = two
    s = Session(job, moves, program=program)
    polls = [(0.0, (5, 8, FLOOR), 11), (0.5, (10, 8, FLOOR), 11),
             (0.998, (14.987495466005157, 8, FLOOR), 11),
             (1.05, (SLOT_END_X, 8, -1.9822674211413869), 12), (1.2, (SLOT_END_X, 8, 5.0), 12)]
    assert _follow(s, moves, polls) == []
    # the feed cut the whole slot end, the rays at exactly the tool radius included
    for x, y in ((SLOT_END_X + RADIUS, 8.0), (SLOT_END_X, 8.0 - RADIUS), (SLOT_END_X, 8.0 + RADIUS)):
        assert _top_at(s.live, x, y) == FLOOR, (x, y)
    assert _top_at(s.live, SLOT_END_X + RADIUS + s.live.frame.spacing, 8.0) == 0.0


@pytest.mark.parametrize("x_before", np.linspace(14.95, 14.99995, 13))
def test_any_poll_before_the_slot_end_then_up_the_retract(two, x_before):
    """Wherever the last poll on the feed falls, the retract after it cuts nothing."""
    job, moves, program = two
    s = Session(job, moves, program=program)
    polls = [(0.0, (5, 8, FLOOR), 11), (0.5, (10, 8, FLOOR), 11), (0.99, (x_before, 8, FLOOR), 11),
             (1.0, (SLOT_END_X, 8, -1.997), 12), (1.01, (SLOT_END_X, 8, -1.99), 12),
             (1.1, (SLOT_END_X, 8, 5.0), 12)]
    assert _follow(s, moves, polls) == []


# --- the corners between two polls ----------------------------------------------------------------

def test_corner_is_the_programs_corner_when_the_machine_is_on_the_program(two):
    job, moves, program = two
    tip = np.array([SLOT_END_X, 8, -1.98])
    for x_before in np.linspace(14.9, 14.9999, 25):
        s = Session(job, moves, program=program)
        s.step(_state(moves, 0.0, (x_before, 8, FLOOR), 11))
        sync = s.sync.update(tip, t=0.05, line=12)   # the second poll's sync, not yet cut
        pts, rows = s._travelled(s._prev_tip, tip, sync)
        assert pts.shape == (3, 3) and list(moves["line"][rows]) == [11, 12]
        assert pts[1].tolist() == [SLOT_END_X, 8.0, FLOOR], x_before   # bit for bit


def test_corner_before_a_work_offset_switch_stays_above_the_first_station(two, tmp_path):
    """The machine's G55 is 35 mm right of G54, the job's .var says 40: the deviation is 0
    on the station-1 retract and -5 mm on the rapid to station 2. The corner at the top of
    the retract is where the machine turned, (15, 8, 5), not 15 + a share of -5 mm."""
    job, moves, program = two
    var = tmp_path / "machine.var"
    var.write_text(STALE_VAR)
    machine_moves, _ = load_moves(replace(job, var_file=var))
    s = Session(job, moves, program=program)
    found = _follow(s, machine_moves, [(0.0, (5, 8, FLOOR), 11), (0.5, (SLOT_END_X, 8, 4.0), 12)])
    last = s.last_sync
    assert last.line == 12 and found == []
    # halfway along the rapid to station 2 (line 14, G55 own coordinates X -5 .. 5): the
    # sync matches the work position the controller reports, not yet cut
    now = _state(machine_moves, 0.6, (0.0, 8, 5.0), 14)
    sync = s.sync.update(np.array([0.0, 8, 5.0]), t=now.t, line=now.line)
    assert sync.line == 14
    # the model tip: the machine's G55 zero is 5 mm left of the job's
    tip = s.tip(now, sync.row)
    np.testing.assert_allclose(tip, [35.0, 8, 5.0], atol=1e-9)
    pts, rows = s._travelled(np.array([SLOT_END_X, 8, 4.0]), tip, sync)
    assert list(moves["line"][rows]) == [12, 14]
    assert pts[1].tolist() == [SLOT_END_X, 8.0, 5.0]


def test_stale_g55_offset_slot_end_at_the_second_station(two, tmp_path):
    """The failing dry run's polls at station 2 with the stale G55 (model X 50 = 15 + 35)."""
    job, moves, program = two
    var = tmp_path / "machine.var"
    var.write_text(STALE_VAR)
    machine_moves, _ = load_moves(replace(job, var_file=var))
    s = Session(job, moves, program=program)
    polls = [(0.0, (5, 8, FLOOR), 11), (0.5, (SLOT_END_X, 8, FLOOR), 11), (0.6, (SLOT_END_X, 8, 5.0), 12),
             (1.0, (5, 8, 5.0), 14), (1.2, (5, 8, FLOOR), 15), (1.5, (10, 8, FLOOR), 16),
             (1.9, (14.9953266017973, 8, FLOOR), 16), (1.95, (SLOT_END_X, 8, -1.9634601422892501), 17),
             (2.0, (SLOT_END_X, 8, -1.8951107875395437), 17), (2.2, (SLOT_END_X, 8, 5.0), 17)]
    assert _follow(s, machine_moves, polls) == []
    assert _top_at(s.live, 50.0 + RADIUS, 8.0) == FLOOR


def test_hold_still_axes():
    # feed along X, retract along Z, rapid along X: corners interpolated a little off
    pts = np.array([[14.9, 8.0, -2.0], [14.999999999999998, 8.0, -1.999999999999994],
                    [15.2, 8.0, 5.0000001], [30.0, 8.0, 5.0]])
    moving = np.array([[True, False, False], [False, False, True], [True, False, False]])
    out = hold_still_axes(pts, moving)
    x = pts[1, 0]   # no poll on the X run of the two corners: its first corner's
    np.testing.assert_array_equal(out, [[14.9, 8, -2], [x, 8, -2], [x, 8, 5], [30, 8, 5]])
    # an axis held from end to end keeps the interpolation unless the polls agree
    pts2 = np.array([[0.0, 1.0, 0.0], [1.0, 1.2, 0.0], [2.0, 1.4, 0.0]])
    still = np.array([[True, False, False], [True, False, False]])
    np.testing.assert_array_equal(hold_still_axes(pts2, still), pts2)
    pts2[2, 1] = 1.0
    assert hold_still_axes(pts2, still)[1, 1] == 1.0
    # no corner: nothing to do
    np.testing.assert_array_equal(hold_still_axes(pts[:2], moving[:1]), pts[:2])


# --- the arrival pose -------------------------------------------------------------------------------

def test_arrival_poses():
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [1, 0, 1], [2, 0, 1]])
    p, r = arrival_poses(pts, np.array([4, 5, 5]))
    np.testing.assert_array_equal(p, [[0, 0, 0], [1, 0, 0], [1, 0, 0], [1, 0, 1], [2, 0, 1]])
    np.testing.assert_array_equal(r, [4, 4, 5, 5])
    p, r = arrival_poses(pts, np.array([4, 5, 6]), arrived_row=3)
    np.testing.assert_array_equal(r, [3, 4, 4, 5, 5, 6])
    np.testing.assert_array_equal(p[[0, 2, 4, 6]], pts)
    np.testing.assert_array_equal(p[[1, 3, 5]], pts[:3])
    p, r = arrival_poses(pts, np.array([7, 7, 7]), arrived_row=7)
    assert np.array_equal(p, pts) and r.tolist() == [7, 7, 7]


def test_feed_into_a_corner_owns_its_end_pose(two):
    """A feed from anywhere to the slot end, then straight up as a rapid, in one batch: the
    rapid removes nothing, whatever the feed's start (the kernel decides the rays at
    exactly the tool radius from the end relative to the start)."""
    job, moves, program = two
    base = Session(job, moves, program=program)
    feed, rapid = _row(moves, 11), _row(moves, 12)
    base.live_checks.cut(np.array([[5.0, 8, 5], [5.0, 8, FLOOR], [14.9, 8, FLOOR]]),
                         np.array([_row(moves, 10), feed]))
    before = base.live.copy()
    rng = np.random.default_rng(7)
    for x0 in 14.9 + rng.random(24) * 0.0999:
        grid = before.copy()
        live = LiveChecks(replace(base.wp, stock=grid), base.moves)
        live.cut(np.array([[14.9, 8, FLOOR], [x0, 8, FLOOR]]), np.array([feed]))
        removed, _, found = live.cut(np.array([[x0, 8, FLOOR], [SLOT_END_X, 8, FLOOR], [SLOT_END_X, 8, -1.9]]),
                                     np.array([feed, rapid]), arrived_row=feed)
        assert found == [], x0
        assert _top_at(grid, SLOT_END_X + RADIUS, 8.0) == FLOOR
        # and nothing is left for the rapid to find afterwards, nor for the next poll
        assert live.cut(np.array([[SLOT_END_X, 8, -1.9], [SLOT_END_X, 8, 5.0]]), np.array([rapid]),
                        arrived_row=rapid)[0] == 0.0
