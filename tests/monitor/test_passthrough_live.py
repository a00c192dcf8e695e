"""``dexmon live --controller grbl+passthrough://...``: the GRBL peer stands for the machine,
the passthrough sits between it and a scripted sender that streams the bundled example's
program through the offered pty, and the live session follows the stream (line sync) and
finds the planted faults."""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest
import serial

from drivers.errors import DriverError
from drivers.grbl.passthrough import Passthrough
from drivers.registry import open_controller
from drivers.state import MachineState, RunState
from monitor.cli import main
from monitor.commands.dry_run import EXAMPLE_JOB
from monitor.job import load_job
from monitor.linesync import StreamedLines, normalise
from monitor.runreader import RunReader
from monitor.program_moves import load_moves
from monitor.sync import ProgramPath, ProgramSync
from sim.gcode.moves import MoveKind, empty_moves
from tests.monitor.test_dry_run import check_planted

RX_BUFFER = 127  # bytes a character-counting sender keeps in GRBL's 128-byte buffer


class CountingSender:
    """A sender as UGS/CNCjs stream: character counting, a '?' now and then, on a pty."""

    def __init__(self, path: str):
        self.port = serial.serial_for_url(path, baudrate=115200, timeout=30)
        self.replies: list[tuple[str, str]] = []
        self.reports = 0

    def _reply(self) -> str:
        while True:
            data = self.port.read_until(b"\n")
            if not data.endswith(b"\n"):
                raise AssertionError(f"sender: no reply (got {data!r})")
            text = data.decode("ascii", "replace").strip()
            if text.startswith("<"):
                self.reports += 1
            elif text == "ok" or text.startswith("error:"):
                return text

    def stream(self, lines: list[str], query_every: int = 4) -> None:
        in_flight: list[tuple[str, int]] = []
        for k, line in enumerate(lines):
            data = line.encode("ascii") + b"\n"
            while in_flight and sum(n for _, n in in_flight) + len(data) > RX_BUFFER:
                self.replies.append((in_flight.pop(0)[0], self._reply()))
            self.port.write(data)
            in_flight.append((line, len(data)))
            if k % query_every == 0:
                self.port.write(b"?")
        while in_flight:
            self.replies.append((in_flight.pop(0)[0], self._reply()))

    def close(self) -> None:
        self.port.close()


@pytest.fixture
def machine():
    """The GRBL peer on a pty, its virtual machine where the program starts."""
    from drivers.grbl.peer import GrblPeer
    from drivers.virtual.machine import VirtualMachine
    from drivers.virtual.machine_config import MachineConfig
    from monitor.commands.dry_run import VIRTUAL_ACCEL, VIRTUAL_MAX_RATE

    job = load_job(EXAMPLE_JOB)
    moves, _ = load_moves(job)
    vm = VirtualMachine(MachineConfig(max_rate=VIRTUAL_MAX_RATE, accel=VIRTUAL_ACCEL, soft_limits=False),
                        position=moves["start"][0])
    peer = GrblPeer(vm, speed=10.0)
    try:
        yield peer, peer.serve_pty()
    finally:
        peer.close()


