"""Issue 11 against the real pymodbus server on 127.0.0.1: a Modbus controller that is
slow, says no, answers short or with garbage, or goes away never makes ``poll()`` raise;
every such poll is a MISSED, BAD or DISCONNECTED state, counted and told as link events."""

from __future__ import annotations

import math
import random
import time
from dataclasses import replace

import pytest

from drivers.errors import ConnectionLost, DriverError
from drivers.modbus.driver import CAUSES, ModbusController, ModbusExceptionError
from drivers.modbus.regmap import load_map, parse_map
from drivers.modbus.server import AnswerFaults, ModbusVirtualServer
from drivers.registry import open_controller
from drivers.state import LinkKind, RunState, implausible
from drivers.virtual.machine import VirtualMachine
from tests.drivers.modbus.conftest import FREE
from tests.drivers.thread_errors import thread_errors

#: client timeout (s) where no timeout is expected: generous, for a busy machine
TIMEOUT = 2.0
#: client timeout (s) where timeouts are the point, and how late a late answer comes
SHORT_TIMEOUT = 0.5
LATE_S = 1.5
#: function codes that write (coils, registers, masks, read/write)
WRITE_CODES = {5, 6, 15, 16, 22, 23}


@pytest.fixture
def server(server):
    server.late_s = LATE_S  # the conftest's server, answering late this late
    return server


def client(srv, timeout=TIMEOUT, **q) -> ModbusController:
    query = "&".join(f"{k}={v}" for k, v in {"timeout": timeout, **q}.items())
    c = open_controller(f"modbus+tcp://127.0.0.1:{srv.port}?{query}")
    c.connect()
    return c


def kinds(events):
    return [e.kind for e in events]


def test_late_reply_is_missed_then_the_next_poll_is_fresh(vm, server):
    vm.position[0] = -5.0
    c = client(server, timeout=SHORT_TIMEOUT)
    try:
        server.script("late")
        late = c.poll()  # raised ReplyTimeout before
        vm.position[0] = -6.0
        fresh = c.poll()
        events = c.link_events()
    finally:
        c.close()
    assert late.state == RunState.MISSED and not late.fresh
    assert "no reply within 0.5 s" in late.raw and "unit 1 input 0..34 (x,y,z" in late.raw
    assert fresh.fresh and fresh.mpos[0] == -6.0  # the late answer is not taken for the next poll's
    assert fresh.t >= late.t
    assert c.counts["timeout"] == 1
    assert kinds(events) == [LinkKind.NOTE, LinkKind.NOTE]  # the cause appeared, then cleared
    assert "no reply" in events[0].message and "cleared" in events[1].message


def test_busy_acknowledge_and_exception_codes_are_retried_and_counted(vm, server):
    c = client(server)
    try:
        asked = server.function_codes[4]
        server.script("busy", "busy", "busy", "acknowledge", "exception")
        missed = [c.poll() for _ in range(5)]
        fresh = c.poll()
        events = c.link_events()
    finally:
        c.close()
    assert [s.state for s in missed] == [RunState.MISSED] * 5 and fresh.fresh
    assert "exception code 6 (server device busy)" in missed[0].raw
    assert "exception code 5 (acknowledge)" in missed[3].raw
    assert "unit 1 input 0..34" in missed[4].raw
    assert server.function_codes[4] - asked == 6  # the same request, repeated at each poll
    assert (c.counts["busy"], c.counts["acknowledge"], c.counts["exception"]) == (3, 1, 1)
    notes = [e.message for e in events if e.kind == LinkKind.NOTE]
    assert len(notes) == 6, notes  # busy, acknowledge, exception: each appeared once, then cleared
    assert sum("busy" in m for m in notes) == 2


def test_short_response_is_missed(vm, server):
    c = client(server)
    try:
        server.script("short")
        short = c.poll()  # failed in regmap.decode before
        fresh = c.poll()
    finally:
        c.close()
    assert short.state == RunState.MISSED and fresh.fresh
    assert "registers of 35" in short.raw and "unit 1 input 0..34" in short.raw
    assert c.counts["short"] == 1


@pytest.mark.parametrize("x", [math.nan, math.inf, -math.inf, 2.0e5, 3.0e38])
def test_impossible_numbers_are_bad_and_never_fresh(vm, server, x):
    vm.position[:3] = (1.0, 2.0, 3.0)
    c = client(server)
    try:
        good = c.poll()
        vm.position[0] = x
        bad = [c.poll(), c.poll()]
        vm.position[0] = 4.0
        again = c.poll()
        events = c.link_events()
    finally:
        c.close()
    assert good.fresh and again.fresh and again.mpos[0] == 4.0
    for st in bad:
        assert st.state == RunState.BAD and not st.fresh
        assert st.mpos == good.mpos  # the last known position, never the garbage
        assert "x=" in st.raw.lower() and "unit 1 input 0..34=[" in st.raw  # what and the raw words
    assert c.counts["bad"] == 2
    assert kinds(events) == [LinkKind.BAD, LinkKind.NOTE]  # told once, then cleared


