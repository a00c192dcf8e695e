"""A run cut off at any moment (kill -9, a full disk, a power cut): what the run file then
holds is what replay, report and ``simulate --resume`` show, and every stage they claim is
the model the monitor had at that stage.

The crash is simulated deterministically: a session on the bundled example is stepped by
the virtual machine on its simulated clock and never finished, and the run file is copied
(SQLite's backup: what the writer had committed) at a chosen moment. The session's trace
clock is the test's, so when the trace is written does not hang on the computer's speed.
"""

from __future__ import annotations

import dataclasses
import json
import re
import sqlite3

import pytest

from monitor.alerts import Alerter
from monitor.cli import main
from monitor.commands.dry_run import EXAMPLE_JOB, virtual_controller
from monitor.job import load_job
from monitor.runfile import RunWriter
from monitor.live_trace import TRACE_CHUNK_S, TRACE_CHUNK_STAGES
from monitor.program_moves import load_moves
from monitor.session import Session
from monitor.trace_io import RunView
from sim.trace import same_model


@pytest.fixture(scope="module")
def example():
    job = load_job(EXAMPLE_JOB)
    moves, program = load_moves(job)
    return job, moves, program


class Crashable:
    """A session on the example writing ``path``, stepped one state at a time, with the
    models it had at each stage (``snaps``) and its trace clock set by the test (``now``,
    s: the states' own time unless ``frozen``)."""

    def __init__(self, example, path, frozen: bool = False):
        job, moves, program = example
        self.writer = RunWriter(path)
        self.now = 0.0
        self.frozen = frozen
        self.session = Session(job, moves, program=program, run=self.writer, alerter=Alerter(run=self.writer),
                               trace_clock=lambda: self.now)
        self.vc = virtual_controller(moves, speed=1.0, rate=job.poll_hz, clock="sim")
        self.vc.connect()
        self.snaps = {0: self.session.live.copy()}
        self.cut_t: dict[int, float] = {}

    def step_until(self, stage: int) -> None:
        s = self.session
        while s.stage < stage:
            st = self.vc.poll()
            if not self.frozen:
                self.now = st.t
            before = s.stage
            s.step(st)
            if s.stage != before:
                self.snaps[s.stage] = s.live.copy()
                self.cut_t[s.stage] = st.t
            assert not self.vc.done, "the program ended first"

    def crash_copy(self, path):
        """The run file as a crash now would leave it: everything the writer committed."""
        self.writer.flush()
        src = sqlite3.connect(f"file:{self.writer.path}?mode=ro", uri=True)
        dst = sqlite3.connect(path)
        src.backup(dst)
        src.close()
        dst.close()
        return path

    def close(self) -> None:
        self.vc.close()
        self.writer.close()


def recorded_stage(path) -> int:
    return sqlite3.connect(path).execute("SELECT MAX(stage) FROM cuts").fetchone()[0]


