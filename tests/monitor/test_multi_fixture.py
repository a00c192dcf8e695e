"""Multi-fixture programs: one model frame (the job's work system), rows in G55 ... placed at
their offsets from it (a .var file), G92 shifts respected; simulate, the session on the
virtual controller and the bundled example agree with that."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from drivers.registry import open_controller
from monitor.alerts import Alerter
from monitor.cli import main
from monitor.commands.dry_run import EXAMPLE_JOB
from monitor.job import JobError, add_job_arguments, job_from_args, load_job, parse_job_text
from monitor.predict import Lookahead
from monitor.work_coords import reference_wco, row_shifts, work_moves
from monitor.workpiece import build_workpiece
from monitor.loop import run_controller
from monitor.program_moves import load_moves
from monitor.session import Session

DATA = Path(__file__).resolve().parent.parent / "data" / "fixtures2"
TWO = DATA / "two_station.toml"
G92 = DATA / "g92.toml"
RES = 0.5
DEPTH = -2.0
#: flat 6 mm slots from X5 to X15 at Y8: X 2..18, Y 5..11 (work mm) at each station
SLOT_X = (2.0, 18.0)


def _frame(job_path):
    job = load_job(job_path)
    moves, _ = load_moves(job)
    return build_workpiece(job, moves).frame


def _cut_columns(top: np.ndarray, frame, y: float = 8.0) -> np.ndarray:
    """X (mm) of the rays along ``y`` cut down to the slot floor."""
    j = int(round((y - frame.origin[1]) / frame.spacing))
    xs = frame.origin[0] + np.arange(top.shape[1]) * frame.spacing
    return xs[np.nan_to_num(top[j], nan=0.0) < DEPTH + 0.01]


def _slots(cut_x: np.ndarray) -> list[tuple[float, float]]:
    """Runs of consecutive cut rays as (first X, last X)."""
    if cut_x.size == 0:
        return []
    breaks = np.nonzero(np.diff(cut_x) > RES * 1.5)[0]
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [cut_x.size - 1]])
    return [(float(cut_x[a]), float(cut_x[b])) for a, b in zip(starts, ends)]


def _simulate_heights(tmp_path, job_path, *flags):
    out = tmp_path / f"h_{Path(job_path).stem}.npy"
    code = main(["simulate", str(job_path), "--heights", str(out), "--json", *flags])
    return code, np.load(out)


# --- job keys ---------------------------------------------------------------------------

def test_program_keys_parsed_and_named_in_errors(tmp_path):
    (tmp_path / "p.nc").write_text("G0 X1\n")
    (tmp_path / "p.var").write_text("5221 1\n")
    (tmp_path / "subs").mkdir()
    job = parse_job_text('[program]\npath = "p.nc"\nvar = "p.var"\nmachine_units = "inch"\n'
                         'subroutine_path = ["subs"]\nwork_system = "g55"\n', base=tmp_path)
    assert job.var_file == tmp_path / "p.var" and job.machine_units == "inch"
    assert job.subroutine_path == [tmp_path / "subs"] and job.work_system == "G55"
    assert load_job(TWO).work_system == "G54"  # the default
    for body, words in (('var = "missing.var"', ["[program] var", "not found"]),
                        ('machine_units = "cm"', ["[program] machine_units", '"mm" or "inch"', '"cm"']),
                        ('subroutine_path = ["nowhere"]', ["[program] subroutine_path", "not found"]),
                        ("subroutine_path = 3", ["[program] subroutine_path", "folder paths"]),
                        ('work_system = "G60"', ["[program] work_system", "G59.3", '"G60"'])):
        with pytest.raises(JobError) as e:
            parse_job_text(f'[program]\npath = "p.nc"\n{body}\n', name="j.toml", base=tmp_path)
        assert all(w in str(e.value) for w in words), str(e.value)


def test_flags_override_the_job(tmp_path):
    other = tmp_path / "other.var"
    other.write_text("5241 -170\n")
    p = argparse.ArgumentParser()
    add_job_arguments(p)
    job = job_from_args(p.parse_args(["--var", str(other), "--machine-units", "inch", "--work-system", "G55",
                                      "--subroutine-path", str(tmp_path)]), TWO)
    assert job.var_file == other and job.machine_units == "inch" and job.work_system == "G55"
    assert job.subroutine_path == [tmp_path]
    with pytest.raises(JobError, match="--var"):
        job_from_args(p.parse_args(["--var", str(tmp_path / "nope.var")]), TWO)
    with pytest.raises(JobError, match="--work-system"):
        job_from_args(p.parse_args(["--work-system", "G53"]), TWO)


# --- the model frame ----------------------------------------------------------------------

def test_rows_placed_in_the_job_system():
    job = load_job(TWO)
    moves, _ = load_moves(job)
    ref = reference_wco(job)
    np.testing.assert_array_equal(ref[:3], [-200, -100, -50])
    own = work_moves(moves)              # each row in its own system: both stations at X 5..15
    placed = work_moves(moves, ref)
    shift = row_shifts(moves, ref)
    g55 = shift[:, 0] != 0
    assert g55.any() and np.all(shift[g55] == [40.0, 0.0, 0.0])
    np.testing.assert_array_equal(placed["end"][~g55], own["end"][~g55])  # G54 rows: bit for bit
    np.testing.assert_allclose(placed["end"][g55, :3], own["end"][g55, :3] + [40, 0, 0], atol=1e-12)
    feeds = placed[placed["kind"] == 1]
    assert sorted({float(x) for x in feeds["end"][:, 0]}) == [5.0, 15.0, 45.0, 55.0]
    # the job in G55: the G54 station is 40 mm left of it
    job.work_system = "G55"
    placed55 = work_moves(moves, reference_wco(job))
    np.testing.assert_allclose(placed55["end"][:, :3], placed["end"][:, :3] - [40, 0, 0], atol=1e-12)


def test_bundled_example_table_unchanged():
    """A single-system program is modelled exactly as before: same table, bit for bit, so
    the same findings, lines, positions and sizes."""
    job = load_job(EXAMPLE_JOB)
    moves, _ = load_moves(job)
    ref = reference_wco(job)
    assert not ref.any() and not row_shifts(moves, ref).any()
    before, after = work_moves(moves), work_moves(moves, ref)
    for name in before.dtype.names:
        np.testing.assert_array_equal(after[name], before[name], err_msg=name)
    s = Session(job, moves)
    assert s.sync_path is s.path


def test_simulate_two_stations(tmp_path):
    code, top = _simulate_heights(tmp_path, TWO)
    assert code == 0
    frame = _frame(TWO)
    assert top.shape == frame.shape
    assert _slots(_cut_columns(top, frame)) == [(2.0, 18.0), (42.0, 58.0)]
    # slot width in Y at a station centre: 5..11
    i = int(round((50 - frame.origin[0]) / frame.spacing))
    ys = frame.origin[1] + np.arange(top.shape[0]) * frame.spacing
    cut_y = ys[np.nan_to_num(top[:, i]) < DEPTH + 0.01]
    assert (cut_y.min(), cut_y.max()) == (5.0, 11.0)
    assert np.nanmin(top) == pytest.approx(DEPTH)


def test_simulate_var_flag_overrides_the_job(tmp_path):
    var = tmp_path / "near.var"
    var.write_text("5221 -200\n5222 -100\n5223 -50\n5241 -180\n5242 -100\n5243 -50\n")  # G55 = G54 + 20
    code, top = _simulate_heights(tmp_path, TWO, "--var", str(var))
    assert code == 0
    assert _slots(_cut_columns(top, _frame(TWO))) == [(2.0, 18.0), (22.0, 38.0)]


def test_simulate_g92_shift(tmp_path):
    code, top = _simulate_heights(tmp_path, G92)
    assert code == 0
    assert _slots(_cut_columns(top, _frame(G92))) == [(2.0, 18.0), (22.0, 38.0)]


# --- the live path on the virtual controller -------------------------------------------------

def _dry_run(job_path, url_var: Path, rate: float = 50, job_var: Path | None = None):
    """Follow the job's program on a virtual controller that interprets it with ``url_var``
    (clock stepped by polls, ``rate`` per simulated second); the job's own .var file is
    ``job_var`` when given. Return the session."""
    job = load_job(job_path)
    if job_var is not None:
        job.var_file = job_var
    moves, program = load_moves(job)
    vc = open_controller(f"virtual://{job.program}?var={url_var}&clock=sim&speed=1&rate={rate}")
    s = Session(job, moves, alerter=Alerter(), program=program)
    vc.connect()
    try:
        run_controller(s, vc, 0.0, done=lambda: vc.done, max_seconds=120)
    finally:
        vc.close()
    return s


def test_dry_run_agrees_with_simulate(tmp_path):
    _, top = _simulate_heights(tmp_path, TWO)
    s = _dry_run(TWO, DATA / "two_station.var")
    assert s.findings == []
    live = s.live.top()
    assert _slots(_cut_columns(live, s.live.frame)) == [(2.0, 18.0), (42.0, 58.0)]
    # the same model, up to the polled path's chords at the slot ends
    differ = np.abs(np.nan_to_num(live) - np.nan_to_num(top)) > 0.05
    assert differ.sum() <= 0.02 * (np.nan_to_num(top) < -0.05).sum()


def test_live_offset_from_the_wco_in_the_job_system(tmp_path):
    """The controller's offsets differ from the job's .var file. Its G54 is somewhere else
    (the machine's zero is learned from its WCO while in G54) and its G55 is 35 mm right of
    G54, not 40: the live model shows where the machine really cut, the look-ahead
    what the job's file says."""
    var = tmp_path / "machine.var"
    var.write_text("5221 -210\n5222 -90\n5223 -40\n5241 -175\n5242 -90\n5243 -40\n")
    s = _dry_run(TWO, var)
    live = s.live.top()
    assert _slots(_cut_columns(live, s.live.frame)) == [(2.0, 18.0), (37.0, 53.0)]
    # sync matched the controller's work position against each row's own coordinates
    assert s.last_sync is not None and s.last_sync.row == len(s.moves) - 1
    predicted = s.lookahead.model.top()
    assert _slots(_cut_columns(predicted, s.live.frame))[-1] == (42.0, 58.0)


NEAR_VAR = "5221 -200\n5222 -100\n5223 -50\n5241 -180\n5242 -100\n5243 -50\n"  # G55 = G54 + 20
MACHINE_VAR = "5221 -210\n5222 -90\n5223 -40\n5241 -175\n5242 -90\n5243 -40\n"  # G55 = G54 + 35


@pytest.mark.parametrize("case, rate", [("near", 11), ("near", 13), ("near", 23), ("machine", 19)])
def test_dry_run_clean_wherever_the_polls_fall(tmp_path, case, rate):
    """Poll rates (simulated clock, so every run is the same) at which two polls used to
    straddle a slot end: the retract after it read as a 1.5 mm^3 rapid into stock (line 12
    before the G55 switch, line 17 at the second station). "near": job and controller
    share a .var file; "machine": the controller's offsets are not the job's (G55 5 mm
    short of where the job's file puts it)."""
    var = tmp_path / f"{case}.var"
    var.write_text(NEAR_VAR if case == "near" else MACHINE_VAR)
    s = _dry_run(TWO, var, rate=rate, job_var=var if case == "near" else None)
    assert s.findings == []
    second = (22.0, 38.0) if case == "near" else (37.0, 53.0)
    assert _slots(_cut_columns(s.live.top(), s.live.frame)) == [(2.0, 18.0), second]


#: machine seconds between polls of a dry run: the fourth comes 3.65 s after the third, as a
#: poll held up by a busy computer does on the wall clock, from the rapid towards the first
#: slot to half way up the retract after it
STALLED_POLLS = (0.134, 1.782, 0.206, 3.652)


def test_dry_run_clean_after_a_late_poll_restarts_the_lookahead(tmp_path, capsys, monkeypatch):
    """One late poll: the machine ran the plunge, the slot and half the retract since the
    last state, a jump of 3.6 s along the program, so the look-ahead restarts from the live
    model at the machine's row (as it does when the spindle overtakes it). It took the
    live model as it was before this poll's path was cut in: the retract rose through a slot not cut yet, a 56.5 mm^3
    rapid into stock (line 12) "predicted as the machine reached it". (On the wall clock
    under load ``test_cli_dry_run_two_stations_with_var_flag`` failed so.)"""
    from drivers.virtual.controller import VirtualController

    polls = []
    poll = VirtualController.poll

    def stalled_poll(self):
        k = len(polls)
        self.speed = (STALLED_POLLS[k] if k < len(STALLED_POLLS) else 0.2) * self.rate
        polls.append(k)
        return poll(self)
    monkeypatch.setattr(VirtualController, "poll", stalled_poll)
    anchored = []   # the rows the look-ahead restarted from
    anchor = Lookahead.anchor

    def noted_anchor(self, live, row, *a, **k):
        anchored.append(row)
        return anchor(self, live, row, *a, **k)
    monkeypatch.setattr(Lookahead, "anchor", noted_anchor)
    var = tmp_path / "near.var"
    var.write_text(NEAR_VAR)
    run = tmp_path / "run.sqlite"
    code = main(["dry-run", str(TWO), "--var", str(var), "--clock", "sim", "--json", "--run", str(run)])
    out = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    # the late poll's jump restarted the look-ahead at the retract (else this test would
    # mean nothing): at the start, then there
    assert anchored[1:2] == [5], anchored
    assert [x for x in out if x["event"] == "finding"] == [] and code == 0, out


def test_cli_dry_run_two_stations_with_var_flag(tmp_path, capsys):
    """``dexmon dry-run JOB --var`` runs the program with that .var file on the virtual
    controller and models it the same: no findings, both slots where that file puts them."""
    var = tmp_path / "near.var"
    var.write_text("5221 -200\n5222 -100\n5223 -50\n5241 -180\n5242 -100\n5243 -50\n")  # G55 = G54 + 20
    run = tmp_path / "run.sqlite"
    code = main(["dry-run", str(TWO), "--var", str(var), "--speed", "10", "--json", "--run", str(run)])
    out = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    # wherever the polls fall (wall clock): nothing at all, the retracts at the slot ends
    # included (tests/monitor/test_live_path.py pins the poll straddles down)
    assert [x for x in out if x["event"] == "finding"] == [] and code == 0, out
    from monitor.runreader import RunReader

    r = RunReader(run)
    frame = r.meta()["frame"]
    frame = json.loads(frame) if isinstance(frame, str) else frame
    assert frame["work_system"] == "G54" and frame["reference_wco"][:3] == [-200, -100, -50]
    # the recorded path (model frame) at slot depth: X 5..15 and, through G55, X 25..35
    pts = np.concatenate([c["arrays"]["points"] for c in r.cuts()])
    floor_x = pts[np.abs(pts[:, 2] - DEPTH) < 1e-6, 0]
    assert floor_x.min() == pytest.approx(5.0, abs=1e-6) and floor_x.max() == pytest.approx(35.0, abs=1e-6)
    assert not np.any((floor_x > 15 + 1e-6) & (floor_x < 25 - 1e-6))
    # replay reads the moves back in the same frame: the G55 slot's floor at X 25..35
    from monitor.trace_io import RunView

    moves = RunView(run).moves
    floor = moves["end"][np.abs(moves["end"][:, 2] - DEPTH) < 1e-6, 0]
    assert floor.max() == pytest.approx(35.0, abs=1e-6)
