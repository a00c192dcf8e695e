"""Modbus RTU against the virtual server framed as RTU over TCP (pyserial's socket://):
an RTU answer carries no transaction id, so a late answer must never be taken for the
next request's, and an answer with a bad CRC is a garbled answer, not a silent device."""

from __future__ import annotations


import pytest

from drivers.modbus.regmap import load_map
from drivers.registry import open_controller
from drivers.state import LinkKind, RunState
from tests.drivers.modbus.rtu_server import RtuOverTcpServer

#: client timeout (s), and how late a late answer comes: 0.1 s after the client gave up
TIMEOUT = 0.5
LATE_S = 0.6


@pytest.fixture
def rtu(vm):
    srv = RtuOverTcpServer(vm, load_map("generic"), port=0).start()
    srv.late_s = LATE_S
    yield srv
    srv.stop()


def client(srv, timeout=TIMEOUT):
    c = open_controller(srv.url(timeout=timeout))
    c.connect()
    return c


def test_late_answer_is_never_taken_for_the_next_polls(vm, rtu):
    """The answer that came after its request timed out was read as the next poll's:
    a fresh state with the position of the earlier instant."""
    c = client(rtu)
    try:
        vm.position[0] = 1.0
        first = c.poll()
        rtu.script("late")
        late = c.poll()
        after = []
        for x in (2.0, 3.0, 4.0):
            vm.position[0] = x  # the machine moves on between polls
            after.append((x, c.poll()))
        events = c.link_events()
    finally:
        c.close()
    assert first.fresh and first.mpos[0] == 1.0
    assert late.state == RunState.MISSED and "no reply within 0.5 s" in late.raw
    for x, st in after:
        assert not st.fresh or st.mpos[0] == x, (x, st.raw)
    assert after[-1][1].fresh  # the line is in step again
    assert c.counts["timeout"] == 1 and LinkKind.LOST not in [e.kind for e in events]


def test_late_answer_before_a_feed_hold_write_is_not_its_reply(vm, rtu):
    """The write after a timed-out read is sent only once the late read answer is gone:
    otherwise that answer would be taken for the write's."""
    c = open_controller(rtu.url(timeout=TIMEOUT, feed_hold=1))
    c.connect()
    try:
        c.poll()
        rtu.script("late")
        late = c.poll()
        c.feed_hold()  # raises if the late read answer were taken for the write's
        held = vm.state
        st = c.poll()
    finally:
        c.close()
    assert late.state == RunState.MISSED
    assert held == RunState.HOLD and st.fresh


def test_bad_crc_is_a_garbled_answer_not_a_lost_link(vm, rtu):
    """Answers with a bad CRC were taken for no answer: each poll waited out the timeout
    and three in a row marked the link lost."""
    c = client(rtu, timeout=5.0)
    try:
        vm.position[0] = 7.0
        c.poll()
        rtu.corrupt(3)
        garbled = [c.poll() for _ in range(3)]
        vm.position[0] = 8.0
        fresh = c.poll()
        events = c.link_events()
    finally:
        c.close()
    assert rtu.corrupted == 3
    for st in garbled:   # garbled when the answer came, not 'no reply' after the timeout
        assert st.state == RunState.MISSED, st.raw
        assert "bad CRC" in st.raw and "unit 1 input 0..34" in st.raw
    assert fresh.fresh and fresh.mpos[0] == 8.0
    assert c.counts["garbled"] == 3 and c.counts["timeout"] == 0 and c.counts["disconnected"] == 0
    assert [e.kind for e in events] == [LinkKind.NOTE, LinkKind.NOTE]  # garbled appeared, then cleared
    assert c.gaps == []
