"""The passthrough as a Controller keeps the driver/monitor contract (drivers.state):
fresh states only, MISSED/BAD/DISCONNECTED otherwise, Gap records and LinkEvents, quick
retries while the machine's port is gone, and no thread dies quietly.

Most tests drive a scripted machine on a TCP socket (the passthrough reaches it with a
pyserial ``socket://`` URL): the test decides what each ``?`` gets back.
"""

from __future__ import annotations

import select
import socket
import threading
import time

import pytest

from drivers.grbl import passthrough as pt_mod
from drivers.grbl.passthrough import Passthrough
from drivers.grbl.peer import GrblPeer
from drivers.state import Gap, LinkKind, RunState
from drivers.virtual.machine import VirtualMachine
from drivers.virtual.machine_config import MachineConfig

WAIT = 10.0  # generous timeout of every wait, s

# a first report after a reset carries WCO (report.c); without one the passthrough cannot know
# the work offset and keeps the state BAD (see test_driver_peer)
IDLE = "<Idle|MPos:1.000,2.000,3.000|FS:0,0|WCO:0.000,0.000,0.000>"


class ScriptedMachine:
    """A GRBL machine on a TCP socket whose answers the test scripts.

    Each ``?`` gets ``reports[0]`` (popped while more than one is left: the last one
    repeats); each line gets ``ok``. ``push(data)`` sends bytes unasked.
    """

    def __init__(self, reports: list[str]):
        self.reports = list(reports)
        self.answer_lines = True
        self._buf = b""
        self.queries = 0
        self.lines: list[bytes] = []
        self._cond = threading.Condition()
        self.server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.server.bind(("127.0.0.1", 0))
        self.server.listen(1)
        self.port = self.server.getsockname()[1]
        self.conn: socket.socket | None = None
        threading.Thread(target=self._serve, daemon=True).start()

    @property
    def url(self) -> str:
        return f"socket://127.0.0.1:{self.port}"

    def _serve(self) -> None:
        try:
            conn, _ = self.server.accept()
        except OSError:
            return
        self.conn = conn
        while True:
            try:
                data = conn.recv(4096)
            except OSError:
                return
            if not data:
                return
            try:
                self._answer(conn, data)
            except OSError:  # closed by the test
                return

    def _answer(self, conn: socket.socket, data: bytes) -> None:
        for b in data:
            if b == ord("?"):
                with self._cond:
                    text = self.reports.pop(0) if len(self.reports) > 1 else self.reports[0]
                    self.queries += 1
                    self._cond.notify_all()
                conn.sendall(text.encode() + b"\r\n")
            elif b == ord("\n"):
                with self._cond:
                    self.lines.append(self._buf)
                    self._cond.notify_all()
                self._buf = b""
                if self.answer_lines:
                    conn.sendall(b"ok\r\n")
            else:
                self._buf += bytes([b])

    def wait_queries(self, n: int) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: self.queries >= n, WAIT)

    def wait_lines(self, n: int) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: len(self.lines) >= n, WAIT)

    def push(self, data: bytes) -> None:
        assert self.conn is not None
        self.conn.sendall(data)

    def close(self) -> None:
        if self.conn is not None:
            self.conn.close()
        self.server.close()


class TcpSender:
    """A sender on the passthrough's TCP port that keeps every line it receives."""

    def __init__(self, port: int):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=WAIT)
        self.rx = b""

    def read_until(self, marker: bytes, count: int = 1) -> bytes:
        deadline = time.monotonic() + WAIT
        while self.rx.count(marker) < count:
            assert select.select([self.sock], [], [], max(0.0, deadline - time.monotonic()))[0], \
                f"sender: {marker!r} did not arrive (got {self.rx!r})"
            data = self.sock.recv(4096)
            assert data, "sender: connection closed"
            self.rx += data
        return self.rx


def _passthrough(url: str, **kw) -> Passthrough:
    pt = Passthrough(url, rate=50, pty=False, tcp_port=0, **kw)
    pt.start()
    return pt


