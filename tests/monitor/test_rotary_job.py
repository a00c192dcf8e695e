"""The bundled rotary example (a 4th-axis engraving, monitor/examples/rotary_job): its one
planted fault (line 35 plunges 2 mm instead of 0.5) is found by ``simulate`` and, ahead
of the spindle, by ``dry-run``; the live session follows moves that turn only A."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from drivers.state import MachineState, RunState
from monitor.cli import main
from monitor.job import JobError, load_job
from monitor.program_moves import load_moves
from monitor.session import Session

JOB = Path(__file__).resolve().parents[2] / "monitor" / "examples" / "rotary_job" / "job.toml"
FAULT_LINE = 35
RING_LINE = 10  # G1 A360 F1800 at X10 Z12: a ring turned by A alone


def lines_of(capsys):
    return [json.loads(x) for x in capsys.readouterr().out.splitlines() if x.startswith("{")]


def test_simulate_finds_the_planted_plunge(capsys):
    code = main(["simulate", str(JOB), "--resolution", "0.5", "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert code == 1
    assert [(f["kind"], f["line"]) for f in doc["findings"]] == [("gouge", FAULT_LINE)]
    # 2 mm deep into a design 1 mm under the bar's surface
    assert doc["findings"][0]["depth"] == pytest.approx(1.0, abs=0.01)


def test_dry_run_predicts_the_plunge_with_lead_time(capsys, tmp_path):
    code = main(["dry-run", str(JOB), "--speed", "50", "--clock", "sim", "--resolution", "0.5", "--json",
                 "--run", str(tmp_path / "run.sqlite")])
    out = lines_of(capsys)
    assert code == 1
    findings = [x for x in out if x["event"] == "finding"]
    assert [(f["kind"], f["line"]) for f in findings] == [("gouge", FAULT_LINE)]
    assert findings[0]["predicted"] and findings[0]["lead_time_s"] > 0
    summary = out[-1]
    assert summary["event"] == "summary" and summary["ended"] == "done" and summary["bad"] == 0


@pytest.fixture(scope="module")
def ring_session():
    job = load_job(JOB)
    job.resolution = 0.5
    moves, program = load_moves(job)
    return Session(job, moves, program=program), moves


def test_sync_follows_a_move_that_turns_only_a(ring_session):
    """The tool stands still in X Y Z while A turns 0 -> 360: the sync walks along the
    ring's row (it used to see one point, the row's start), and each step cuts."""
    s, moves = ring_session
    ring = int(np.nonzero(moves["line"] == RING_LINE)[0][0])
    # on the ring's start: the plunge (line 9) has just ended at Z12
    t = 0.0
    s.step(MachineState(t=t, mpos=(10.0, 0.0, 16.0, 0.0, 0.0, 0.0), state=RunState.RUN, spindle=12000))
    progress, removed = [], []
    for k, z in enumerate(np.linspace(16.0, 12.0, 5)):
        t += 0.2
        s.step(MachineState(t=t, mpos=(10.0, 0.0, z, 0.0, 0.0, 0.0), state=RunState.RUN, spindle=12000))
    for a in np.arange(10.0, 361.0, 10.0):
        t += 0.05
        info = s.step(MachineState(t=t, mpos=(10.0, 0.0, 12.0, a, 0.0, 0.0), state=RunState.RUN,
                                   spindle=12000))
        assert info.sync.row == ring, (a, info.sync)
        progress.append(info.sync.progress)
        removed.append(info.removed)
    assert np.all(np.diff(progress) > 0)
    assert progress[-1] == pytest.approx(s.path.row_t1[ring], abs=1e-6)
    # every step turned the bar under the tool: a 0.5 mm deep ring is cut piece by piece
    assert all(r > 0 for r in removed)
    assert not s.findings


def test_simulate_without_checks_cuts_on_the_turned_bar(capsys):
    """--no-checks cuts with the job's kinematics too: the rings and flutes remove what
    they remove with checks (it cut 3 axes, A ignored: every flute on the bar's top,
    about a third of the volume)."""
    main(["simulate", str(JOB), "--resolution", "0.5", "--json"])
    checked = json.loads(capsys.readouterr().out)["removed_mm3"]
    main(["simulate", str(JOB), "--resolution", "0.5", "--json", "--no-checks"])
    unchecked = json.loads(capsys.readouterr().out)["removed_mm3"]
    assert unchecked == pytest.approx(checked, rel=1e-9)


def test_stock_cylinder_along_x_and_its_errors():
    from monitor.job import JobError, parse_job_text

    job = parse_job_text('[stock]\ncylinder = [1, 2, 5, 0, 60]\naxis = "x"\n')
    assert job.stock.axis == "x"
    assert job.stock.bounds() == ((0.0, -4.0, -3.0), (60.0, 6.0, 7.0))
    assert job.stock.cylinder_placement() == ((0.0, 1.0, 2.0), (1.0, 0.0, 0.0), 5.0, 60.0)
    # a Z cylinder stays what it was
    z = parse_job_text("[stock]\ncylinder = [1, 2, 5, 0, 10]\n").stock
    assert z.bounds() == ((-4.0, -3.0, 0.0), (6.0, 7.0, 10.0))
    with pytest.raises(JobError, match=r'\[stock\] axis: expected "x", "y" or "z"'):
        parse_job_text('[stock]\ncylinder = [1, 2, 5, 0, 60]\naxis = "a"\n')
    with pytest.raises(JobError, match=r"\[stock\] cylinder: expected radius > 0 and x0 < x1"):
        parse_job_text('[stock]\ncylinder = [1, 2, 5, 60, 0]\naxis = "x"\n')
    with pytest.raises(JobError, match=r"\[stock\].*axis"):
        parse_job_text('[stock]\nbox = [0, 0, 0, 1, 1, 1]\naxis = "x"\n')


def test_program_path_with_angles_makes_a_turn_a_segment():
    """A row turning only A is a point in X Y Z; with the rotary scale it has a length,
    and positions along the turn project onto it in order."""
    from monitor.sync import ProgramPath, ProgramSync
    from sim.gcode.program import interpret

    moves = interpret("G21 G90\nG0 X10 Z5\nG1 A90 F900\nG1 X20 F900\n").moves
    flat = ProgramPath.from_moves(moves)
    six = ProgramPath.from_moves(moves, rotary_scale=0.2)
    turn = int(np.nonzero(moves["line"] == 3)[0][0])
    assert six.p0.shape[1] == 6 and len(six) == len(flat)
    seg = int(np.nonzero(six.row == turn)[0][0])
    assert np.linalg.norm(flat.p1[seg] - flat.p0[seg]) == 0.0
    assert np.linalg.norm(six.p1[seg] - six.p0[seg]) == pytest.approx(18.0)
    sync = ProgramSync(six)
    got = [sync.update([10, 0, 5, 0.2 * a, 0, 0], t=k * 0.1) for k, a in enumerate((0, 30, 60, 90))]
    assert [g.row for g in got[1:]] == [turn] * 3
    assert got[1].progress < got[2].progress < got[3].progress


class ScriptedController:
    """A controller that reports the given states, one per poll, then closes."""

    def __init__(self, states):
        self._states = list(states)

    def states(self, period):
        yield from self._states


def test_a_program_ending_in_an_a_only_move_runs_to_its_end(tmp_path):
    """The program's last motion turns only A (unwinding to A0). The machine standing
    idle at the end of the last X Y Z motion, A still at 90, is not the program's end
    (a sender between lines does that): the loop goes on until A is back at 0."""
    from monitor.loop import run_controller

    prog = tmp_path / "unwind.nc"
    prog.write_text("G21 G90 G94\nT1 M6\nM3 S12000\nG0 Z16\nG0 X10 Y0 A0\nG1 Z12 F200\nG1 A90 F1800\n"
                    "G0 Z16\nG0 A0\nM5\nM2\n")
    job = load_job(JOB)
    job.program, job.design, job.resolution = prog, None, 0.5
    moves, program = load_moves(job)
    session = Session(job, moves, program=program)

    def state(t, x, z, a, run=RunState.RUN):
        return MachineState(t=t, mpos=(x, 0.0, z, a, 0.0, 0.0), state=run, spindle=12000)

    script = [state(0.0, 10.0, 16.0, 0.0), state(0.2, 10.0, 12.0, 0.0)]
    script += [state(0.3 + 0.05 * k, 10.0, 12.0, a) for k, a in enumerate(np.arange(10.0, 91.0, 10.0))]
    script += [state(1.0, 10.0, 16.0, 90.0, RunState.IDLE)]  # between lines: A is still to unwind
    script += [state(1.2 + 0.05 * k, 10.0, 16.0, a) for k, a in enumerate(np.arange(80.0, -1.0, -10.0))]
    script += [state(2.0, 10.0, 16.0, 0.0, RunState.IDLE), state(2.1, 10.0, 16.0, 0.0, RunState.IDLE)]
    n = run_controller(session, ScriptedController(script), period=0.02, give_up_s=None)
    assert session.end_reason == "program end"
    assert n == len(script) - 1  # ended on the first idle state at A0, not at A90


def test_a_gap_in_the_middle_of_a_turn_cuts_the_turn_up_to_where_the_machine_is():
    """The link drops while A turns the ring (line 10, A0 -> 360) and comes back at A120:
    the rows between are cut as programmed up to A120, not to the row's end (A360), so
    the next polls go on cutting the ring."""
    from monitor.gaps import GAP_POLLS

    job = load_job(JOB)
    job.resolution = 0.5
    moves, program = load_moves(job)
    s = Session(job, moves, program=program)
    ring = int(np.nonzero(moves["line"] == RING_LINE)[0][0])

    def at(t, z, a, state=RunState.RUN):
        return MachineState(t=t, mpos=(10.0, 0.0, z, a, 0.0, 0.0), state=state, spindle=12000)

    t = 0.0
    s.step(at(t, 16.0, 0.0))
    for z in np.linspace(16.0, 12.0, 5):
        t += 0.2
        s.step(at(t, z, 0.0))
    for a in (10.0, 20.0, 30.0):
        t += 0.05
        s.step(at(t, 12.0, a))
    for _ in range(GAP_POLLS):
        s.step(MachineState(t=t, mpos=s.last.mpos, state=RunState.MISSED, raw="late"))
    t += 0.3
    s.step(at(t, 12.0, 120.0))
    assert len(s.gaps) == 1 and s.gaps[0]["rows_cut_unchecked"] == [RING_LINE]
    assert s.last_sync.row == ring
    removed = []
    for a in (130.0, 140.0, 150.0):
        t += 0.05
        removed.append(s.step(at(t, 12.0, a)).removed)
    # each 10 degrees of the ring is about 1.5 mm^3 (as before the gap); a gap that cut
    # the whole turn left nothing but float dust for them
    assert all(r > 0.5 for r in removed), removed


def test_a_tilted_head_places_the_tip_one_tool_length_from_the_gauge_point(tmp_path, capsys):
    """A head-head machine (xyzbc-head, pivot 100 mm above the gauge point), the tool's
    G43 length 50 mm, B tilted 30 degrees, a plunge: the tip is ``pivot + P Z - (P + L) k``
    (k the tilted axis), 75 mm in +X from the gauge point and 20.096 mm above the
    program's Z (the tip with G43). Placed there the flat end mill's lowest rim point
    goes 3.5 mm into the design box; the tool length left out, the tip lands 25 mm short,
    beside the design, and no gouge is found."""
    tilt, r = 30.0, 3.0
    tip_z = 16.0   # the plunge's end (see _tilted_plunge_job)
    job = _tilted_plunge_job(tmp_path, "G0 Z60\n")
    job.write_text(job.read_text() + '[design]\nbox = [20, 0, 0, 40, 20, 18]\n'
                   '[tolerance]\ngouge = 0.05\nundercut = 5\ninterest = 6\n')
    code = main(["simulate", str(tmp_path / "job.toml"), "--json"])
    doc = json.loads(capsys.readouterr().out)
    gouges = [f for f in doc["findings"] if f["kind"] == "gouge"]
    # ahead of the spindle too, with lead time
    main(["dry-run", str(tmp_path / "job.toml"), "--speed", "50", "--clock", "sim", "--json",
          "--run", str(tmp_path / "run.sqlite")])
    ahead = [x for x in lines_of(capsys) if x["event"] == "finding" and x["kind"] in ("gouge", "setup")]
    assert [(x["kind"], x["line"]) for x in ahead] == [("gouge", 9)]
    assert ahead[0]["predicted"] and ahead[0]["lead_time_s"] > 0
    assert code == 1 and [f["line"] for f in gouges] == [9], doc["findings"]
    assert [(f["kind"], f["line"]) for f in doc["findings"]] == [("gouge", 9)]   # nothing else
    # the setup check sees the tips the head puts on the part, not the program's X Y Z
    assert not [f for f in doc["findings"] if f["kind"] == "setup"], doc["findings"]
    # the rim's lowest point: r sin(tilt) below the tip, under the design's top (18)
    assert gouges[0]["depth"] == pytest.approx(18.0 - (tip_z - r * math.sin(math.radians(tilt))), abs=0.01)


def test_head_tool_lengths_one_per_tilted_tool_or_a_clear_error():
    """The G43 length each tool is tilted with (the work tables hold tips); a tool
    tilted with two lengths is refused, naming both lines."""
    from monitor.workpiece import head_tool_lengths
    from sim.gcode.program import interpret
    from sim.kinematics import HeadHead

    kin = HeadHead("B", pivot_length=100.0)
    moves = interpret("G21 G90\nT1 M6\nG0 Z50\nG43.1 Z40\nG0 B20\nG1 X5 F500\nG0 B0\n"
                      "T2 M6\nG43.1 Z60\nG1 X9 F500\n").moves
    assert head_tool_lengths(kin, moves, "job.toml") == {1: 40.0}  # T2 is never tilted
    moves = interpret("G21 G90\nT1 M6\nG43.1 Z40\nG0 B20\nG1 X5 F500\nG43.1 Z45\nG1 X9 F500\n").moves
    with pytest.raises(JobError, match=r"job.toml: T1 is tilted by the head with two tool lengths, 40 mm \(line 4\) "
                                       r"and 45 mm \(line 7\)"):
        head_tool_lengths(kin, moves, "job.toml")


def _tilted_plunge_job(tmp_path, after: str) -> Path:
    """A plunge on a head-head machine (pivot 100 mm), B30, the tool's G43 length 50 mm:
    the flat end mill's lowest rim point ends on the ray at X30 at Z16 - 3 sin 30;
    then ``after`` (G-code lines, ``{x}``/``{z}`` the plunge's end in machine X and
    program Z) and the program's end."""
    P, L, tilt, r = 100.0, 50.0, 30.0, 3.0
    k = np.array([-math.sin(math.radians(tilt)), 0.0, math.cos(math.radians(tilt))])
    tip_x, tip_z = 30.0 + r * math.cos(math.radians(tilt)), 16.0
    x = tip_x - (P + L) * -k[0]
    z = tip_z - (P + L - (P + L) * k[2])
    (tmp_path / "tilt.nc").write_text(
        "G21 G90 G94\nT1 M6\nG43.1 Z50\nM3 S10000\nG0 Z60\nG0 B30\n"
        f"G0 X{x:.4f} Y10\nG1 Z{z + 10:.4f} F300\nG1 Z{z:.4f} F200\n"
        + after.format(x=x, z=z) + "M5\nM2\n")
    (tmp_path / "job.toml").write_text(
        'work_offset = [0, 0, 0]\nresolution = 0.5\n'
        '[program]\npath = "tilt.nc"\ndialect = "linuxcnc"\n'
        f'[machine]\nkinematics = "xyzbc-head"\npivot_length = {P}\n'
        '[stock]\nbox = [0, 0, 0, 60, 20, 20]\n'
        '[tools]\n1 = "flat:6:L=20"\n')
    return tmp_path / "job.toml"


