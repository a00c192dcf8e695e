"""After a feed hold dexmon says at once, on every output, that it sent the hold, why and how
to go on; it keeps following the machine after a resume and ends when the program ends."""

from __future__ import annotations

import argparse
import json

import pytest

from drivers.state import RunState
from monitor.commands.dry_run import EXAMPLE_JOB, VIRTUAL_MACHINE, virtual_controller
from monitor.commands.live import run_session
from monitor.job import load_job
from monitor.runreader import RunReader
from monitor.program_moves import load_moves

#: polls the test leaves the machine held before it resumes it (as a machinist would, later)
HELD_POLLS = 10


class ResumingMachine:
    """The virtual controller (simulated clock: time moves per poll, not per wall second)
    with a machinist beside it: every hold is resumed after :data:`HELD_POLLS` polls at
    rest (``Hold:0``, when GRBL takes a cycle start). Counts the holds dexmon sends."""

    def __init__(self, controller):
        self.controller = controller
        self.holds = 0
        self.resumes = 0
        self.states_seen: list[RunState] = []

    def __getattr__(self, name):
        return getattr(self.controller, name)

    def feed_hold(self) -> None:
        self.holds += 1
        self.controller.feed_hold()

    def states(self, period):
        held = 0
        while True:
            st = self.controller.poll()
            self.states_seen.append(st.state)
            held = held + 1 if st.state == RunState.HOLD and st.substate == 0 else 0
            if held == HELD_POLLS:
                self.controller.resume()
                self.resumes += 1
            yield st


@pytest.fixture(scope="module")
def hold_job():
    job = load_job(EXAMPLE_JOB)
    job.alerts = tuple(job.alerts) + ("feed_hold",)
    job.machine = dict(VIRTUAL_MACHINE)
    moves, _ = load_moves(job)
    return job, moves


def _run(job, moves, tmp_path, as_json: bool):
    vc = virtual_controller(moves, 1.0, job.poll_hz, clock="sim")
    machine = ResumingMachine(vc)
    args = argparse.Namespace(run=str(tmp_path / "r.sqlite"), json=as_json, quiet=False, view=False, frames=None)
    code = run_session(args, job, machine, done=lambda: vc.done)
    return code, machine


def test_hold_said_in_json_then_resumed_and_followed_to_the_end(hold_job, tmp_path, capsys):
    job, moves = hold_job
    code, machine = _run(job, moves, tmp_path, as_json=True)
    out = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert code == 1
    findings = [x for x in out if x["event"] == "finding"]
    holds = [x for x in out if x["event"] == "feed_hold"]
    # one hold per finding that justifies one, each sent once, each said at once (right after its finding)
    assert machine.holds == len(holds) == len(findings) == 2, out
    for h in holds:
        f = next(x for x in findings if x["kind"] == h["kind"] and x["line"] == h["line"])
        assert out.index(h) == out.index(f) + 1
        assert h["sent"] is True and h["lead_time_s"] == f["lead_time_s"] > 0
        assert f"line {f['line']}" in h["message"] and "~" in h["message"] and "keeps monitoring" in h["message"]
    # the machine really held, was resumed, and dexmon said so and followed it on
    assert machine.resumes == 2 and RunState.HOLD in machine.states_seen
    resumed = [x for x in out if x["event"] == "resumed"]
    assert len(resumed) == 2 and all("keeps monitoring" in r["message"] for r in resumed)
    summary = out[-1]
    assert summary["event"] == "summary" and summary["ended"] == "done"
    assert summary["progress_s"] == pytest.approx(summary["program_s"], abs=1e-3)
    alerts = RunReader(tmp_path / "r.sqlite").alerts()
    said = [a["text"] for a in alerts if a["channel"] == "feed_hold"]
    assert sum("FEED HOLD sent" in t for t in said) == 2 and sum("resumed" in t for t in said) == 2


def test_hold_said_on_a_piped_terminal(hold_job, tmp_path, capsys):
    job, moves = hold_job
    code, machine = _run(job, moves, tmp_path, as_json=False)
    out = capsys.readouterr().out  # captured: not a terminal, as when piped into a log
    assert code == 1 and machine.holds == 2
    lines = out.splitlines()
    gouge = next(k for k, x in enumerate(lines) if x.startswith("GOUGE line 22"))
    assert lines[gouge + 1].startswith("FEED HOLD sent by dexmon: gouge at line 22"), lines
    assert "~" in lines[gouge + 1] and "keeps monitoring" in lines[gouge + 1]
    assert sum("resumed after dexmon's feed hold" in x for x in lines) == 2
    assert "2 finding(s)" in out


def test_dry_run_with_feed_hold_resumes_the_virtual_machine_and_ends(tmp_path, capsys):
    """A dry run has no sender and no cycle-start button: dexmon itself resumes the
    virtual machine a few seconds after it held it, says so, and the run ends."""
    from monitor.cli import main

    # the sim clock: both holds come before their findings however busy the computer is
    code = main(["dry-run", "--feed-hold", "--speed", "20", "--clock", "sim", "--json", "--run",
                 str(tmp_path / "r.sqlite")])
    out = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    holds = [x for x in out if x["event"] == "feed_hold"]
    assert code == 1 and len(holds) == 2
    assert all("dry run: dexmon resumes the virtual machine" in h["message"] for h in holds)
    assert len([x for x in out if x["event"] == "resumed"]) == 2
    assert out[-1]["event"] == "summary" and out[-1]["ended"] == "done"


def test_a_hold_the_machine_does_not_show_is_said_once():
    """A controller that ignores the hold (GRBL takes no `!` in some states): after 2 s the
    machinist is told to hold it by hand -- once; a later hold and resume are followed."""
    import io

    from drivers.state import MachineState
    from monitor.alerts import HOLD_CONFIRM_S, Alerter

    js = io.StringIO()
    a = Alerter(json_stream=js, feed_hold=lambda: None)
    a.offer([{"kind": "gouge", "line": 22, "position": [1, 2, 3], "lead_time_s": 4.0}], t=10.0)

    def see(t, state):
        a.follow_state(MachineState(t=t, mpos=(0, 0, 0), state=state))
    for t in (10.5, 10.0 + HOLD_CONFIRM_S, 13.0, 14.0):
        see(t, RunState.RUN)
    see(15.0, RunState.HOLD)
    see(16.5, RunState.IDLE)
    events = [json.loads(x) for x in js.getvalue().splitlines()]
    assert [e["event"] for e in events] == ["finding", "feed_hold", "feed_hold_ignored", "resumed"]
    assert "not held (state Run): hold it by hand" in events[2]["message"]
    assert events[3]["held_s"] == 1.5 and "left the hold (now Idle)" in events[3]["message"]
    assert a.hold is None


def test_hold_said_on_a_terminal():
    import io

    from rich.console import Console

    from monitor.alerts import Alerter

    term = io.StringIO()
    a = Alerter(console=Console(file=term, force_terminal=True, width=80, color_system=None), feed_hold=lambda: None)
    a.offer([{"kind": "gouge", "line": 22, "position": [1, 2, 3], "lead_time_s": 4.2}], t=0.0)
    lines = term.getvalue().splitlines()
    assert lines[1].startswith("FEED HOLD sent by dexmon: gouge at line 22 (predicted in 4.2 s). To go on: ")
    assert lines[1].endswith("dexmon keeps monitoring")  # one line, not wrapped at the terminal's width
