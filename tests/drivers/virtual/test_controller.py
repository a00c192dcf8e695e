"""VirtualController: stepped (deterministic) and wall-clock runs, URLs, faults."""

from __future__ import annotations

import threading

import pytest

from drivers.errors import DriverError
from drivers.registry import open_controller
from drivers.state import LinkKind, RunState
from drivers.virtual.controller import VirtualController
from drivers.virtual.faults import FaultInjector, FaultPlan, FaultSpecError
from drivers.virtual.machine_config import MachineConfig
from tests.drivers.virtual.helpers import line, rapid, rows

FREE = MachineConfig(travel_min=None, travel_max=None)


def program(n=40):
    pts = [line(((i % 2) * 10.0, i * 1.0, 0), 600) for i in range(1, n + 1)]
    return rows(rapid((0, 0, 5)), *pts)


def test_sim_clock_runs_whole_program_deterministically():
    def run():
        c = VirtualController(program(), speed=1.0, rate=50, clock="sim", config=FREE)
        c.connect()
        states = [c.poll()]
        while not c.done:
            states.append(c.poll())
            assert len(states) < 100000
        c.close()
        return states, c

    a, ca = run()
    b, _ = run()
    assert [s.mpos for s in a] == [s.mpos for s in b]
    assert a[-1].mpos[:2] == pytest.approx((0.0, 40.0))
    assert a[-1].state == RunState.IDLE
    # the times step by one period
    assert a[1].t - a[0].t == pytest.approx(1 / 50)
    lines_seen = {s.line for s in a if s.line}
    assert lines_seen == set(range(1, 42))
    assert [p for _, name, p in ca.events if name == "block_done"] == list(range(1, 42))


def test_speed_scales_simulated_step():
    c = VirtualController(program(), speed=10.0, rate=20, clock="sim", config=FREE)
    c.connect()
    s1 = c.poll()
    s2 = c.poll()
    assert s2.t - s1.t == pytest.approx(0.5)


def test_long_poll_steps_keep_the_planner_fed_and_the_programs_time():
    """A poll step far longer than the planner's blocks (``--speed 2000`` at 50 Hz: 40 s
    per poll) runs the program in its own time, as a sender keeps the planner filled as
    blocks complete. Before: the feeder refilled the 15 blocks once per poll, the machine
    stood idle the rest of the step, and the recorded run took a poll per 15 rows
    (the corpus dome: 65,080 s recorded against 280 s programmed)."""
    def finish_time(speed):
        c = VirtualController(program(300), speed=speed, rate=50, clock="sim", config=FREE)
        c.connect()
        polls = 0
        while not c.done:
            c.poll()
            polls += 1
            assert polls < 100000
        c.close()
        done = [t for t, name, _ in c.events if name == "block_done"]
        return polls, done[-1], len(done)

    fine = finish_time(1.0)                       # 20 ms per poll: shorter than every block
    polls, t_end, blocks = finish_time(2000.0)    # 40 s per poll
    assert blocks == fine[2] == 301
    assert t_end == pytest.approx(fine[1], rel=0.01)  # the program's time, not a poll per 15 rows
    assert polls <= fine[1] / 40.0 + 2


def test_wall_clock_runs_and_holds():
    c = VirtualController(rows(line((-100, 0, 0), 600)), speed=20.0, clock="wall", config=FREE)
    moved = threading.Event()
    with c:
        for st in c.states(0.005):
            if st.mpos[0] < -10:
                moved.set()
                break
        assert moved.is_set()
        c.feed_hold()
        for st in c.states(0.005):
            if st.state == RunState.HOLD and st.substate == 0:
                break
        held = c.poll().mpos
        c.resume()
        for st in c.states(0.005):
            if st.state == RunState.IDLE:
                break
        assert st.mpos[0] == pytest.approx(-100.0)
        assert held[0] > -100.0


def test_open_controller_url(tmp_path):
    c = open_controller("virtual://?speed=5&rate=10&clock=sim&travel=none")
    assert isinstance(c, VirtualController) and c.speed == 5.0 and c.config.travel_min is None
    with pytest.raises(DriverError, match="unknown option 'sped'"):
        open_controller("virtual://?sped=5")
    with pytest.raises(DriverError, match="not found"):
        open_controller(f"virtual://{tmp_path}/missing.nc")
    with pytest.raises(DriverError, match="clock"):
        open_controller("virtual://?clock=moon")
    with pytest.raises(FaultSpecError, match="bad item"):
        open_controller("virtual://?faults=explode:1")
    # speed=inf was taken: each tick advanced the machine by inf (or 0 x inf = nan) seconds
    for bad in ("speed=inf", "speed=nan", "rate=inf", "speed=0"):
        with pytest.raises(DriverError, match="finite numbers > 0"):
            open_controller(f"virtual://?{bad}")