@pytest.fixture
def scripted():
    made = []

    def make(reports):
        m = ScriptedMachine(reports)
        pt = _passthrough(m.url)
        made.append((m, pt))
        return m, pt

    yield make
    for m, pt in made:
        pt.close()
        m.close()


def _poll_until(pt, wanted, polls: int = 500):
    """Poll until ``wanted(state)``; the state, or an AssertionError after ``polls``."""
    for _ in range(polls):
        st = pt.poll(timeout=WAIT)
        if wanted(st):
            return st
    raise AssertionError(f"no wanted state in {polls} polls; the last: {st}")


def _events(pt, kind):
    return [ev for ev in pt.link_events() if ev.kind is kind]


def test_poll_never_returns_an_old_state_again(scripted):
    """One report, then the machine goes quiet: MISSED stamped now, never the old state."""
    m, pt = scripted([IDLE, ""])  # the second and later '?' get an empty line
    first = pt.poll(timeout=WAIT)
    assert first.fresh and first.mpos[:3] == (1.0, 2.0, 3.0)
    assert m.wait_queries(3)  # the passthrough keeps polling the silent machine
    later = [pt.poll(timeout=0.2) for _ in range(3)]
    assert [s.state for s in later] == [RunState.MISSED] * 3
    assert all(s.mpos == first.mpos for s in later)   # the last known position
    ts = [first.t] + [s.t for s in later]
    assert ts == sorted(ts) and later[0].t > first.t  # stamped now, never backwards


def test_poll_before_any_report_is_missed_not_an_exception(scripted):
    m, pt = scripted([""])
    st = pt.poll(timeout=0.1)
    assert st.state is RunState.MISSED and "no status report" in st.raw


def test_implausible_report_is_bad_and_forwarded_unchanged(scripted):
    m, pt = scripted([IDLE])
    sender = TcpSender(pt.sender_port)
    assert pt.poll(timeout=WAIT).fresh
    far = "<Idle|MPos:200000.000,0.000,0.000|FS:0,0>"
    m.reports[:] = [far]
    sender.sock.sendall(b"?")  # the sender asks: it gets exactly what the machine said
    assert far.encode() in sender.read_until(far.encode())
    bad = _poll_until(pt, lambda s: not s.fresh)  # an own poll's IDLE may come first
    assert bad.state is RunState.BAD and far in bad.raw and bad.mpos[:3] == (1.0, 2.0, 3.0)
    assert pt.last_state.mpos[0] == 1.0  # the model never sees the far position
    bads = _events(pt, LinkKind.BAD)
    assert len(bads) == 1 and far in bads[0].raw  # once for the run of far reports
    m.reports[:] = [IDLE]
    st = _poll_until(pt, lambda s: s.fresh)
    assert st.mpos[:3] == (1.0, 2.0, 3.0)


def test_garbage_reaches_the_sender_and_breaks_nothing(scripted):
    m, pt = scripted([IDLE])
    sender = TcpSender(pt.sender_port)
    assert pt.poll(timeout=WAIT).fresh
    # an unparsable setting value (inf) and noise pushed unasked; replies to own polls
    # with a huge line number, and garbage: the poller must not wait for those forever
    huge = "<Run|MPos:9999999.000,0.000,0.000|FS:0,0>"  # 10 km: parses, but no machine's
    huge_ln = "<Run|MPos:0.000,0.000,0.000|Ln:" + "9" * 30 + "|FS:0,0>"  # garbage: no GRBL line number
    m.reports[:] = [huge_ln, huge, "<Idle|MPos:1.0,zz", "", IDLE]
    m.push(b"$13=" + b"9" * 400 + b"\r\n\xff\xfe<Idle|MPos:zz\r\n")
    got = sender.read_until(b"<Idle|MPos:zz")
    assert b"$13=" + b"9" * 400 + b"\r\n\xff\xfe<Idle|MPos:zz" in got  # forwarded as they came
    assert pt.wait_connected(0)
    fresh = 0
    for _ in range(200):
        st = pt.poll(timeout=WAIT)
        fresh += st.fresh
        if fresh >= 3:
            break
    assert fresh >= 3 and st.mpos[:3] == (1.0, 2.0, 3.0)
    assert 13 not in pt.settings  # an infinite setting is not learned
    bads = _events(pt, LinkKind.BAD)
    assert len(bads) == 1 and "position" in bads[0].message and huge in bads[0].raw


