"""The GRBL driver never goes blind or silent (issue 11): garbage on the wire, lost and
impossible replies, attaching to a running machine, link drops and restarted controllers,
against the GRBL peer on a real pty or TCP socket."""

from __future__ import annotations

import threading
import time

import pytest

from drivers.grbl import protocol as p
from drivers.grbl.driver import GrblController
from drivers.grbl.peer import GrblPeer
from drivers.registry import open_controller
from drivers.state import LinkKind, RunState, implausible
from tests.drivers.thread_errors import thread_errors
from drivers.virtual.machine import VirtualMachine
from drivers.virtual.machine_config import MachineConfig

FAST = dict(max_rate=(3000.0, 3000.0, 3000.0), accel=(200.0, 200.0, 200.0))
HUGE = str(2**64 + 1).encode()
HANDSHAKE = ["$I", "$$", "$#", "$G"]


def make_vm() -> VirtualMachine:
    return VirtualMachine(MachineConfig(travel_min=(-200.0,) * 3, travel_max=(200.0,) * 3, **FAST))


@pytest.fixture
def peers():
    made = []

    def make(vm=None, speed=4.0, **kw):
        pr = GrblPeer(vm or make_vm(), speed=speed, **kw)
        made.append(pr)
        return pr

    yield made, make
    for pr in made:
        pr.close()


@pytest.fixture
def controllers():
    made = []

    def make(url: str, connect: bool = True) -> GrblController:
        c = open_controller(url)
        made.append(c)
        if connect:
            c.connect()
        return c

    yield make
    for c in made:
        c.close()


@pytest.fixture
def idle_link(peers, controllers):
    """(peer, controller) connected over a pty at 50 polls/s."""
    _, make_peer = peers
    pr = make_peer()
    return pr, controllers(pr.serve_url("pty", "rate=50"))


def rewrite_status(pr: GrblPeer, old: bytes, new: bytes) -> None:
    """Make the peer's status reports say ``new`` where they say ``old`` (None: stop)."""
    pr.mutate = None if old is None else (lambda d: d.replace(old, new) if d.startswith(b"<") else d)


def kinds(c) -> list[LinkKind]:
    return [e.kind for e in c.link_events()]


# ----------------------------------------------------------------------------- garbage


@pytest.mark.parametrize("push", [b"$13=abc", b"$13=1e5", b"$13=nan", b"$13=inf", b"$13=" + b"9" * 400,
                                  b"$13=-1", b"$13=2", b"$13=" + HUGE])
def test_garbage_inch_setting_push_keeps_the_reader_and_the_units(idle_link, push):
    pr, c = idle_link
    c.command("G1 X2 F3000")
    with thread_errors() as errors:
        pr.inject(push + b"\r\n")
        pr.inject(b"$10=" + HUGE + b"\r\n")
        c.wait_for_state(lambda s: s.fresh and s.state is RunState.IDLE and s.mpos[0] == pytest.approx(2.0), 5)
        s = c.poll()
    assert errors == [] and c._reader.is_alive()
    assert s.fresh and s.mpos[0] == pytest.approx(2.0)  # still mm: the last good $13=0 kept
    assert c.settings[13] == 0 and c.settings[10] == 1
    assert any(push[:6].decode() in g[1] for g in c.garbage)


@pytest.mark.parametrize("bad", [b"nan", b"inf", b"1e308", b"-1", b"1" + b"0" * 400])
def test_garbage_inch_setting_in_the_settings_reply(idle_link, bad):
    pr, c = idle_link
    pr.mutate = lambda d: d.replace(b"$13=0", b"$13=" + bad)
    with thread_errors() as errors:
        c.command("$$")
        c.command("G1 X1 F3000")
        s = c.wait_for_state(lambda s: s.fresh and s.state is RunState.IDLE, 5)
    assert errors == [] and c._reader.is_alive()
    assert s.mpos[0] == pytest.approx(1.0) and c.settings[13] == 0