def test_huge_integers_are_bad():
    doc = {"fields": {"x": {"table": "input", "address": 0, "type": "float32"},
                      "line": {"table": "input", "address": 30, "type": "uint32"}}}
    regmap = parse_map(doc, "line.toml")
    vm = VirtualMachine(FREE)
    with ModbusVirtualServer(vm, regmap).start() as srv:
        c = ModbusController(regmap, host="127.0.0.1", port=srv.port, timeout=TIMEOUT)
        c.connect()
        try:
            srv.script("mutate")  # the only integer field gets 0xFFFF....: above 2**31
            seen = [c.poll() for _ in range(6)]
        finally:
            c.close()
    assert all(s.fresh or s.state == RunState.BAD for s in seen)
    assert all(implausible(s) is None for s in seen if s.fresh)


def test_huge_float64_velocities_are_bad_not_an_overflow():
    """A path feed from float64 axis velocities near 1e300 must not overflow on the way
    to a BAD state."""
    doc = {"fields": {"x": {"table": "input", "address": 0, "type": "float64"},
                      "vx": {"table": "input", "address": 4, "type": "float64"},
                      "vy": {"table": "input", "address": 8, "type": "float64"}}}
    regmap = parse_map(doc, "f64.toml")
    vm = VirtualMachine(FREE)
    with ModbusVirtualServer(vm, regmap).start() as srv:
        c = ModbusController(regmap, host="127.0.0.1", port=srv.port, timeout=TIMEOUT)
        c.connect()
        try:
            srv.answers = AnswerFaults(mutate=1.0, seed=3)
            seen = [c.poll() for _ in range(60)]
        finally:
            c.close()
    assert {s.state for s in seen if not s.fresh} == {RunState.BAD}
    assert c.counts["error"] == 0  # every mutated answer decoded into a verdict
    assert "1e+300" in " ".join(s.raw for s in seen)


def test_silent_controller_goes_down_after_three_timeouts_and_comes_back(vm, server):
    c = client(server, timeout=SHORT_TIMEOUT)
    try:
        c.poll()
        server.silent = True
        states = [c.poll() for _ in range(6)]
        lost_events = c.link_events()
        server.silent = False
        back = c.poll()
        back_events = c.link_events()
    finally:
        c.close()
    assert [s.state for s in states[:2]] == [RunState.MISSED] * 2
    assert [s.state for s in states[2:]] == [RunState.DISCONNECTED] * 4
    assert LinkKind.LOST in kinds(lost_events) and "3 requests in a row" in lost_events[-1].message
    assert back.fresh
    assert kinds(back_events)[-1] == LinkKind.BACK
    gap = back_events[-1].gap
    assert gap is not None and c.gaps == [gap]
    assert gap.polls_missed == 4 and gap.t_lost <= gap.t_back <= back.t


def test_server_stopped_and_restarted_on_the_same_port(vm, server):
    """Polls lost to the outage: every poll that started while the server was away,
    plus at most one more (the one in flight when it came back)."""
    c = client(server, rate=50)
    try:
        before = [c.poll() for _ in range(3)]
        t_stop = time.monotonic()
        server.stop()
        polls: list[tuple[float, object]] = []
        while sum(s.state == RunState.DISCONNECTED for _, s in polls) < 5:
            polls.append((time.monotonic(), c.poll()))
            assert len(polls) < 500
        vm.position[0] = -42.0
        server.restart()
        t_back = time.monotonic()
        while not polls[-1][1].fresh:
            polls.append((time.monotonic(), c.poll()))
            assert len(polls) < 500
        events = c.link_events()
    finally:
        c.close()
    assert all(s.fresh for s in before)
    states = [s for _, s in polls]
    assert states[-1].mpos[0] == -42.0
    not_fresh = [s for s in states if not s.fresh]
    started_during_outage = sum(t_stop <= t < t_back for t, _ in polls)
    assert len(not_fresh) <= started_during_outage + 1
    assert all(s.state == RunState.DISCONNECTED for s in not_fresh)
    assert kinds(events) == [LinkKind.LOST, LinkKind.BACK]
    gap = events[-1].gap
    assert gap.polls_missed == len(not_fresh) and c.gaps == [gap]
    ts = [s.t for s in before + states]
    assert ts == sorted(ts)