def test_a_tilted_retract_up_its_own_plunge_is_no_rapid_into_stock(tmp_path, capsys):
    """Retracting (G0) straight up the way a tilted tool plunged: the instances of motion
    of the plunge and of the retract fall at different places, so the retract shaves the
    plunge's cusps (slivers 0.05 mm thick, 0.06 mm^3): not a rapid into material. A
    rapid across the stock at the plunge's depth still is."""
    job = _tilted_plunge_job(tmp_path, "G0 Z60\n")
    code = main(["simulate", str(job), "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert code == 0 and doc["findings"] == [], doc["findings"]
    job = _tilted_plunge_job(tmp_path, "G0 X{x:.4f} Y16\nG0 Z60\n")
    main(["simulate", str(job), "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert [(f["kind"], f["line"]) for f in doc["findings"]] == [("rapid_into_stock", 10)], doc["findings"]


@pytest.mark.parametrize("model", ["z", "tri-dexel"])
def test_the_unchecked_cut_places_a_tilted_tool_by_its_g43_length(tmp_path, capsys, model):
    """``simulate --no-checks`` cuts the tilted plunge where the checked cut does, on
    either stock model: the head places the tool by its G43 length (50 mm), not at the
    gauge point (beside the stock, where it removed nothing)."""
    job = _tilted_plunge_job(tmp_path, "G0 Z60\n")
    flags = ["--tri-dexel"] if model == "tri-dexel" else []
    assert main(["simulate", str(job), "--json", *flags]) == 0
    checked = json.loads(capsys.readouterr().out)["removed_mm3"]
    assert main(["simulate", str(job), "--json", "--no-checks", *flags]) == 0
    unchecked = json.loads(capsys.readouterr().out)["removed_mm3"]
    assert checked > 100.0 and unchecked == pytest.approx(checked, abs=1e-3)