@pytest.mark.parametrize("old,new", [
    (b"|FS:", b"|Ln:" + HUGE + b"|FS:"),
    (b"<Idle|", b"<Hold:" + HUGE + b"|"),
    (b"|FS:", b"|Bf:15," + HUGE + b"|FS:"),
    (b"|FS:", b"|Ov:100," + HUGE + b",100|FS:"),
    (b"MPos:0.000", b"MPos:" + b"9" * 400),
])
def test_huge_numbers_in_a_report_are_garbage_not_a_state(idle_link, old, new):
    pr, c = idle_link
    with thread_errors() as errors:
        rewrite_status(pr, old, new)
        t0 = time.monotonic()
        s = c.poll(timeout=0.3)
        pr.inject(b"ALARM:" + HUGE + b"\r\nerror:" + HUGE + b"\r\n")
        rewrite_status(pr, None, None)
        again = c.wait_for_state(lambda s: s.fresh, 5)
    assert errors == [] and c._reader.is_alive()
    assert s.state is RunState.MISSED and not s.fresh and s.t >= t0
    assert "garbled" in s.raw and new[-12:].decode() not in str(s.line)
    assert again.state is RunState.IDLE and implausible(again) is None
    assert any(b"ALARM:" + HUGE == g[1].encode() for g in c.garbage)


def test_implausible_report_is_bad_kept_raw_and_skipped(idle_link):
    pr, c = idle_link
    good = c.poll()
    rewrite_status(pr, b"MPos:0.000", b"MPos:250000.000")
    t0 = time.monotonic()
    bad = c.poll()
    rewrite_status(pr, None, None)
    assert bad.state is RunState.BAD and not bad.fresh and bad.t >= t0
    assert "250000.000" in bad.raw and "position X" in bad.raw
    assert bad.mpos == good.mpos and c.last_state.mpos == good.mpos  # skipped
    events = c.link_events()
    assert [e.kind for e in events] == [LinkKind.BAD] and "250000.000" in events[0].raw
    after = c.poll()
    assert after.fresh and after.t >= bad.t and implausible(after) is None


def test_a_failing_state_callback_is_reported_not_fatal(idle_link):
    pr, c = idle_link

    def broken(state):
        raise RuntimeError("callback bug")

    c.on_state = broken
    with thread_errors() as errors:
        s = c.poll()
        c.on_state = None
        again = c.poll()
    assert errors == [] and c._reader.is_alive() and s.fresh and again.fresh
    notes = [e for e in c.link_events() if e.kind is LinkKind.NOTE]
    assert any("callback bug" in e.message for e in notes)


# ----------------------------------------------------------------------------- freshness


def test_a_lost_or_garbled_reply_is_missed_stamped_now(idle_link):
    pr, c = idle_link
    good = c.poll()
    pr.mutate = lambda d: b"" if d.startswith(b"<") else d  # replies lost
    t0 = time.monotonic()
    lost = c.poll(timeout=0.1)
    pr.mutate = lambda d: b"{" + d[1:] if d.startswith(b"<") else d  # replies garbled
    garbled = c.poll(timeout=0.3)
    pr.mutate = None
    assert lost.state is RunState.MISSED and lost.t >= t0 > good.t and "no status report" in lost.raw
    assert lost.mpos == good.mpos
    assert garbled.state is RunState.MISSED and garbled.t >= lost.t and "{Idle|" in garbled.raw
    assert c.poll().fresh


def test_a_late_reply_is_not_taken_for_the_next_poll(idle_link):
    pr, c = idle_link
    held = []
    pr.mutate = lambda d: held.append(d) or b"" if d.startswith(b"<") else d  # the reply is held back
    missed = c.poll(timeout=0.1)
    pr.mutate = None
    arrived = threading.Event()
    c.on_state = lambda s: arrived.set()
    pr.inject(held[0].replace(b"MPos:0.000", b"MPos:7.000"))  # ... and arrives after that poll gave up
    assert arrived.wait(5)
    c.on_state = None
    t_ask = time.monotonic()
    s = c.poll()
    assert missed.state is RunState.MISSED
    assert s.fresh and s.t >= t_ask and s.mpos[0] == 0.0  # its own answer, not the late one