def test_a_failing_callback_kills_no_thread(scripted):
    """on_state (machine reader) and on_line (endpoint reader) raising: reported, and
    the passthrough goes on forwarding both ways."""
    m, pt = scripted([IDLE])
    calls = {"state": 0, "line": 0}
    three_states = threading.Event()

    def bad_state(state):
        calls["state"] += 1
        if calls["state"] >= 3:
            three_states.set()
        raise RuntimeError("monitor bug")

    def bad_line(line):
        calls["line"] += 1
        raise RuntimeError("linesync bug")

    pt.on_state, pt.on_line = bad_state, bad_line
    sender = TcpSender(pt.sender_port)
    for k in range(3):
        sender.sock.sendall(b"G4 P0\n?")
        sender.read_until(b"ok\r\n", count=k + 1)
    # the reports reach on_state on the machine reader's thread, maybe after the oks
    assert calls["line"] == 3 and three_states.wait(WAIT)
    assert pt.wait_lines(3, WAIT)
    assert pt.poll(timeout=WAIT).fresh
    notes = _events(pt, LinkKind.NOTE)
    assert any("monitor bug" in ev.message for ev in notes)
    assert any("linesync bug" in ev.message for ev in notes)


def _peer():
    vm = VirtualMachine(MachineConfig(max_rate=(3000.0,) * 3, accel=(200.0,) * 3,
                                      travel_min=(-200.0,) * 3, travel_max=(200.0,) * 3))
    return GrblPeer(vm, speed=4.0)


def test_lost_and_back_are_a_gap_and_events():
    peer = _peer()
    port = peer.serve_tcp()
    pt = _passthrough(f"socket://127.0.0.1:{port}")
    try:
        sender = TcpSender(pt.sender_port)
        sender.sock.sendall(b"G4 P0\n")
        sender.read_until(b"ok\r\n")
        assert pt.poll(timeout=WAIT).fresh
        peer.close_transports()
        st = _poll_until(pt, lambda s: s.state is RunState.DISCONNECTED)
        assert "lost" in st.raw
        missed = [pt.poll(timeout=WAIT) for _ in range(3)]
        assert all(s.state is RunState.DISCONNECTED for s in missed)
        peer.serve_tcp(port=port)
        assert pt.wait_connected(WAIT)
        assert len(pt.gaps) == 1
        gap = pt.gaps[0]
        assert isinstance(gap, Gap) and gap.t_back > gap.t_lost and gap.polls_missed >= 4
        assert gap.reason
        events = [ev for ev in pt.link_events() if ev.kind in (LinkKind.LOST, LinkKind.BACK)]
        assert [ev.kind for ev in events] == [LinkKind.LOST, LinkKind.BACK]
        assert events[1].gap == gap and str(port) in events[1].message
        _poll_until(pt, lambda s: s.fresh)
    finally:
        pt.close()
        peer.close()


def test_lines_in_flight_when_the_link_drops_are_lost():
    m = ScriptedMachine([IDLE])
    m.answer_lines = False
    pt = _passthrough(m.url)
    try:
        sender = TcpSender(pt.sender_port)
        sender.sock.sendall(b"G1 X1\nG1 X2\n")
        assert m.wait_lines(2) and pt.wait_lines(2, WAIT, acked=False)
        assert [line.result for line in pt.lines] == [None, None]
        m.close()  # the machine goes, and stays away, with both lines unanswered
        deadline = time.monotonic() + WAIT
        while any(line.result is None for line in pt.lines) and time.monotonic() < deadline:
            pt.poll(timeout=0.1)
        assert [line.result for line in pt.lines] == ["lost", "lost"]
        sender.sock.sendall(b"G1 X3\n")  # sent while the machine is away: lost at once
        assert pt.wait_lines(3, WAIT) and pt.lines[2].result == "lost"
    finally:
        pt.close()
        m.close()