def test_link_dropped_during_the_feed_hold_write_is_an_outage(vm, server):
    """The write that met a dropped link closed the client but recorded no outage: every
    later poll was MISSED (a driver failure), with no LOST, no reconnect and no gap."""
    c = client(server, feed_hold=1)
    try:
        vm.position[0] = 10.0
        before = c.poll()
        server.stop()  # the controller goes away (a power blip) ...
        with pytest.raises(ConnectionLost, match="during the feed-hold write"):
            c.feed_hold()  # ... as the monitor tries to stop the machine
        lost_events = c.link_events()
        down = [c.poll(), c.poll()]
        vm.position[0] = 20.0
        server.restart()
        polls = [c.poll()]
        while not polls[-1].fresh:
            polls.append(c.poll())
            assert len(polls) < 500
        back_events = c.link_events()
    finally:
        c.close()
    assert before.fresh
    assert kinds(lost_events) == [LinkKind.LOST] and "feed-hold write" in lost_events[0].message
    assert [s.state for s in down] == [RunState.DISCONNECTED] * 2
    assert all(s.mpos[0] == 10.0 for s in down)  # the last known position
    assert polls[-1].mpos[0] == 20.0
    assert all(s.state == RunState.DISCONNECTED for s in polls[:-1])
    assert c.counts["error"] == 0
    assert kinds(back_events) == [LinkKind.BACK]
    gap = back_events[0].gap
    assert c.gaps == [gap] and gap.polls_missed == 2 + len(polls) - 1 and c.reconnects == 1
    assert gap.t_lost <= down[0].t and gap.t_back <= polls[-1].t


def test_a_failure_inside_the_driver_is_a_missed_poll_not_a_stop(vm, server, monkeypatch):
    c = client(server)
    try:
        monkeypatch.setattr(c, "_state", lambda *a: 1 / 0)
        broken = [c.poll(), c.poll()]
        monkeypatch.undo()
        fresh = c.poll()
        events = c.link_events()
    finally:
        c.close()
    assert [s.state for s in broken] == [RunState.MISSED] * 2 and fresh.fresh
    assert "ZeroDivisionError" in broken[0].raw and c.counts["error"] == 2
    assert kinds(events) == [LinkKind.NOTE, LinkKind.NOTE]


def test_map_that_does_not_fit_fails_connect_naming_the_registers(vm, server):
    doc = {"fields": {"x": {"table": "input", "address": 0, "type": "float32"},
                      "line": {"table": "input", "address": 200, "type": "uint32"}}}
    c = ModbusController(parse_map(doc, "wrong.toml"), host="127.0.0.1", port=server.port, timeout=TIMEOUT)
    with pytest.raises(ModbusExceptionError, match=r"unit 1 input 200..201 \(line\): exception code 2 \(illegal data address\)"):
        c.connect()
    c.close()


def test_exception_code_after_connect_is_missed_not_raised(vm, server):
    c = client(server)
    try:
        server.script("exception", "exception", "exception")
        states = [c.poll() for _ in range(4)]
    finally:
        c.close()
    assert [s.state for s in states[:3]] == [RunState.MISSED] * 3 and states[3].fresh
    assert c.counts["exception"] == 3


def test_no_write_reaches_the_device_unless_feed_hold_is_enabled_and_asked(vm, server):
    ro = client(server)
    try:
        for _ in range(5):
            ro.poll()
        with pytest.raises(DriverError, match="read-only: feed hold is not enabled .*feed_hold=1"):
            ro.feed_hold()
    finally:
        ro.close()
    assert not WRITE_CODES & set(server.function_codes)
    rw = client(server, feed_hold=1)
    try:
        for _ in range(5):
            rw.poll()
        assert not WRITE_CODES & set(server.function_codes)  # enabled, but not asked
        rw.feed_hold()
    finally:
        rw.close()
    assert {k: n for k, n in server.function_codes.items() if k in WRITE_CODES} == {5: 1}


FUZZ = AnswerFaults(late=0.04, busy=0.08, acknowledge=0.04, exception=0.06, short=0.06, garble=0.08,
                    mutate=0.2, late_s=0.2)


def test_fuzz_30_sessions_of_late_busy_garbled_and_non_finite_answers(vm):
    """Each session: a server drawing answer faults from its own seed, a client polling
    60 times; now and then the server stops and comes back on the same port."""
    with thread_errors() as errors:
        totals = dict.fromkeys(("fresh", "missed", "bad", "disconnected"), 0)
        causes = dict.fromkeys(CAUSES, 0)
        for seed in range(30):
            rng = random.Random(seed)
            with ModbusVirtualServer(vm, load_map("generic")) as srv:
                c = ModbusController(load_map("generic"), host="127.0.0.1", port=srv.port, timeout=0.1)
                c.connect()
                srv.answers = replace(FUZZ, seed=seed)  # after connect(): its probe read is clean
                states = []
                try:
                    for k in range(60):
                        vm.position[:3] = (rng.uniform(-500, 500), rng.uniform(-500, 500), rng.uniform(-100, 0))
                        if k in (20, 40) and rng.random() < 0.5:
                            srv.stop()
                            states.append(c.poll())
                            srv.restart()
                        states.append(c.poll())  # never raises
                        c.link_events()
                finally:
                    c.close()
                ts = [s.t for s in states]
                assert ts == sorted(ts)
                for st in states:
                    assert not st.fresh or implausible(st) is None, st.raw
                    totals["fresh" if st.fresh else st.state.value.lower()] += 1
                assert srv.errors == []
                causes = {k: n + c.counts[k] for k, n in causes.items()}
    assert errors == []
    assert min(totals.values()) > 0, totals
    assert causes.pop("error") == 0  # no failure inside the driver
    assert min(causes.values()) > 0, causes  # every kind of trouble was met
