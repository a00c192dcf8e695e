"""The live loop under link trouble (issue 11): no driver failure ends or freezes it, link
events are said, recorded and counted, a controller that never comes back ends the run
cleanly (exit 2), the run ends by itself at the program's end, and feed hold stays opt-in.

Controllers here are the virtual one (its fault injection follows the driver contract) and
small fakes; ``dexmon live`` is run through ``monitor.cli.main``.
"""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest

from drivers.state import Controller, LinkKind, MachineState, RunState, stale_state
from drivers.virtual.controller import VirtualController
from monitor.cli import main
from monitor.commands.dry_run import EXAMPLE_JOB, virtual_controller
from monitor.job import load_job
from monitor.runfile import RunWriter
from monitor.runreader import RunReader
from monitor.loop import run_controller
from monitor.program_moves import load_moves
from monitor.session import Session

PROGRAM = EXAMPLE_JOB.parent / "face.nc"


@pytest.fixture(scope="module")
def example():
    job = load_job(EXAMPLE_JOB)
    moves, program = load_moves(job)
    return job, moves, program


def _main(argv, timeout=300.0) -> int:
    """``main(argv)`` on a thread, so a run that never ends fails the test instead of
    hanging it."""
    result = []
    worker = threading.Thread(target=lambda: result.append(main(argv)), daemon=True)
    worker.start()
    worker.join(timeout)
    assert not worker.is_alive(), f"dexmon {' '.join(argv[:2])} did not end within {timeout} s"
    return result[0]


def _url(faults: str = "", speed: int = 20) -> str:
    """The example program on the virtual controller, stepped (one poll = speed/50 s)."""
    return f"virtual://{PROGRAM}?clock=sim&speed={speed}&rate=50" + (f"&faults={faults}" if faults else "")


class Flaky(Controller):
    """The virtual controller behind a driver that raises on every ``every``-th poll."""

    def __init__(self, inner, every: int = 7):
        self.inner, self.every, self.polls, self.raised = inner, every, 0, 0
        self.gaps = []

    def connect(self):
        self.inner.connect()

    def close(self):
        self.inner.close()

    def poll(self):
        self.polls += 1
        if self.polls % self.every == 0:
            self.raised += 1
            raise RuntimeError(f"driver bug #{self.raised}")
        return self.inner.poll()


def test_driver_exceptions_are_missed_polls_and_the_run_goes_on_to_the_end(example, tmp_path):
    job, moves, program = example
    flaky = Flaky(virtual_controller(moves, speed=5.0, rate=50, clock="sim"))
    with RunWriter(tmp_path / "r.sqlite") as w:
        s = Session(job, moves, run=w, program=program)
        flaky.connect()
        run_controller(s, flaky, 0.0, max_seconds=120)
        flaky.close()
        summary = s.finish()
    assert s.end_reason == "program end"  # no done(): idle at the last motion's end
    assert flaky.raised > 10 and summary["missed"] == flaky.raised
    st = RunReader(tmp_path / "r.sqlite").states()
    assert list(st["state"]).count("Missed") == flaky.raised
    assert np.all(np.diff(st["t"]) >= 0)
    assert st["state"][-1] == "Idle"
    assert {("gouge", 22), ("rapid_into_stock", 36)} <= {(f["kind"], f["line"]) for f in s.findings}


def test_run_ends_when_the_machine_is_idle_at_the_programs_end(example):
    """The machine runs the program and then stands idle at its final position forever
    (no ``done``): the loop ends by itself there, not at the table's last row (M30)."""
    job, moves, program = example
    vc = virtual_controller(moves, speed=5.0, rate=50, clock="sim")
    s = Session(job, moves, program=program)
    vc.connect()
    run_controller(s, vc, 0.0, max_seconds=120)
    final = vc.poll()
    vc.close()
    assert s.end_reason == "program end"
    assert final.state == RunState.IDLE and s.last.mpos == final.mpos


class Gone(Controller):
    """A controller that connected once and never came back: DISCONNECTED for ever."""

    def __init__(self):
        self.gaps, self.t = [], 0.0
        self.queued = False

    def connect(self):
        self._link_event(LinkKind.LOST, "tcp://10.0.0.9:23: connection reset", t=0.0)

    def close(self):
        pass

    def poll(self):
        self.t += 0.01
        return stale_state(None, RunState.DISCONNECTED, self.t, "tcp://10.0.0.9:23: connection refused")