def test_a_run_cut_off_between_trace_writes_claims_only_stages_it_rebuilds(example, tmp_path, capsys):
    """Killed with the cuts committed past the trace (here: the trace clock stands still, so
    only the every-50-stages bound writes it): 'end' is the last stage the trace rebuilds,
    every stage replay offers is the model the session had then, and replay, report and
    --resume say the run was cut short and where."""
    run = Crashable(example, tmp_path / "live.sqlite", frozen=True)
    try:
        # the example's facing pass starts cutting at stage 81: stop well into it, with
        # stages that removed material since the last trace write
        run.step_until(2 * TRACE_CHUNK_STAGES + 10)
        crash = run.crash_copy(tmp_path / "crash.sqlite")
    finally:
        run.close()
    recorded = recorded_stage(crash)
    assert recorded == 2 * TRACE_CHUNK_STAGES + 10
    with RunView(crash) as view:
        last = view.last_stage
        for stage in range(view.first_stage, last + 1):
            assert same_model(view.trace.grid_at(stage), run.snaps[stage]), f"stage {stage} is not the model"
        assert last < recorded and run.snaps[recorded].volume() < run.snaps[last].volume()
    said = f"cut short: recorded up to stage {recorded}, the model rebuilds up to stage {last}"

    assert main(["replay", str(crash), "--json"]) == 0
    out, err = capsys.readouterr()
    summary = json.loads(out)
    assert summary["last_stage"] == last and summary["truncated"] and summary["recorded_stage"] == recorded
    assert said in err and len(err.strip().splitlines()) == 1, err

    stl = tmp_path / "end.stl"
    assert main(["replay", str(crash), "--export-stl", "end", str(stl), "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["stage"] == last and said in err
    assert main(["replay", str(crash), "--stage", str(recorded), "--png", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert said in err and len(err.strip().splitlines()) == 1, err

    html = tmp_path / "r.html"
    assert main(["report", str(crash), "-o", str(html)]) == 0
    assert said in capsys.readouterr().err and said in html.read_text()

    from monitor.resume import resume_grid

    grid, stage = resume_grid(f"{crash}:end")
    assert stage == last and same_model(grid, run.snaps[last])


def test_the_trace_keeps_up_with_the_cuts_within_its_time_bound(example, tmp_path):
    """The trace is written at least every TRACE_CHUNK_S of the trace clock, cutting or not:
    a crash at any moment leaves at most that much (and one poll) of the run unrebuilt,
    never 50 stages."""
    run = Crashable(example, tmp_path / "live.sqlite")
    period = 1.0 / example[0].poll_hz
    try:
        for k, stage in enumerate((7, 23, TRACE_CHUNK_STAGES - 3, TRACE_CHUNK_STAGES + 40)):
            run.step_until(stage)
            crash = run.crash_copy(tmp_path / f"crash{k}.sqlite")
            with RunView(crash) as view:
                last = view.last_stage
                assert same_model(view.trace.grid_at(last), run.snaps[last]), stage
            assert recorded_stage(crash) == run.session.stage
            late = [run.cut_t[s] for s in range(last + 1, run.session.stage + 1)]
            assert not late or min(late) > run.now - TRACE_CHUNK_S - period - 1e-9, (last, stage, late, run.now)
        # the machine then stands still (a feed hold): the trace catches up all the same
        held = run.session.last
        for i in range(1, int(2 * TRACE_CHUNK_S / period) + 2):
            run.now = held.t + i * period
            run.session.step(dataclasses.replace(held, t=run.now))
        crash = run.crash_copy(tmp_path / "held.sqlite")
        with RunView(crash) as view:
            assert view.last_stage == run.session.stage == recorded_stage(crash)
    finally:
        run.close()


def test_a_finding_past_where_the_model_ends_is_not_pictured_as_cut(tmp_path, capsys):
    """A run cut short after recording a finding's lines but before its trace got there:
    the report pictures it at the last stage the model rebuilds and says so, not "its lines
    cut" over material they never touched in the model."""
    import shutil

    from tests.monitor.run_helpers import record_run

    whole = tmp_path / "whole.dexrun"
    record_run(whole)
    crash = tmp_path / "crash.dexrun"
    shutil.copy(whole, crash)
    con = sqlite3.connect(crash)
    # as a crash leaves it: the writer never closed (no row counts) and the trace written
    # up to stage 10 while the cuts (and the findings) went on
    con.execute("DELETE FROM meta WHERE key = 'rows'")
    con.execute("DELETE FROM trace WHERE stage_to > 10")
    con.commit()
    con.close()
    html = tmp_path / "r.html"
    assert main(["report", str(crash), "-o", str(html)]) == 0
    capsys.readouterr()
    text = html.read_text()
    # the gouge's lines 13-14 were cut after stage 10, the rapid's line 10 before it
    assert "3-D view round the finding at stage 10 (the last stage the model rebuilds: the run was cut " \
           "short before its lines were)" in text
    assert re.search(r"3-D view round the finding at stage [0-9] \(its lines cut\)", text)