def test_poll_never_raises_once_connected(peers, controllers):
    _, make_peer = peers
    pr = make_peer()
    c = controllers(pr.serve_url("tcp", "rate=50&reconnect=0"))
    assert c.poll().fresh
    pr.close_transports()
    assert c.wait_disconnected(5)
    assert c.poll().state is RunState.DISCONNECTED
    c.close()
    assert c.poll().state is RunState.DISCONNECTED


# ----------------------------------------------------------------------------- attaching


def test_attach_to_a_running_machine_never_stops_it(peers, controllers):
    _, make_peer = peers
    pr = make_peer(speed=1.0)
    url = pr.serve_url("pty", "rate=50")
    first = controllers(url)
    first.send("G1 X30 F1800")
    first.wait_for_state(lambda s: s.state is RunState.RUN, 5)
    first.close()
    rt0, lines0 = len(pr.realtime_log), len(pr.received_lines)
    c = controllers(url + "&reset=1")  # even when a reset is asked for
    s = c.poll()
    # the machine runs; its work offset (WCO, sent every 30th report while busy, $# only
    # read when Idle) may not be known yet, and a position without it is BAD, not fresh
    assert s.state is RunState.RUN or (s.state is RunState.BAD and "<Run|" in s.raw and "(WCO)" in s.raw)
    assert set(pr.realtime_log[rt0:]) == {ord("?")} and pr.received_lines[lines0:] == []
    notes = [e.message for e in c.link_events() if e.kind is LinkKind.NOTE]
    assert any("not reset" in m for m in notes)
    assert any("settings" in m and "mm" in m for m in notes)  # units assumed from the report, said
    # the queries wait for Idle, then run once
    c.wait_for_state(lambda s: s.state is RunState.IDLE, 10)
    deadline = time.monotonic() + 5
    while pr.received_lines[lines0:] != HANDSHAKE and time.monotonic() < deadline:
        c.poll()
    assert pr.received_lines[lines0:] == HANDSHAKE and c.settings[13] == 0
    assert 0x18 not in pr.realtime_log[rt0:]


@pytest.mark.parametrize("state", [b"Run", b"Hold:0", b"Hold:1", b"Jog", b"Home", b"Door:0", b"Door:2",
                                   b"Door:3", b"Check", b"Sleep"])
def test_reset_asked_for_is_not_sent_unless_idle_or_alarm(peers, controllers, state):
    _, make_peer = peers
    pr = make_peer()
    rewrite_status(pr, b"<Idle|", b"<" + state + b"|")
    c = controllers(pr.serve_url("pty", "rate=50&reset=1"))
    assert c.poll().state.value == state.split(b":")[0].decode()
    assert set(pr.realtime_log) == {ord("?")} and pr.received_lines == []
    assert c.banner is None


@pytest.mark.parametrize("alarm", [False, True])
def test_reset_asked_for_when_idle_or_alarm(peers, controllers, alarm):
    _, make_peer = peers
    vm = make_vm()
    if alarm:
        vm.raise_alarm(1)
    pr = make_peer(vm)
    c = controllers(pr.serve_url("pty", "rate=50&reset=1"))
    assert 0x18 in pr.realtime_log and c.banner.version == "1.1h"
    assert pr.received_lines == ([] if alarm else HANDSHAKE)  # no $ command in alarm
    assert c.poll().state is (RunState.ALARM if alarm else RunState.IDLE)


def test_plain_driver_sends_only_status_polls_and_idle_queries(idle_link):
    pr, c = idle_link
    for s in c.states(period=0.02):
        if pr.status_requests >= 20:
            break
    c.close()
    assert set(pr.realtime_log) == {ord("?")}  # never ! ~ Ctrl-X or an override
    assert pr.received_lines == HANDSHAKE  # no program line, no $ beyond the handshake
    assert not pr._line and not pr._rx  # nothing half sent either


# ----------------------------------------------------------------------------- link drops


