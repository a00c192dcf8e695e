"""Planner and motion of the virtual machine against analytic oracles."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.state import RunState
from drivers.virtual.machine import MachineLocked, PlannerFull, TravelExceeded, VirtualMachine
from drivers.virtual.machine_config import MachineConfig
from sim.gcode.moves import MoveKind
from tests.drivers.virtual.helpers import line, rapid, rows, run_until_idle

FREE = MachineConfig(travel_min=None, travel_max=None)


def trapezoid_time(length, v, a):
    """Time of a rest-to-rest move of ``length`` mm at cruise ``v`` mm/s, accel ``a``."""
    if v * v / a >= length:  # triangle
        return 2 * math.sqrt(length / a)
    return length / v + v / a


def finish_time(vm, step=0.05):
    """Exact simulated time at which the machine gets idle (event-stamped)."""
    done = []
    vm.on_event = lambda name, payload: done.append(vm.time) if name == "idle" else None
    t0 = vm.time
    while vm.busy:
        vm.advance(step)
    # the idle event fires inside advance(); find the exact instant by bisection of the step
    return t0, done


def exact_duration(make_vm, total_guess=100.0):
    """Duration of a program to within 1e-9 s: bisection on 'busy after advance(t)'."""
    lo, hi = 0.0, total_guess
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        vm = make_vm()
        vm.advance(mid)
        if vm.busy:
            lo = mid
        else:
            hi = mid
    return hi


@pytest.mark.parametrize("length,feed", [(10.0, 300.0), (0.5, 300.0), (50.0, 120.0)])
def test_single_move_matches_trapezoid(length, feed):
    def make():
        vm = VirtualMachine(FREE)
        vm.queue(rows(line((length, 0, 0), feed)))
        return vm

    expected = trapezoid_time(length, feed / 60.0, 10.0)
    assert exact_duration(make) == pytest.approx(expected, rel=1e-6)


def test_time_slicing_does_not_change_the_result():
    prog = rows(line((10, 0, 0), 300), line((10, 7, 0), 200), rapid((-3, -4, -1)), line((0, 0, 0), 400))
    a = VirtualMachine(FREE)
    b = VirtualMachine(FREE)
    a.queue(prog)
    b.queue(prog)
    for _ in range(800):
        a.advance(0.01)
    for _ in range(8):
        b.advance(1.0)
    np.testing.assert_allclose(a.position, b.position, atol=1e-9)
    assert a.speed == pytest.approx(b.speed, abs=1e-9)


def test_diagonal_move_is_limited_per_axis():
    # X is slow (100 mm/min); a 45 degree feed at 1000 mm/min runs at 100*sqrt(2)
    cfg = MachineConfig(max_rate=(100, 1000, 1000), accel=(1000, 1000, 1000), travel_min=None, travel_max=None)
    vm = VirtualMachine(cfg)
    vm.queue(rows(line((20, 20, 0), 1000)))
    vm.advance(3.0)
    assert vm.snapshot().feed == pytest.approx(100 * math.sqrt(2), rel=1e-9)


def test_rapid_runs_at_max_rate_times_rapid_override():
    vm = VirtualMachine(FREE)
    vm.queue(rows(rapid((-100, 0, 0))))
    vm.advance(3.0)
    assert vm.snapshot().feed == pytest.approx(500.0)
    vm.set_rapid_override(25)
    vm.advance(3.0)
    assert vm.snapshot().feed == pytest.approx(125.0)
    assert vm.snapshot().overrides == (100, 25, 100)


def test_feed_override_scales_and_is_capped_by_max_rate():
    vm = VirtualMachine(FREE)
    vm.queue(rows(line((-100, 0, 0), 300)))
    vm.advance(2.0)
    assert vm.snapshot().feed == pytest.approx(300.0)
    vm.set_feed_override(150)
    vm.advance(2.0)
    assert vm.snapshot().feed == pytest.approx(450.0)
    vm.set_feed_override(200)  # 600 > 500 max rate
    vm.advance(2.0)
    assert vm.snapshot().feed == pytest.approx(500.0)
    vm.set_feed_override(50)
    vm.advance(0.1)  # decelerating at 10 mm/s^2 from 500 mm/min
    assert vm.snapshot().feed == pytest.approx(500.0 - 10 * 0.1 * 60, rel=1e-9)
    vm.advance(2.0)
    assert vm.snapshot().feed == pytest.approx(150.0)


def test_machine_passes_corner_at_junction_speed():
    dev = 0.05
    cfg = MachineConfig(junction_deviation=dev, travel_min=None, travel_max=None)
    vm = VirtualMachine(cfg)
    vm.queue(rows(line((20, 0, 0), 400), line((20, 20, 0), 400)))
    s = math.sqrt(0.5)
    v_corner = math.sqrt((10 / s) * dev * s / (1 - s))
    seen = []
    vm.on_event = lambda name, row: seen.append(vm.speed) if name == "block_done" else None
    while vm.busy:
        vm.advance(0.01)
    assert seen[0] == pytest.approx(v_corner, rel=1e-6)
    assert seen[1] == pytest.approx(0.0, abs=1e-9)


def test_collinear_blocks_do_not_slow_down():
    vm = VirtualMachine(FREE)
    vm.queue(rows(line((5, 0, 0), 300), line((10, 0, 0), 300)))
    speeds = []
    vm.on_event = lambda name, row: speeds.append(vm.speed) if name == "block_done" else None
    run_until_idle(vm, dt=0.01)
    assert speeds[0] == pytest.approx(5.0)


def test_lookahead_plans_stop_only_at_the_end():
    # 10 blocks of 1 mm each: the whole path is one trapezoid of 10 mm
    def make():
        vm = VirtualMachine(FREE)
        vm.queue(rows(*[line((i + 1.0, 0, 0), 300) for i in range(10)]))
        return vm

    assert exact_duration(make) == pytest.approx(trapezoid_time(10.0, 5.0, 10.0), rel=1e-6)


def test_feed_hold_decelerates_over_v2_over_2a_then_holds():
    vm = VirtualMachine(FREE)
    vm.queue(rows(line((-100, 0, 0), 300)))
    vm.advance(2.0)
    x0 = vm.position[0]
    v = vm.speed
    vm.feed_hold()
    vm.advance(0.1)
    st = vm.snapshot()
    assert (st.state, st.substate) == (RunState.HOLD, 1)
    assert st.feed == pytest.approx((v - 10 * 0.1) * 60)
    vm.advance(1.0)
    st = vm.snapshot()
    assert (st.state, st.substate, st.feed) == (RunState.HOLD, 0, 0.0)
    assert x0 - vm.position[0] == pytest.approx(v * v / (2 * 10.0), rel=1e-9)
    vm.advance(5.0)  # held: nothing moves
    assert x0 - vm.position[0] == pytest.approx(v * v / 20.0)
    vm.resume()
    assert vm.state == RunState.RUN
    run_until_idle(vm, dt=0.05)
    assert vm.position[0] == pytest.approx(-100.0)


def test_hold_deceleration_spans_blocks():
    vm = VirtualMachine(FREE)
    vm.queue(rows(*[line((-(i + 1) * 0.2, 0, 0), 300) for i in range(10)]))
    vm.advance(0.8)  # at 5 mm/s after 0.5 s; x = -1.25 - 1.5 = -2.75... block boundaries around
    v = vm.speed
    x0 = vm.position[0]
    vm.feed_hold()
    vm.advance(2.0)
    assert vm.speed == 0.0
    assert x0 - vm.position[0] == pytest.approx(min(v * v / 20.0, 2.0 + x0), rel=1e-9)


def test_soft_limit_alarms_before_moving():
    vm = VirtualMachine(MachineConfig())  # travel [-200, 0]
    events = []
    vm.on_event = lambda name, payload: events.append((name, payload))
    vm.queue(rows(line((5, 0, 0), 300)))
    assert vm.state == RunState.ALARM and vm.snapshot().alarm == 2
    assert ("alarm", 2) in events
    vm.advance(1.0)
    assert vm.position[0] == 0.0
    with pytest.raises(MachineLocked):
        vm.queue(rows(line((-5, 0, 0), 300)))
    vm.unlock()
    vm.queue(rows(line((-5, 0, 0), 300)))
    run_until_idle(vm, dt=0.05)
    assert vm.position[0] == pytest.approx(-5.0)


def test_soft_limit_while_moving_decelerates_then_alarms():
    vm = VirtualMachine(MachineConfig())
    vm.queue(rows(line((-50, 0, 0), 300)))
    vm.advance(2.0)
    vm.queue(rows(line((-50, 0, 0), 300), line((-50, 300, 0), 300), start=(-50, 0, 0))[1:])
    assert vm.state == RunState.HOLD
    vm.advance(2.0)
    assert vm.state == RunState.ALARM and vm.alarm == 2
    assert vm.position[0] > -50.0  # stopped along the path, did not finish


def test_reset_during_motion_is_alarm_3_and_keeps_position():
    vm = VirtualMachine(FREE)
    vm.queue(rows(line((10, 0, 0), 300)))
    vm.advance(1.0)
    x = vm.position[0]
    vm.set_feed_override(150)
    vm.reset()
    st = vm.snapshot()
    assert st.state == RunState.ALARM and st.alarm == 3
    assert st.mpos[0] == x and st.overrides == (100, 100, 100)
    assert vm.planner_free() == 15
    idle = VirtualMachine(FREE)
    idle.reset()
    assert idle.state == RunState.IDLE


def test_planner_full():
    vm = VirtualMachine(FREE)
    vm.queue(rows(*[line((i + 1.0, 0, 0), 300) for i in range(15)]))
    assert vm.planner_free() == 0
    with pytest.raises(PlannerFull):
        vm.queue(rows(line((20, 0, 0), 300)))
    vm.advance(0.6)  # at least one block done
    assert vm.planner_free() >= 1


def test_block_done_events_carry_rows_in_order():
    vm = VirtualMachine(FREE)
    lines = []
    vm.on_event = lambda name, row: lines.append(int(row["line"])) if name == "block_done" else None
    vm.queue(rows(line((1, 0, 0), 300), line((1, 1, 0), 300), rapid((0, 0, 0))))
    st = []
    while vm.busy:
        vm.advance(0.05)
        st.append(vm.snapshot().line)
    assert lines == [1, 2, 3]
    assert st[0] == 1 and 2 in st and 3 in st


def test_full_circle_arc_runs_the_circumference():
    def make():
        vm = VirtualMachine(FREE)
        r = rows((MoveKind.ARC_CW, (0, 0, 0), 60.0, {"turns": 1}))
        r["center"][0] = (5, 0, 0)
        vm.queue(r)
        return vm

    # 1 mm/s along 2*pi*5 mm; accel time negligible (0.1 s at 10 mm/s^2 ... +0.1 s)
    assert exact_duration(make, 100.0) == pytest.approx(2 * math.pi * 5 / 1.0 + 0.1, rel=2e-3)


def test_dwell_stops_then_waits():
    def make():
        vm = VirtualMachine(FREE)
        vm.queue(rows(line((5, 0, 0), 300), (MoveKind.DWELL, (5, 0, 0), 0.0, {"dwell": 1.5}), line((10, 0, 0), 300)))
        return vm

    assert exact_duration(make) == pytest.approx(2 * trapezoid_time(5.0, 5.0, 10.0) + 1.5, rel=1e-6)


def test_pause_m0_holds_until_resume():
    vm = VirtualMachine(FREE)
    vm.queue(rows(line((5, 0, 0), 300), (MoveKind.PAUSE, (5, 0, 0), 0.0), line((10, 0, 0), 300)))
    vm.advance(10.0)
    assert vm.state == RunState.HOLD and vm.position[0] == pytest.approx(5.0)
    vm.resume()
    vm.advance(10.0)
    assert vm.state == RunState.IDLE and vm.position[0] == pytest.approx(10.0)


def test_a_tool_change_row_that_moves_takes_the_machine_to_its_end():
    # rs274 re-reads its position after "T1 M6 G43 H1": the tool change row moves Z 0 -> 10
    vm = VirtualMachine(FREE)
    vm.queue(rows(rapid((5, 0, 0)), (MoveKind.TOOL_CHANGE, (5, 0, 10), 0.0), line((10, 0, 10), 300)))
    run_until_idle(vm)
    np.testing.assert_allclose(vm.position[:3], [10, 0, 10])
    done = []
    vm = VirtualMachine(FREE)
    vm.on_event = lambda name, payload: done.append(vm.position[2]) if name == "block_done" else None
    vm.queue(rows((MoveKind.TOOL_CHANGE, (0, 0, 10), 0.0)))
    run_until_idle(vm)
    assert done == [pytest.approx(10.0)]   # one block_done per row, once it is there


def test_inverse_time_feed():
    def make():
        vm = VirtualMachine(MachineConfig(accel=(1e6, 1e6, 1e6), travel_min=None, travel_max=None))
        vm.queue(rows((MoveKind.FEED, (10, 0, 0), 0.0, {"inverse_time": 30.0})))  # 1/30 min = 2 s
        return vm

    assert exact_duration(make) == pytest.approx(2.0, rel=1e-4)


def test_jog_cancel_and_travel():
    vm = VirtualMachine(MachineConfig())
    with pytest.raises(TravelExceeded):
        vm.jog((10, 0, 0), 300)
    vm.jog((-50, 0, 0), 300)
    assert vm.state == RunState.JOG
    vm.advance(2.0)
    vm.set_feed_override(50)  # jogs ignore the feed override
    vm.advance(0.5)
    assert vm.snapshot().feed == pytest.approx(300.0)
    x = vm.position[0]
    vm.cancel_jog()
    vm.advance(2.0)
    assert vm.state == RunState.IDLE
    assert x - vm.position[0] == pytest.approx(25 / 20.0)
    assert vm.planner_free() == 15


def test_snapshot_fields():
    vm = VirtualMachine(FREE)
    vm.t0 = 100.0
    r = rows(line((10, 0, 0), 300, ), )
    r["spindle"] = 1000
    r["spindle_dir"] = -1
    r["coolant"] = 2
    r["wco"][0] = (-3.0, 1.0, 2.0, 0, 0, 0)
    vm.queue(r)
    vm.set_spindle_override(120)
    vm.advance(0.25)
    st = vm.snapshot()
    assert st.t == pytest.approx(100.25)
    assert st.state == RunState.RUN and st.line == 1
    assert st.feed == pytest.approx(0.25 * 10 * 60)
    assert st.spindle == pytest.approx(-1200.0)
    assert st.accessories == "CF"
    assert st.wco[:3] == pytest.approx((-3.0, 1.0, 2.0))
    assert st.buffer == (14, 128)


from hypothesis import given, settings, strategies as st


@settings(max_examples=12, deadline=None)
@given(st.lists(st.tuples(st.floats(-20, 20), st.floats(-20, 20), st.floats(30, 600)), min_size=1, max_size=12),
       st.sampled_from([0.031, 0.1, 0.7]))
def test_random_paths_stay_within_limits_and_arrive(points, step):
    prog = rows(*[line((x, y, 0), f) for x, y, f in points])
    vm = VirtualMachine(FREE)
    vm.queue(prog)
    ends = prog["end"][:, :2]
    starts = prog["start"][:, :2]
    for _ in range(20000):
        if not vm.busy:
            break
        vm.advance(step)
        assert np.all(np.abs(vm.velocity()[:3]) <= 500.0 + 1e-6)  # per-axis max rate, mm/min
        assert vm.speed * 60 <= max(f for _, _, f in points) + 1e-6
        # the machine is always on the programmed polyline (within rounding)
        p = vm.position[:2]
        d = []
        for a, b in zip(starts, ends):
            ab = b - a
            L = float(ab @ ab)
            t = 0.0 if L == 0 else min(max(float((p - a) @ ab) / L, 0.0), 1.0)
            d.append(float(np.linalg.norm(a + t * ab - p)))
        assert min(d) < 1e-6
    assert not vm.busy
    np.testing.assert_allclose(vm.position[:2], ends[-1], atol=1e-9)


def test_virtual_url_runs_gcode_file(tmp_path):
    from drivers.registry import open_controller

    job = tmp_path / "job.nc"
    job.write_text("G21 G90\nG0 X5 Y5\nG1 X20 F300\nG2 X30 Y15 I0 J10\nG4 P0.5\nM2\n")
    c = open_controller(f"virtual://{job}?clock=sim&rate=20&speed=2")
    c.connect()
    try:
        seen = [c.poll()]
        while not c.done:
            seen.append(c.poll())
            assert len(seen) < 10000
    finally:
        c.close()
    assert seen[-1].mpos[:2] == pytest.approx((30.0, 15.0), abs=1e-9)
    assert {s.line for s in seen if s.line} >= {2, 3, 4}
    arc = [s for s in seen if s.line == 4]
    r = [math.hypot(s.mpos[0] - 20, s.mpos[1] - 15) for s in arc]
    assert max(r) == pytest.approx(10.0, abs=0.003) and min(r) >= 10.0 - 0.003
