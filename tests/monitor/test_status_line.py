"""The status line labels every figure and counts down to the next predicted finding; with
the output piped it becomes a progress line every few seconds."""

from __future__ import annotations

import argparse
import io
import re

import numpy as np
import pytest
from rich.console import Console

from drivers.state import MachineState, RunState
from monitor.alerts import Alerter
from monitor.commands.dry_run import EXAMPLE_JOB, VIRTUAL_MACHINE, virtual_controller
from monitor.commands.live import run_session
from monitor.job import load_job
from monitor.loop import run_controller
from monitor.program_moves import load_moves
from monitor.session import Session
from monitor.status import StatusLine, next_finding, progress_line, status_text
from monitor.sync import SyncResult
from tests.monitor.test_falling_behind import FreeRunning, StepClock


def _sync(line=22, progress=9.0):
    return SyncResult(row=3, segment=3, line=line, progress=progress, distance=0.0, how="track")


def test_every_figure_is_labelled():
    st = MachineState(t=1.0, mpos=(1.0, 2.0, 3.0), state=RunState.RUN)
    text = status_text(st, _sync(), 20.0, 1, 2.5, upcoming="next: gouge line 22 in 4.2 s").plain
    assert re.fullmatch(r"state Run +work X +1\.000 Y +2\.000 Z +3\.000 +line +22 +progress +45\.0 % +"
                        r"findings 1 +next: gouge line 22 in 4\.2 s +latency +2\.5 ms", text), text


def test_countdown_to_the_next_predicted_finding():
    row_t0 = np.array([0.0, 2.0, 5.0, 9.0, 14.0])
    found = [{"kind": "gouge", "line": 22, "move": 4, "status": "predicted"},           # row 3, at 9 s
             {"kind": "rapid_into_stock", "line": 36, "move": 5, "status": "predicted"},  # row 4, at 14 s
             {"kind": "gouge", "line": 12, "move": 2, "status": "happened"}]
    assert next_finding(found, row_t0, 4.8) == "next: gouge line 22 in 4.2 s"
    assert next_finding(found, row_t0, 4.8, feed_override=200) == "next: gouge line 22 in 2.1 s"
    assert next_finding(found, row_t0, 10.0) == "next: rapid into stock line 36 in 4.0 s"
    assert next_finding(found, row_t0, 14.0) == ""  # reached: it happens now, no countdown
    assert next_finding(found[2:], row_t0, 0.0) == ""


def test_piped_output_gets_a_progress_line_every_few_seconds():
    out = io.StringIO()
    console = Console(file=out, width=80)  # not a terminal, as when piped into a log
    clock = StepClock(1.0)  # one second per update
    status = StatusLine(console, progress_every=5.0, clock=clock)
    st = MachineState(t=1.0, mpos=(1.0, 2.0, 3.0), state=RunState.RUN)
    with status:
        for k in range(12):
            status.update(st, _sync(progress=float(k)), 20.0, 1, upcoming=lambda: "next: gouge line 22 in 4.2 s")
    lines = out.getvalue().splitlines()
    assert lines == [progress_line(st, _sync(progress=float(k)), 20.0, 1, upcoming="next: gouge line 22 in 4.2 s")
                     for k in (0, 5, 10)]
    assert lines[0] == "progress: state Run, line 22, 0.0 %, findings 1, next: gouge line 22 in 4.2 s"
    quiet = io.StringIO()
    StatusLine(Console(file=quiet), enabled=False).update(st, _sync(), 20.0, 0)
    StatusLine(None).update(st, _sync(), 20.0, 0)
    assert quiet.getvalue() == ""


@pytest.fixture(scope="module")
def example():
    job = load_job(EXAMPLE_JOB)
    job.machine = dict(VIRTUAL_MACHINE)
    moves, program = load_moves(job)
    return job, moves, program


def test_piped_dry_run_counts_down_to_the_gouge(example):
    job, moves, program = example
    out = io.StringIO()
    vc = virtual_controller(moves, 1.0, 50.0, clock="sim")
    s = Session(job, moves, alerter=Alerter(), program=program)
    vc.connect()
    # the status reads its clock once a step, 0.25 s each: a progress line every 20 steps (0.4 program s)
    status = StatusLine(Console(file=out, width=80), progress_every=5.0, clock=StepClock(0.25))
    with status:
        run_controller(s, FreeRunning(vc), 0.02, status=status, done=lambda: vc.done, clock=lambda: 0.0)
    vc.close()
    counts = [float(m.group(1)) for m in re.finditer(r"next: gouge line 22 in ([0-9.]+) s", out.getvalue())]
    assert len(counts) >= 10 and counts[0] == pytest.approx(s.findings[0]["lead_time_s"], abs=0.45)
    assert counts == sorted(counts, reverse=True)  # counting down, never up
    assert out.getvalue().splitlines()[-1].startswith("progress: state ")


def test_a_piped_dry_run_says_it_is_alive(example, tmp_path, capsys):
    job, moves, _ = example
    vc = virtual_controller(moves, 1.0, job.poll_hz, clock="sim")
    args = argparse.Namespace(run=str(tmp_path / "r.sqlite"), json=False, quiet=False, view=False, frames=None)
    assert run_session(args, job, FreeRunning(vc), done=lambda: vc.done) == 1
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("run file: ")
    progress = [ln for ln in lines if ln.startswith("progress: state ")]
    # the first one at once, before any finding (after the start lines: limits, setup)
    assert progress and "findings 0" in progress[0] and lines.index(progress[0]) <= 3