def _serve(pr: GrblPeer, transport: str, where) -> None:
    if transport == "pty":
        pr.serve_pty(link=where)
    else:
        pr.serve_tcp(port=where)


def _address(pr: GrblPeer, transport: str, tmp_path):
    if transport == "pty":
        where = str(tmp_path / "ttyGRBL")
        pr.serve_pty(link=where)
        return where, f"grbl://{where}?rate=50"
    port = pr.serve_tcp()
    return port, f"grbl+socket://127.0.0.1:{port}?rate=50"


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_link_drop_costs_the_outage_and_no_more(peers, controllers, tmp_path, transport):
    _, make_peer = peers
    pr = make_peer()
    where, url = _address(pr, transport, tmp_path)
    c = controllers(url)
    before = c.poll()
    assert before.fresh
    dwell = c.send("G4 P5")  # in flight when the link drops: its ok never comes
    c.link_events()
    states = []
    pr.close_transports()  # cable pulled
    assert c.wait_disconnected(5)
    polls = c.states(period=0.02)
    down = [next(polls) for _ in range(40)]  # 0.8 s away: a doubling backoff would wait 0.75 s more
    _serve(pr, transport, where)
    for s in polls:
        states.append(s)
        if s.fresh or len(states) > 100:
            break
    assert all(s.state is RunState.DISCONNECTED for s in down)
    assert states[-1].fresh and len(states) <= 10  # back within a few polls of the port
    ts = [before.t] + [s.t for s in down + states]
    assert all(b >= a for a, b in zip(ts, ts[1:]))
    assert dwell.done and dwell.failure is not None
    gap = c.gaps[-1]
    assert len(c.gaps) == 1 and gap.polls_missed >= 40 and gap.lines_lost == 1 and gap.came_back == ""
    assert states[-1].t >= gap.t_back > gap.t_lost
    events = c.link_events()
    assert [e.kind for e in events] == [LinkKind.LOST, LinkKind.BACK] and events[1].gap == gap


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_restarted_controller_is_reported_as_reset_and_handshaken_again(peers, controllers, tmp_path, transport):
    made, make_peer = peers
    pr = make_peer()
    where, url = _address(pr, transport, tmp_path)
    c = controllers(url)
    c.command("G1 X5 F3000")
    c.wait_for_state(lambda s: s.state is RunState.IDLE and s.mpos[0] == pytest.approx(5.0), 5)
    c.link_events()
    # 1: power-cycled, its boot banner arrives after the port opened (an Arduino's ~1.1 s later)
    pr.close()
    assert c.wait_disconnected(5)
    pr = make_peer()
    _serve(pr, transport, where)
    assert c.wait_connected(5) and pr.wait_for_client(5)  # the banner comes once the port is open
    t_banner = time.monotonic()
    pr.reset()
    assert c.wait_for_message(lambda m: isinstance(m, p.Banner), 5, since=t_banner)
    s = c.wait_for_state(lambda s: s.fresh, 5)
    assert s.mpos[0] == 0.0 and s.t >= c.gaps[-1].t_back
    gap = c.gaps[-1]
    assert gap.came_back.startswith("reset") and "Grbl 1.1h" in gap.came_back
    events = c.link_events()
    assert [e.kind for e in events][:3] == [LinkKind.LOST, LinkKind.BACK, LinkKind.RESET]
    deadline = time.monotonic() + 5
    while pr.received_lines != HANDSHAKE and time.monotonic() < deadline:
        c.poll()  # the handshake is done again once it answers Idle
    assert pr.received_lines == HANDSHAKE
    # 2: comes back in alarm (homing required), no banner heard
    pr.close()
    assert c.wait_disconnected(5)
    vm = make_vm()
    vm.raise_alarm(1)
    pr = make_peer(vm)
    _serve(pr, transport, where)
    s = c.wait_for_state(lambda s: s.fresh, 5)
    assert s.state is RunState.ALARM
    assert len(c.gaps) == 2 and "alarm" in c.gaps[-1].came_back
    assert LinkKind.RESET in kinds(c)
    assert pr.received_lines == []  # no $ command while in alarm
