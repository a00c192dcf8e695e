"""Link trouble seen by the session (issue 11): states that are not fresh are recorded and
counted, never synced or cut; a jump across a gap is not a cut; whatever a controller
reports, nothing non-finite or far away blows up a kernel.

The states are made here (the driver/monitor contract of drivers.state), or come from the
virtual controller's fault injection: no real driver is involved.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from drivers.virtual.faults import FaultInjector
from drivers.state import Gap, LinkEvent, LinkKind, MachineState, RunState
from monitor.commands.dry_run import EXAMPLE_JOB, virtual_controller
from monitor.job import load_job
from monitor.runfile import RunWriter
from monitor.runreader import RunReader
from monitor.loop import run_controller
from monitor.gaps import GAP_POLLS
from monitor.program_moves import load_moves
from monitor.session import Session


@pytest.fixture(scope="module")
def example():
    job = load_job(EXAMPLE_JOB)
    moves, program = load_moves(job)
    return job, moves, program


def _state(t, tip, spindle=10000.0, state=RunState.RUN, **kw):
    return MachineState(t=t, mpos=tuple(tip) + (0, 0, 0), state=state, spindle=spindle, **kw)


def _row(moves, line):
    return int(np.nonzero(moves["line"] == line)[0][0])


def _on_line_11(s, moves, n=6, t0=0.0, offset=(0.0, 0.0, 0.0)):
    """``n`` states along line 11 (G1 X68 at Y2, Z-5) with the spindle on, the work zero at
    machine ``offset``; returns the last t."""
    mw = s.moves
    k = _row(moves, 11)
    p0, p1 = mw["start"][k, :3], mw["end"][k, :3]
    t = t0
    for f in np.linspace(0.0, 0.3, n):
        s.step(_state(t, p0 + f * (p1 - p0) + offset))
        t += 0.02
    return t


def test_a_jump_across_a_disconnect_is_not_a_cut(example, tmp_path):
    """The issue's case: the link drops while cutting line 11, the controller restarts and
    comes back in alarm at machine (0, 0, 0) -- inside the stock with this job's work
    offset -- with the spindle off. The path during the gap is unknown: no cut, no
    ``spindle_stopped_cutting``, a gap record saying what happened."""
    job, moves, program = example
    job = dataclasses.replace(job, work_offset=(-40.0, -30.0, 3.0), design=None, fixtures=[])
    with RunWriter(tmp_path / "r.sqlite") as w:
        s = Session(job, moves, run=w, program=program)
        t = _on_line_11(s, moves, offset=job.work_offset)
        assert s.last_sync.line == 11 and s.last_sync.how == "track"
        stage = s.stage
        last_tip = s.tip(s.last, s.last_sync.row)
        down = [MachineState(t=t + 0.02 * i, mpos=s.last.mpos, state=RunState.DISCONNECTED, raw="port gone")
                for i in range(7)]
        for st in down:
            assert s.step(st).sync is s.last_sync  # nothing synced or cut
        assert s.stage == stage
        s.link_event(LinkEvent(t + 0.2, LinkKind.RESET, "grbl:///dev/ttyUSB0: Grbl 1.1h banner: reset"))
        back = MachineState(t=t + 0.2, mpos=(0.0,) * 6, state=RunState.ALARM, spindle=0.0)
        s.step(back)
        s.step(dataclasses.replace(back, t=t + 0.22))
        summary = s.finish()
    assert not [f for f in s.findings if f["kind"] == "spindle_stopped_cutting"], s.findings
    assert s.stage == stage  # the jump was not cut; standing still cuts nothing
    assert s.counts == {"missed": 0, "bad": 0, "disconnected": 7}
    [gap] = s.gaps
    assert gap["polls_missed"] == 7 and gap["t_lost"] == down[0].t and gap["t_back"] == back.t
    assert gap["seconds"] == pytest.approx(back.t - down[0].t)
    assert "reset" in gap["came_back"] and gap["reason"] == "port gone"
    assert gap["jump_mm"] == pytest.approx(float(np.linalg.norm(np.array([40.0, 30.0, -3.0]) - last_tip)))
    assert gap["resync"]["how"] == "lost"  # (40, 30, -3) is on no program row
    assert gap["rows_cut_unchecked"] == []
    assert "reset" in gap["message"] and "7 polls" in gap["message"]
    assert summary["gaps"] == [gap] and summary["disconnected"] == 7
    r = RunReader(tmp_path / "r.sqlite")
    kinds = [e["kind"] for e in r.link_events()]
    assert kinds == ["reset", "gap"]
    assert list(r.states()["state"]).count("Disconnected") == 7


def test_missed_polls_are_marked_counted_and_open_a_gap(example):
    """Fewer than GAP_POLLS missed polls in a row: counted, the path is still joined (a
    missed poll or two is noise); GAP_POLLS or more: a gap, re-synced, not joined."""
    job, moves, program = example
    job = dataclasses.replace(job, work_offset=(0.0, 0.0, 0.0), design=None, fixtures=[])
    s = Session(job, moves, program=program)
    mw = s.moves
    k = _row(moves, 11)
    p0, p1 = mw["start"][k, :3], mw["end"][k, :3]
    t = _on_line_11(s, moves)
    for i in range(GAP_POLLS - 1):
        s.step(MachineState(t=t, mpos=s.last.mpos, state=RunState.MISSED, raw="garbled"))
    stage = s.stage
    s.step(_state(t + 0.1, p0 + 0.4 * (p1 - p0)))
    assert s.stage == stage + 1 and s.gaps == []  # joined: a short miss is no gap
    for i in range(GAP_POLLS):
        s.step(MachineState(t=t + 0.1, mpos=s.last.mpos, state=RunState.MISSED, raw="late"))
    s.step(_state(t + 0.3, p0 + 0.6 * (p1 - p0)))
    assert len(s.gaps) == 1  # not joined: re-synced
    gap = s.gaps[0]
    assert gap["polls_missed"] == GAP_POLLS and gap["missed"] == GAP_POLLS and gap["resync"]["line"] == 11
    assert s.counts["missed"] == 2 * GAP_POLLS - 1
    # the machine went on along line 11 meanwhile: the part between is cut as programmed
    assert gap["rows_cut_unchecked"] == [11] and s.stage == stage + 2  # one stage, as programmed
    s.step(_state(t + 0.32, p0 + 0.62 * (p1 - p0)))
    assert s.stage == stage + 3  # joined again


def test_a_disconnect_while_the_machine_runs_on_keeps_the_model_right(example):
    """The virtual machine runs on while the link is down: after the gap the session
    re-syncs on the program, cuts the rows it ran meanwhile as programmed (unchecked,
    said in the gap record) and ends with the same model as a run without the outage."""
    job, moves, program = example

    def run(faults):
        vc = virtual_controller(moves, speed=1.0, rate=50, clock="sim")
        vc.faults = FaultInjector(faults)  # before connect(), which hands it to the feeder
        s = Session(job, moves, program=program)
        vc.connect()
        run_controller(s, vc, 0.0, done=lambda: vc.done)
        vc.close()
        return s

    clean = run(None)
    s = run("disconnect=10,disconnect_for=4")
    [gap] = s.gaps
    assert gap["polls_missed"] >= 150 and gap["resync"]["how"] != "lost"
    assert len(gap["rows_cut_unchecked"]) >= 2
    assert gap["lines_lost"] == 0 and gap["came_back"] == ""
    diff = np.abs(np.nan_to_num(s.live.top()) - np.nan_to_num(clean.live.top()))
    assert float(diff.max()) <= 1e-6
    # the planted faults are still found (the gap did not hide the rest of the program)
    assert {("gouge", 22), ("rapid_into_stock", 36)} <= {(f["kind"], f["line"]) for f in s.findings}


BAD_NUMBERS = [math.nan, math.inf, -math.inf, 1e300, 1.0e5 + 1]


@pytest.mark.parametrize("bad", BAD_NUMBERS)
def test_impossible_fresh_states_are_bad_not_cut(example, tmp_path, bad):
    """A driver that hands on a state whose numbers cannot be right: the session treats it
    as BAD (recorded with its text, counted, skipped); nothing non-finite reaches the model."""
    job, moves, program = example
    with RunWriter(tmp_path / "r.sqlite") as w:
        s = Session(job, moves, run=w, program=program)
        t = _on_line_11(s, moves)
        stage = s.stage
        for axis in range(3):
            tip = list(s.last.mpos[:3])
            tip[axis] = bad
            s.step(_state(t, tip, raw=f"<Run|MPos:{tip}>"))
        s.step(dataclasses.replace(s.last, t=t, wco=(bad, 0, 0, 0, 0, 0), raw="<Run|WCO:...>"))
        s.step(dataclasses.replace(s.last, t=t, feed=bad * 100, raw="<Run|FS:...>"))  # beyond any feed
        s.finish()
    assert s.counts["bad"] == 5 and s.stage == stage
    st = RunReader(tmp_path / "r.sqlite").states()
    bad_rows = st[st["state"] == "Bad"]
    assert len(bad_rows) == 5 and np.all(np.isfinite(bad_rows["mpos"]))


@pytest.mark.parametrize("far", [1.0e5, -1.0e5, 9.9e4])
def test_far_away_positions_do_not_blow_up_a_kernel(example, far):
    """Finite but far positions (up to the contract's 1e5 mm): the session steps through
    them (off the program, lost) and back without an exception, a huge allocation or a
    crash; nothing is cut out there."""
    job, moves, program = example
    s = Session(job, moves, program=program)
    t = _on_line_11(s, moves)
    back = s.last
    for i, tip in enumerate(([far, 2.0, -5.0], [far, far, far], [2.0, far, -5.0], [far, -far, 0.0])):
        info = s.step(_state(t + 0.02 * (i + 1), tip))
        assert info.sync is not None and info.sync.how == "lost"
        assert all(np.all(np.isfinite(f.get("position", [0]))) for f in s.findings)
    # the work offset far the other way: the tip (mpos - WCO) twice as far
    info = s.step(MachineState(t=t + 0.12, mpos=(far, far, far, 0, 0, 0), wco=(-far, -far, -far, 0, 0, 0),
                               state=RunState.RUN, spindle=10000.0))
    assert info.sync.how == "lost"
    s.step(dataclasses.replace(back, t=t + 0.2))
    assert s.last_sync.how in ("search", "track")


def test_session_link_event_back_carries_the_drivers_gap(example):
    """A BACK link event with the driver's Gap gives the gap record its lines lost and how
    the controller came back."""
    job, moves, program = example
    job = dataclasses.replace(job, work_offset=(0.0, 0.0, 0.0))
    s = Session(job, moves, program=program)
    t = _on_line_11(s, moves)
    s.step(MachineState(t=t, mpos=s.last.mpos, state=RunState.DISCONNECTED, raw="socket closed"))
    drv = Gap(t, t + 1.0, "socket closed", polls_missed=1, lines_lost=3, came_back="alarm 1")
    s.link_event(LinkEvent(t + 1.0, LinkKind.BACK, "back after 1.0 s", gap=drv))
    s.step(dataclasses.replace(s.last, t=t + 1.0))
    [gap] = s.gaps
    assert gap["lines_lost"] == 3 and gap["came_back"] == "alarm 1" and "3 lines" in gap["message"]


def test_a_reset_told_before_the_first_state_is_no_gap(example):
    """A driver that tells a RESET at connect (the banner) before any fresh state: there is
    nothing to join yet, so no gap record and the first states are followed as usual."""
    job, moves, program = example
    job = dataclasses.replace(job, work_offset=(0.0, 0.0, 0.0))
    s = Session(job, moves, program=program)
    s.link_event(LinkEvent(0.0, LinkKind.RESET, "grbl:///dev/ttyUSB0: Grbl 1.1h ['$' for help]"))
    _on_line_11(s, moves)
    assert s.gaps == [] and s.last_sync.how == "track" and s.stage == 5


def test_after_a_reset_the_rows_between_are_not_cut_as_programmed(example):
    """A controller that reset lost its program: found again further on (the operator
    restarted from a later line), the rows in between did not run and are not cut."""
    job, moves, program = example
    job = dataclasses.replace(job, work_offset=(0.0, 0.0, 0.0))
    s = Session(job, moves, program=program)
    t = _on_line_11(s, moves)
    s.step(MachineState(t=t, mpos=s.last.mpos, state=RunState.DISCONNECTED, raw="port gone"))
    s.link_event(LinkEvent(t + 1.0, LinkKind.RESET, "Grbl 1.1h banner"))
    k = _row(moves, 16)
    s.step(_state(t + 1.0, s.moves["start"][k, :3] + 0.5 * (s.moves["end"][k, :3] - s.moves["start"][k, :3]), line=16))
    [gap] = s.gaps
    assert gap["reset"] and gap["resync"]["line"] == 16 and gap["rows_cut_unchecked"] == []