def test_fault_plan_parse_and_determinism():
    plan = FaultPlan.parse("drop=0.1, garble:0.2,late=0.05,alarm=3.5:2,disconnect=1,disconnect_for=0.5,seed=9")
    assert (plan.drop, plan.garble, plan.late, plan.alarm, plan.alarm_code, plan.seed) == (0.1, 0.2, 0.05, 3.5, 2, 9)
    a = FaultInjector(plan)
    b = FaultInjector(plan)
    da = [a.reply_fault() for _ in range(2000)]
    assert da == [b.reply_fault() for _ in range(2000)]
    assert da.count("drop") == pytest.approx(200, abs=45)
    assert da.count("garble") == pytest.approx(400, abs=60)
    g = a.garble_bytes(b"<Idle|MPos:0.000,0.000,0.000>\r\n")
    assert g.endswith(b"\r\n") and g != b"<Idle|MPos:0.000,0.000,0.000>\r\n"
    with pytest.raises(FaultSpecError, match="not a number"):
        FaultPlan.parse("drop=lots")
    with pytest.raises(FaultSpecError, match="probability"):
        FaultPlan.parse("drop=2")


def test_faults_in_controller_poll_are_states_never_exceptions():
    """The contract (drivers.state.Controller): a dropped or garbled reply is a MISSED
    state, the link down a DISCONNECTED one, both at the last known position with the
    reason in ``raw``; poll() never raises for them and time never goes backwards."""
    c = VirtualController(program(), clock="sim", rate=50, config=FREE,
                          faults="drop=0.2,garble=0.2,late=0.2,disconnect=0.5,disconnect_for=1,alarm=3:1,seed=1")
    c.connect()
    states = [c.poll() for _ in range(200)]
    kinds = {k: [s for s in states if s.state == k] for k in (RunState.MISSED, RunState.DISCONNECTED)}
    assert kinds[RunState.MISSED] and kinds[RunState.DISCONNECTED]
    assert any("garbled" in s.raw for s in kinds[RunState.MISSED])
    assert any("no reply" in s.raw for s in kinds[RunState.MISSED])
    assert all(not s.fresh for v in kinds.values() for s in v)
    assert all(b.t >= a.t for a, b in zip(states, states[1:]))
    # a not-fresh state carries the last fresh position, never a new one
    last = None
    for s in states:
        if s.fresh:
            last = s
        elif last is not None:
            assert s.mpos == last.mpos and s.line == last.line
    assert c.faults.counts["disconnect"] == 1
    last = [s for s in states if s.fresh][-1]
    assert last.state == RunState.ALARM and last.alarm == 1
    assert c.done
    # the outage told once as LOST then BACK, and kept in ``gaps``
    events = c.link_events()
    assert [e.kind for e in events if e.kind in (LinkKind.LOST, LinkKind.BACK)] == [LinkKind.LOST, LinkKind.BACK]
    back = next(e for e in events if e.kind == LinkKind.BACK)
    assert len(c.gaps) == 1 and back.gap == c.gaps[0]
    gap = c.gaps[0]
    assert gap.polls_missed == len(kinds[RunState.DISCONNECTED])
    assert 0.5 <= gap.seconds <= 1.3 and "fault injection" in gap.reason  # late replies move time in jumps
    assert c.link_events() == []  # drained


def test_reset_on_reconnect_comes_back_at_zero_in_alarm():
    """``reset=1``: the controller restarted while the link was down: it comes back at
    (0, 0, 0) in alarm (position lost), told as a RESET link event and in the gap."""
    c = VirtualController(program(), clock="sim", rate=50, config=FREE,
                          faults="disconnect=0.5,disconnect_for=0.2,reset=1")
    c.connect()
    states = [c.poll() for _ in range(60)]
    before = [s for s in states if s.fresh and s.t < 0.5][-1]
    after = [s for s in states if s.fresh and s.t > 0.5]
    assert before.mpos[:3] != (0.0, 0.0, 0.0)
    assert after and all(s.state == RunState.ALARM and s.mpos[:3] == (0.0, 0.0, 0.0) for s in after)
    kinds = [e.kind for e in c.link_events()]
    assert kinds == [LinkKind.LOST, LinkKind.BACK, LinkKind.RESET]
    assert "reset" in c.gaps[0].came_back
    assert c.done  # in alarm: the program will not go on


def test_bad_reply_is_a_bad_state_with_its_text():
    """``bad=P``: a reply with non-finite numbers is a BAD state at the last position,
    ``raw`` holding what came, told as a BAD link event; nothing non-finite is handed on."""
    import math

    c = VirtualController(program(), clock="sim", rate=50, config=FREE, faults="bad=0.5,seed=3")
    c.connect()
    states = [c.poll() for _ in range(100)]
    bad = [s for s in states if s.state == RunState.BAD]
    assert bad and len(bad) < 100
    assert all("nan" in s.raw.lower() for s in bad)
    assert all(math.isfinite(v) for s in states for v in s.mpos + s.wco)
    assert sum(e.kind == LinkKind.BAD for e in c.link_events()) == len(bad)