def test_a_controller_that_never_comes_back_is_said_and_given_up(example):
    job, moves, program = example
    s = Session(job, moves, program=program)
    told = []
    gone = Gone()
    gone.connect()
    n = run_controller(s, gone, 0.005, notify=told.append, give_up_s=1.0, notice_every=0.05)
    assert s.end_reason.startswith("gave up") and "give-up time 1 s" in s.end_reason
    assert "connection refused" in s.end_reason
    assert s.counts["disconnected"] == n
    notices = [r for r in told if r["event"] == "lost"]
    assert notices and all(r["message"].startswith("controller lost for") and r["message"].endswith("retrying")
                           for r in notices)
    assert told[0] == {"event": "link", "kind": "lost", "message": "tcp://10.0.0.9:23: connection reset", "t": 0.0}


def test_cli_give_up_exits_2_with_reason_summary_and_run_file(tmp_path, capsys):
    run = tmp_path / "r.sqlite"
    code = _main(["live", str(EXAMPLE_JOB), "--controller", _url("disconnect:0,disconnect_for:1e9"),
                  "--give-up", "0.5", "--json", "--run", str(run)])
    out, err = capsys.readouterr()
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "gave up" in err
    events = [json.loads(x) for x in out.splitlines()]
    assert events[0]["event"] == "start"
    assert {"event": "link", "kind": "lost"}.items() <= events[1].items()
    summary = events[-1]
    assert summary["event"] == "summary" and summary["ended"].startswith("gave up")
    assert summary["disconnected"] > 0 and summary["gaps"][0]["t_back"] is None
    r = RunReader(run)  # closed and complete
    assert json.loads(r.meta()["summary"])["disconnected"] == summary["disconnected"]
    kinds = [e["kind"] for e in r.link_events()]
    assert kinds[0] == "lost" and kinds[-1] == "gap"  # the gap the run ended in
    report = tmp_path / "r.html"
    assert main(["report", str(run), "-o", str(report)]) == 0
    assert "<td>not back</td>" in report.read_text()


def test_cli_link_events_gaps_and_missed_polls(tmp_path, capsys):
    """The virtual link drops for 2 s of machine time and garbles some replies: each link
    event is one JSON line and a run-file row, the gap is told when it closes, and the
    summary counts the missed polls and lists the gap; the run ends at the program's end."""
    run = tmp_path / "r.sqlite"
    code = _main(["live", str(EXAMPLE_JOB), "--controller", _url("disconnect:8,disconnect_for:2,garble:0.05,seed:2"),
                  "--json", "--run", str(run)])
    out = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert code == 1  # the planted findings
    links = [e for e in out if e["event"] == "link"]
    assert [e["kind"] for e in links] == ["lost", "back"]
    gaps = [e for e in out if e["event"] == "gap"]
    assert len(gaps) == 1 and gaps[0]["polls_missed"] >= 4 and gaps[0]["resync"]["how"] != "lost"
    summary = out[-1]
    assert summary["ended"] == "program end"
    assert summary["missed"] > 0 and summary["disconnected"] == gaps[0]["disconnected"] > 0
    assert [g["message"] for g in summary["gaps"]] == [gaps[0]["message"]]
    r = RunReader(run)
    assert [e["kind"] for e in r.link_events()] == ["lost", "back", "gap"]
    st = r.states()
    assert list(st["state"]).count("Missed") == summary["missed"]
    assert list(st["state"]).count("Disconnected") == summary["disconnected"]


def test_cli_terminal_says_link_trouble_and_gaps(tmp_path, capsys):
    code = _main(["live", str(EXAMPLE_JOB), "--controller", _url("disconnect:8,disconnect_for:2"),
                  "--run", str(tmp_path / "r.sqlite")])
    out = capsys.readouterr().out
    assert code == 1
    assert "link: " in out and "link back after" in out
    assert "gap: link gap of" in out and "polls missed" in out and "re-synced at line" in out
    assert "disconnected poll(s), 1 gap(s)" in out


@pytest.mark.parametrize("flag", [False, True])
def test_feed_hold_only_when_enabled(tmp_path, monkeypatch, flag):
    """The monitor sends feed hold only with --feed-hold (or the job's actions): never
    otherwise, whatever it finds."""
    calls = []
    monkeypatch.setattr(VirtualController, "feed_hold", lambda self: calls.append(self))
    argv = ["live", str(EXAMPLE_JOB), "--controller", _url(), "--quiet", "--run", str(tmp_path / "r.sqlite")]
    code = _main(argv + (["--feed-hold"] if flag else []))
    assert code == 1  # findings either way
    assert (len(calls) > 0) == flag


def test_status_line_says_the_controller_is_lost():
    from monitor.status import status_text

    st = MachineState(t=1.0, mpos=(1, 2, 3), state=RunState.DISCONNECTED, raw="port gone")
    text = status_text(st, None, 10.0, 0, note="lost 30 s, retrying").plain
    assert text.startswith("state Disconnected") and text.endswith("lost 30 s, retrying")