def test_live_follows_a_sender_through_the_passthrough(machine, tmp_path, monkeypatch, capsys):
    peer, machine_path = machine
    program = EXAMPLE_JOB.parent.joinpath("face.nc").read_text().splitlines()
    started = threading.Event()
    box: dict = {}
    real_start = Passthrough.start

    def start(self):  # the test's sender learns the pty the way a user reads it: at start
        path = real_start(self)
        box["pt"] = self
        started.set()
        return path

    monkeypatch.setattr(Passthrough, "start", start)
    # count the states the session synced on a streamed line
    real_line_for = StreamedLines.line_for
    picks: list[int | None] = []

    def line_for(self, state, tip, sync):
        got = real_line_for(self, state, tip, sync)
        picks.append(got)
        return got

    monkeypatch.setattr(StreamedLines, "line_for", line_for)

    def sender():
        if not started.wait(120):  # warm-up compiles the kernels on a cold cache
            box["error"] = "the passthrough never started"
            return
        s = CountingSender(box["pt"].sender_path)
        try:
            s.stream(program)
            box["replies"] = s.replies
        except Exception as exc:  # noqa: BLE001 - reported by the test below
            box["error"] = repr(exc)
        finally:
            s.close()

    th = threading.Thread(target=sender, daemon=True)
    th.start()
    run = tmp_path / "run.sqlite"
    code = main(["live", str(EXAMPLE_JOB), "--controller", f"grbl+passthrough://{machine_path}?tcp=0&rate=50",
                 "--json", "--run", str(run)])
    th.join(30)
    assert "error" not in box, box.get("error")
    out = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert code == 1, out
    # the endpoints the user points the sender at are told at start
    assert out[0]["event"] == "start" and out[0]["controller"].startswith("grbl+passthrough://")
    ends = out[1]
    assert ends["event"] == "passthrough" and ends["pty"] == box["pt"].sender_path
    assert ends["tcp"] > 0 and ends["machine"] == machine_path
    # the program went through unchanged and every line was answered
    assert [r[0] for r in box["replies"]] == program
    assert peer.received_lines == program
    findings = [x for x in out if x["event"] == "finding"]
    check_planted(findings)
    assert out[-1]["event"] == "summary" and out[-1]["progress_s"] == pytest.approx(out[-1]["program_s"], abs=0.5)
    # the session followed the stream: most states synced on a line the sender streamed
    # (which lines a state happens to fall on depends on the machine's speed: the planted
    # findings' lines are checked above, through the findings themselves)
    on_line = [p for p in picks if p is not None]
    assert len(on_line) > 0.8 * len(picks) and len(set(on_line)) >= 10, picks
    r = RunReader(run)
    assert r.state_count() == len(picks) and len(list(r.cuts())) > 20


# --- URLs ---------------------------------------------------------------------------------

def test_passthrough_urls():
    pt = open_controller("grbl+passthrough:///dev/ttyUSB7?tcp=0&rate=25&link=/tmp/x-grbl")
    assert isinstance(pt, Passthrough)
    assert (pt.port, pt.rate, pt._tcp_port, pt._link, pt._want_pty) == ("/dev/ttyUSB7", 25.0, 0, "/tmp/x-grbl", True)
    assert pt.url == "grbl+passthrough:///dev/ttyUSB7?tcp=0&rate=25&link=/tmp/x-grbl"
    net = open_controller("grbl+passthrough+socket://10.0.0.5:23?pty=0&tcp=2323&host=0.0.0.0")
    assert (net.port, net._want_pty, net._tcp_port, net._tcp_host) == ("socket://10.0.0.5:23", False, 2323, "0.0.0.0")
    with pytest.raises(DriverError, match="unknown parameter 'speed'"):
        open_controller("grbl+passthrough:///dev/ttyUSB0?speed=2")
    with pytest.raises(DriverError, match="pty=0 needs tcp=PORT"):
        open_controller("grbl+passthrough:///dev/ttyUSB0?pty=0")
    with pytest.raises(DriverError, match="expected host:port"):
        open_controller("grbl+passthrough+socket:///nohost")
    with pytest.raises(DriverError, match="not a number"):
        open_controller("grbl+passthrough:///dev/ttyUSB0?tcp=x")