def test_stopped_machine_thread_is_a_state_not_an_exception():
    """A wall-clock machine whose thread died: poll() says so as DISCONNECTED states
    (and one LOST event), it does not raise."""
    c = VirtualController(program(), clock="wall", speed=50, config=FREE)
    c.connect()
    try:
        c._runner.stop()
        c._runner.error = RuntimeError("boom")
        states = [c.poll() for _ in range(3)]
    finally:
        c.close()
    assert all(s.state == RunState.DISCONNECTED and "boom" in s.raw for s in states)
    assert [e.kind for e in c.link_events()] == [LinkKind.LOST]


def test_url_passes_var_file_and_units_to_the_interpreter(tmp_path):
    """``var=`` gives the interpreter its work offsets: a G55 row runs at the G55 offset
    (machine coords) and the machine reports that offset as WCO while it runs."""
    nc = tmp_path / "p.ngc"
    nc.write_text("G21 G90\nG55\nG0 X1 Y2 Z3\nM2\n")
    var = tmp_path / "p.var"
    var.write_text("5241 -4\n5242 2\n5243 -1\n")  # G55, in inch below
    c = open_controller(f"virtual://{nc}?var={var}&machine_units=inch&clock=sim&speed=1&rate=50")
    assert c.moves["end"][-1][:3] == pytest.approx((1 - 101.6, 2 + 50.8, 3 - 25.4))
    c.connect()
    st = c.poll()
    for _ in range(10000):
        if c.done:
            break
        st = c.poll()
    c.close()
    assert st.mpos[:3] == pytest.approx((1 - 101.6, 2 + 50.8, 3 - 25.4))
    assert st.wco[:3] == pytest.approx((-101.6, 50.8, -25.4))
    plain = open_controller(f"virtual://{nc}?clock=sim")
    assert plain.moves["end"][-1][:3] == pytest.approx((1, 2, 3))


def test_url_block_delete_switch(tmp_path):
    """'/' lines run on the virtual machine unless its block delete switch is on."""
    nc = tmp_path / "p.ngc"
    nc.write_text("G21 G90\n/G0 X5\nG0 Y1\nM2\n")
    assert open_controller(f"virtual://{nc}?clock=sim").moves["end"][0][:2] == pytest.approx((5, 0))
    assert open_controller(f"virtual://{nc}?clock=sim&block_delete=on").moves["end"][0][:2] == pytest.approx((0, 1))


def test_url_interpreter_options_named_in_errors(tmp_path):
    nc = tmp_path / "p.ngc"
    nc.write_text("G0 X1\nM2\n")
    for query, words in ((f"var={tmp_path / 'nope.var'}", ["var file", "not found"]),
                         ("machine_units=cm", ["machine_units='cm'", "mm or inch"]),
                         ("dialect=fanuc", ["dialect='fanuc'"]),
                         (f"subroutine_path={tmp_path / 'nodir'}", ["subroutine_path", "not found"]),
                         ("block_delete=maybe", ["block_delete='maybe'", "on or off"])):
        with pytest.raises(DriverError) as e:
            open_controller(f"virtual://{nc}?{query}")
        assert all(w in str(e.value) for w in words), str(e.value)
    with pytest.raises(DriverError, match="no program"):
        open_controller("virtual://?machine_units=mm")


def test_rotary_axes_run_and_reach_the_states(tmp_path):
    """A program turning A (a 4th axis, LinuxCNC dialect): the states carry A in degrees,
    through every value between, to the end; its bad replies show A too."""
    path = tmp_path / "rotary.ngc"
    path.write_text("G21 G90 G94\nG0 X0 Y0 Z5 A0\nG1 X10 A90 F600\nG1 A180 F3600\nM30\n")
    c = open_controller(f"virtual://{path}?speed=4&clock=sim&rate=50")
    c.connect()
    states = [c.poll()]
    while not c.done:
        states.append(c.poll())
        assert len(states) < 100000
    c.close()
    a = [s.mpos[3] for s in states]
    assert a == sorted(a) and len({round(v) for v in a}) > 10  # A turned step by step
    assert states[-1].mpos == pytest.approx((10.0, 0.0, 5.0, 180.0, 0.0, 0.0))


def test_status_text_of_a_bad_reply_shows_the_rotary_axes():
    from drivers.state import MachineState
    from drivers.virtual.controller import _status_text

    text = _status_text(MachineState(t=0.0, mpos=(1, 2, 3, 1e9, 0, 0)))
    assert "MPos:1.000,2.000,3.000,1000000000.000,0.000,0.000" in text
    assert "MPos:1.000,2.000,3.000|" in _status_text(MachineState(t=0.0, mpos=(1, 2, 3)))