def test_retries_stay_quick_while_the_port_is_gone(monkeypatch):
    """Forty failed opens in a row: the pause between attempts never grows (the old
    backoff doubled to 2 s)."""
    peer = _peer()
    port = peer.serve_tcp()
    pt = _passthrough(f"socket://127.0.0.1:{port}")
    attempts: list[float] = []
    done = threading.Event()
    real_open = pt._open

    def failing_open():
        attempts.append(time.monotonic())
        if len(attempts) < 40:
            raise pt_mod.ConnectionLost("test: still gone")
        done.set()
        return real_open()

    try:
        assert pt.poll(timeout=WAIT).fresh
        monkeypatch.setattr(pt, "_open", failing_open)
        peer.close_transports()
        peer.serve_tcp(port=port)
        assert done.wait(30.0)
        assert pt.wait_connected(WAIT)
        pauses = [b - a for a, b in zip(attempts, attempts[1:])]
        # 0.05 s apart; even a loaded machine stays far from the doubling backoff's seconds
        assert max(pauses) < 1.0, pauses
    finally:
        pt.close()
        peer.close()


def test_reset_banner_is_a_reset_event_and_flushes_lines_in_flight():
    peer = _peer()
    pt = _passthrough(f"socket://127.0.0.1:{peer.serve_tcp()}")
    try:
        sender = TcpSender(pt.sender_port)
        sender.sock.sendall(b"\x18")
        sender.read_until(b"Grbl 1.1h")
        deadline = time.monotonic() + WAIT
        while not (resets := _events(pt, LinkKind.RESET)) and time.monotonic() < deadline:
            pt.poll(timeout=0.1)
        assert len(resets) == 1 and "Grbl 1.1h" in resets[0].raw
    finally:
        pt.close()
        peer.close()


def test_work_positions_wait_for_the_offset_and_take_it_from_dollar_hash_passing_by(scripted):
    """WPos = MPos - WCO, and WCO comes every 10th-30th report: before the passthrough
    knows it, a work position is no position (BAD, told once); the sender's $# and $G
    passing by tell it the offset in force, as the reports would."""
    wpos = "<Idle|WPos:4.000,-1.000,2.500|FS:0,0>"
    m, pt = scripted([wpos])
    first = pt.poll(timeout=WAIT)
    assert first.state is RunState.BAD and "(WCO)" in first.raw
    assert _poll_until(pt, lambda s: s.state is RunState.BAD).state is RunState.BAD
    assert len([e for e in _events(pt, LinkKind.BAD) if "(WCO)" in e.message]) == 1
    m.push(b"[G54:-5.000,2.000,-1.000]\r\n[G55:0.000,0.000,0.000]\r\n[G92:1.000,0.000,0.000]\r\n"
           b"[TLO:0.500]\r\n[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]\r\n")
    st = _poll_until(pt, lambda s: s.fresh)
    # WCO = G54 + G92 + TLO on Z = (-4, 2, -0.5): MPos = WPos + WCO
    assert st.wco[:3] == pytest.approx((-4.0, 2.0, -0.5)) and st.mpos[:3] == pytest.approx((0.0, 1.0, 2.0))
    # a report's own WCO wins over what $# said
    m.reports[:] = ["<Idle|WPos:4.000,-1.000,2.500|FS:0,0|WCO:0.000,0.000,0.000>"]
    assert _poll_until(pt, lambda s: s.fresh and s.mpos[0] == 4.0).wco[:3] == (0.0, 0.0, 0.0)