def test_cli_reports_a_missing_machine_port_in_one_line(tmp_path, capsys):
    code = main(["live", str(EXAMPLE_JOB), "--controller", f"grbl+passthrough://{tmp_path}/no-such-port",
                 "--quiet", "--run", str(tmp_path / "r.sqlite")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "no such serial device" in err[0] and "no-such-port" in err[0]


# --- line sync from the stream, without a machine -------------------------------------------

class FakeLine:
    def __init__(self, text, result="ok", n=None):
        self.text, self.result, self.n = text, result, n


class FakeStream:
    def __init__(self):
        self.learned_lines: list[FakeLine] = []
        self.last_state = None


def test_normalise_matches_what_senders_rewrite():
    assert normalise("G1 X68 F1200 (cut)") == normalise("N120 g1x68.000f1200.") == "G1.0000 X68.0000 F1200.0000"
    assert normalise("(only a comment)") is None and normalise("  ") is None and normalise("$H") is None
    assert normalise("G1 X[#1+2]") == "G1X[#1+2]"


def _two_passes():
    """Source lines 1-6: the same square path twice (a spring pass), each edge its line."""
    corners = np.array([[0, 0, -1], [20, 0, -1], [20, 20, -1], [0, 0, -1]], np.float64)
    text = "G90 G21\nG1 X20 Y0 Z-1 F600\nG1 X20 Y20\nG1 X0 Y0\nG1 X20 Y0 (second pass)\nG1 X20 Y20\nG1 X0 Y0\n"
    m = empty_moves(6)
    m["kind"] = MoveKind.FEED
    m["feed"] = 600.0
    m["line"] = [2, 3, 4, 5, 6, 7]
    for k in range(6):
        a, b = corners[k % 3], corners[k % 3 + 1]
        m["start"][k, :3], m["end"][k, :3] = a, b
    return text, m


def test_line_sync_tells_a_repeated_pass_apart():
    text, m = _two_passes()
    path = ProgramPath.from_moves(m, position="machine")
    ctl = FakeStream()
    lines = StreamedLines(ctl, text, m)
    # a sender that numbers its lines and drops comments still maps onto the source lines
    for t in ("G90 G21", "N1 G1 X20 Y0 Z-1 F600", "N2 G1 X20 Y20", "G1 X0 Y0.000"):
        ctl.learned_lines.append(FakeLine(t))
    assert lines.window(MachineState(t=0, mpos=(0,) * 3)) == [2, 3, 4] and lines.mapped == [1, 2, 3, 4]
    ctl.learned_lines.clear()
    lines = StreamedLines(ctl, text, m)
    for t in ("G90 G21", "G1 X20 Y0 Z-1 F600", "G1 X20 Y20", "G1 X0 Y0", "G1 X20 Y0", "G1 X20 Y20"):
        ctl.learned_lines.append(FakeLine(t))
    ctl.learned_lines[-1].result = None  # in flight
    # Bf: 2 of 15 planner blocks in use: the two newest acknowledged lines (4, 5), and 6 in
    # flight; the tip half-way up the right edge is on line 3 or 6 by position: 6 by stream
    sync = ProgramSync(path)
    state = MachineState(t=1.0, mpos=(20, 10, -1), state=RunState.RUN, buffer=(13, 100))
    assert lines.window(state) == [4, 5, 6]
    assert lines.line_for(state, np.array([20.0, 10.0, -1.0]), sync) == 6
    got = sync.update(np.array([20.0, 10.0, -1.0]), t=1.0, line=6)
    assert got.row == 4 and got.how == "line"
    # position sync alone takes the first pass
    assert ProgramSync(path).update(np.array([20.0, 10.0, -1.0]), t=1.0).row == 1


def test_ln_reports_map_through_the_n_words_the_sender_added():
    text, m = _two_passes()
    ctl = FakeStream()
    lines = StreamedLines(ctl, text, m)
    for k, t in enumerate(("G90 G21", "G1 X20 Y0 Z-1 F600", "G1 X20 Y20", "G1 X0 Y0", "G1 X20 Y0")):
        ctl.learned_lines.append(FakeLine(f"N{10 * (k + 1)} {t}", n=10 * (k + 1)))
    sync = ProgramSync(ProgramPath.from_moves(m, position="machine"))
    st = MachineState(t=0, mpos=(10, 0, -1), state=RunState.RUN, line=50)
    assert lines.line_for(st, np.array([10.0, 0.0, -1.0]), sync) == 5  # N50 is source line 5


def test_refused_lines_are_not_candidates_and_finished_needs_idle():
    text, m = _two_passes()
    ctl = FakeStream()
    lines = StreamedLines(ctl, text, m)
    for t, res in (("G90 G21", "ok"), ("G1 X20 Y0 Z-1 F600", "ok"), ("G1 X20 Y20", "error:33"),
                   ("G1 X0 Y0", "ok")):
        ctl.learned_lines.append(FakeLine(t, res))
    assert lines.window(MachineState(t=0, mpos=(0,) * 3, state=RunState.RUN)) == [2, 4]
    for t in ("G1 X20 Y0", "G1 X20 Y20", "G1 X0 Y0"):
        ctl.learned_lines.append(FakeLine(t))
    ctl.last_state = MachineState(t=0, mpos=(0,) * 3, state=RunState.IDLE)
    assert lines.finished()
    ctl.last_state = MachineState(t=0, mpos=(0,) * 3, state=RunState.RUN)
    assert not lines.finished()
    ctl.learned_lines[-1].result = None
    ctl.last_state = MachineState(t=0, mpos=(0,) * 3, state=RunState.IDLE)
    assert not lines.finished()
