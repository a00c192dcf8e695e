"""Live checks on the real motion and the one-alert rule, all through sim.checks.Checker.

* a machine whose work offset is 0.5 mm lower in Z than the job says gouges the design on
  every facing pass: the program looks clean ahead, the gouge is found on the live model
  (with its line, lead time 0, status "happened");
* a predicted finding that then really happens is alerted once and its record (memory,
  JSON lines, run file) is updated to "happened";
* the look-ahead work per state is bounded and gives the same findings as one big batch;
* travel limits are checked in work coordinates and told in machine coordinates.
"""

from __future__ import annotations

import dataclasses
import io
import json

import numpy as np
import pytest

from drivers.state import MachineState, RunState
from monitor.alerts import Alerter
from monitor.commands.dry_run import EXAMPLE_JOB, virtual_controller
from monitor.job import load_job
from monitor.predict import LiveChecks, Lookahead
from monitor.work_coords import finding_to_machine, limits_in_work, work_moves
from monitor.workpiece import build_workpiece
from monitor.runfile import RunWriter
from monitor.runreader import RunReader
from monitor.loop import run_controller
from monitor.program_moves import load_moves
from monitor.session import Session
from monitor.sync import ProgramPath
from sim.checks.findings import Finding
from sim.gcode.moves import MoveKind, empty_moves, work_end

GOUGE_LINE, RAPID_LINE = 22, 36
DESIGN_TOP = -5.0  # the example's design is the box 5..55 x 5..35 x -20..-5


@pytest.fixture(scope="module")
def example():
    job = load_job(EXAMPLE_JOB)
    moves, program = load_moves(job)
    return job, moves, program


def _shift_z(moves, dz):
    out = moves.copy()
    for col in ("start", "end"):
        out[col][:, 2] += dz
    out["center"][:, 2] += dz
    return out


def test_gouge_found_on_the_live_model_when_the_machine_deviates(example):
    job, moves, program = example
    # the job says work zero is machine zero; the machine really has it 0.5 mm lower
    job = dataclasses.replace(job, work_offset=(0.0, 0.0, 0.0))
    vc = virtual_controller(_shift_z(moves, -0.5), speed=1.0, rate=50, clock="sim")
    s = Session(job, moves, program=program)
    vc.connect()
    run_controller(s, vc, 0.0, done=lambda: vc.done)
    vc.close()
    live = [f for f in s.findings if f["kind"] == "gouge" and not f["predicted"]]
    assert live, s.findings
    first = live[0]
    assert first["status"] == "happened" and first["lead_time_s"] == 0.0
    # found on the first pass over the design (line 13: G1 X-8 at Y6), where the tool was;
    # followed along, the record holds every pass and its deepest hit (the planted dip on
    # line 22 makes it 0.5 + 0.5 mm there), as simulate merges one gouge
    assert 13 <= first["lines"][0] < GOUGE_LINE and len(first["lines"]) > 3, first
    assert first["depth"] >= 0.5 - 0.06 and first["depth"] == pytest.approx(1.0, abs=0.06)
    assert first["position"][2] == pytest.approx(DESIGN_TOP - first["depth"], abs=0.06)
    assert 5.0 - 1e-6 <= first["position"][0] <= 55.0 + 1e-6
    # the live model really is 0.5 mm below the design top inside the faced area
    f = s.live.frame
    i, j = int(round((40 - f.origin[0]) / f.spacing)), int(round((20 - f.origin[1]) / f.spacing))
    assert s.live.top()[j, i] == pytest.approx(DESIGN_TOP - 0.5, abs=1e-6)
    # the long gouge along the passes is followed, not re-alerted every few mm
    assert len(live) <= 3, [(f["line"], f["position"]) for f in live]
    # the program itself is clean there: nothing predicted before the planted gouge
    predicted = [f for f in s.findings if f["predicted"]]
    assert all(f["line"] >= GOUGE_LINE for f in predicted), predicted


def test_predicted_then_happened_is_one_alert(example, tmp_path):
    job, moves, program = example
    vc = virtual_controller(moves, speed=1.0, rate=50, clock="sim")
    out = io.StringIO()
    with RunWriter(tmp_path / "r.sqlite") as w:
        s = Session(job, moves, run=w, alerter=Alerter(json_stream=out, run=w), program=program)
        vc.connect()
        run_controller(s, vc, 0.0, done=lambda: vc.done)
        vc.close()
        s.finish()
    events = [json.loads(x) for x in out.getvalue().splitlines()]
    alerted = [e for e in events if e["event"] == "finding"]
    keys = [(e["kind"], e["line"]) for e in alerted]
    assert sorted(keys) == [("gouge", GOUGE_LINE), ("rapid_into_stock", RAPID_LINE)], keys
    assert all(e["predicted"] and e["lead_time_s"] > 0 and e["status"] == "predicted" for e in alerted)
    updates = [e for e in events if e["event"] == "finding_update" and e["status"] == "happened"]
    assert sorted((u["kind"], u["status"]) for u in updates) == [("gouge", "happened"),
                                                                 ("rapid_into_stock", "happened")]
    # in memory: the alerted records now say they happened, after they were predicted
    for rec in s.findings:
        assert rec["status"] == "happened" and rec["happened_t"] > rec["t"], rec
    # in the run file: same two findings, updated in place, one alert each per channel
    r = RunReader(tmp_path / "r.sqlite")
    stored = r.findings()
    assert [(f["kind"], f["status"]) for f in stored] == [(k, "happened") for k, _ in keys]
    channels = [a["channel"] for a in r.alerts()]
    assert channels.count("json") == 2


def _state(t, tip, spindle=10000.0, state=RunState.RUN):
    return MachineState(t=t, mpos=tuple(tip) + (0, 0, 0), state=state, spindle=spindle)


def test_live_spindle_stopped_and_rapid_are_found_on_the_real_path(example):
    job, moves, program = example
    job = dataclasses.replace(job, work_offset=(0.0, 0.0, 0.0), design=None, fixtures=[])
    # the facing row at line 11 (G1 X68 at Y2, Z-5) runs with the spindle reported stopped
    k = int(np.nonzero(moves["line"] == 11)[0][0])
    s = Session(job, moves, program=program)
    p0, p1 = work_end(moves)[k - 1, :3], work_end(moves)[k, :3]
    t = 0.0
    for f in np.linspace(0.0, 0.5, 12):
        s.step(_state(t, p0 + f * (p1 - p0), spindle=0.0))
        t += 0.02
    kinds = {(r["kind"], r["line"], r["predicted"]) for r in s.findings}
    assert ("spindle_stopped_cutting", 11, False) in kinds, s.findings
    rec = next(r for r in s.findings if r["kind"] == "spindle_stopped_cutting")
    assert rec["volume"] > 1.0 and rec["lead_time_s"] == 0.0


def test_lookahead_budget_spreads_work_and_finds_the_same(example):
    job, moves, program = example
    wp = build_workpiece(job, moves)
    mw = work_moves(moves)
    path = ProgramPath.from_moves(mw)

    def run(budget):
        la = Lookahead(wp, mw, path, horizon_s=1e9, budget_rays=budget)
        la.anchor(wp.stock, 0)
        found, calls, per_call = [], 0, []
        while la.behind(0.0):
            before = la.next_row
            found += la.advance(0.0)
            per_call.append(la.next_row - before)
            calls += 1
        return found, calls, per_call, la

    big, calls_big, _, _ = run(1e12)
    small, calls_small, per_call, la = run(1.0)
    assert calls_big == 1 and calls_small == len(moves)  # tiny budget: one row per call
    assert all(n == 1 for n in per_call)
    def lines(found):  # (kind, line) of every line involved: batches merge hits differently
        return {(f.kind, ln) for f in found for ln in f.lines}
    assert lines(big) == lines(small)
    assert {("gouge", GOUGE_LINE), ("rapid_into_stock", RAPID_LINE)} <= lines(small)
    # a moderate budget bounds the rows' estimated cost per call (one row may exceed it)
    costs = np.diff(la.cost_cum)
    mid = 5 * float(np.median(costs))
    la2 = Lookahead(wp, mw, path, horizon_s=1e9, budget_rays=mid)
    la2.anchor(wp.stock, 0)
    while la2.behind(0.0):
        lo = la2.next_row
        la2.advance(0.0)
        hi = la2.next_row
        assert hi - lo == 1 or costs[lo:hi].sum() <= mid


def test_live_checks_unit_gouge_depth_is_exact(example):
    """A flat end mill cutting 0.3 mm into the top of a box design: gouge 0.3 deep, found
    on the live model at the program line of the piece that made it."""
    job, moves, _ = example
    job = dataclasses.replace(job, fixtures=[])
    m = empty_moves(1)
    m["kind"] = MoveKind.FEED
    m["line"] = 77
    m["spindle"], m["spindle_dir"], m["feed"], m["tool"] = 10000, 1, 600, 1
    m["start"][0, :3] = (10, 20, -5.3)
    m["end"][0, :3] = (40, 20, -5.3)
    wp = build_workpiece(job, m)
    lc = LiveChecks(wp, work_moves(m))
    pts = np.array([[10.0, 20.0, -5.3], [25.0, 20.0, -5.3], [40.0, 20.0, -5.3]])
    removed, rays, found = lc.cut(pts, np.array([0, 0]), spindle_rpm=10000)
    # a 6 mm slot 30 mm long with round ends, 5.3 mm deep (stock top at 0); dexels count
    # whole cells, so the error is bounded by the outline x half a cell x the depth
    outline = 2 * 30 + 2 * np.pi * 3
    assert abs(removed - (30 * 6 + np.pi * 9) * 5.3) <= outline * wp.frame.spacing / 2 * 5.3
    assert rays.size > 0
    g = [f for f in found if f.kind == "gouge"]
    assert len(g) == 1 and g[0].line == 77 and g[0].depth == pytest.approx(0.3, abs=0.01)


def test_travel_limits_checked_in_work_coordinates_told_in_machine():
    wco = np.array([-100.0, -50.0, -30.0, 0, 0, 0])
    lim = limits_in_work({"x": (-200.0, 0.0), "z": (-60.0, 0.0)}, wco)
    assert lim == {"X": (-100.0, 100.0), "Z": (-30.0, 30.0)}
    f = Finding("travel_limit", line=5, stage=2, position=(101.0, 0.0, 0.0), depth=1.0,
                detail={"group": "X+", "axis": "X", "limit": 100.0})
    g = finding_to_machine(f, wco)
    assert g.position == (1.0, -50.0, -30.0) and g.detail["limit"] == 0.0
    assert "Xmax 0 exceeded by 1.000 at line 5" in g.message


def test_reanchor_refills_the_scratch_model_from_the_live_one(example):
    job, moves, _ = example
    wp = build_workpiece(job, moves)
    mw = work_moves(moves)
    la = Lookahead(wp, mw, ProgramPath.from_moves(mw), horizon_s=1e9)
    live_top = wp.stock.top().copy()
    la.anchor(wp.stock, 0)
    scratch = la.model
    while la.behind(0.0):  # the whole program on the scratch model
        la.advance(0.0)
    assert np.nanmin(la.model.top()) < -9.0 and np.array_equal(wp.stock.top(), live_top, equal_nan=True)
    la.anchor(wp.stock, 5)  # a jump: same scratch object, refilled
    assert la.model is scratch and la.next_row == 5
    assert np.array_equal(la.model.top(), live_top, equal_nan=True)


BOSS_PROGRAM = """G21 G90 G17 G94
T1 M6
S10000 M3
G0 Z5
G0 X43 Y30
G1 Z-2 F600
G2 X43 Y30 I-13 J0 F1200
G0 Z5
M5
M30
"""


def test_contour_around_a_boss_is_clean_live(tmp_path):
    """A 6 mm flat end mill circling a 10 mm-radius boss at 13 mm: tangent to the design
    all round, so the live path (the program's arc between polls) must not gouge it by
    its chords (gouge band 0.02 mm)."""
    import trimesh

    from monitor.job import Job, Solid, ToolDef
    from sim.tolerance import Tolerance

    boss = trimesh.creation.cylinder(radius=10.0, height=10.0, sections=512)
    boss.apply_translation((30.0, 30.0, -5.0))
    boss.export(str(tmp_path / "boss.stl"))
    (tmp_path / "boss.nc").write_text(BOSS_PROGRAM)
    job = Job(program=tmp_path / "boss.nc", stock=Solid("box", box=(0, 0, -10, 60, 60, 0)),
              default_tool=ToolDef(0, "flat:6:L=20"), design=Solid("stl", stl=tmp_path / "boss.stl"),
              resolution=0.1, tolerance=Tolerance(gouge=0.02, undercut=0.02), work_offset=(0.0, 0.0, 0.0))
    moves, program = load_moves(job)
    s = Session(job, moves, program=program)
    vc = virtual_controller(moves, speed=1.0, rate=50, clock="sim")
    vc.connect()
    run_controller(s, vc, 0.0, done=lambda: vc.done)
    vc.close()
    assert s.findings == []
    # and the boss wall really was cut to within the band all round
    f = s.live.frame
    top = s.live.top()
    ang = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    for r, want in ((10.3, -2.0), (15.5, -2.0), (9.7, 0.0)):
        i = np.round((30 + r * np.cos(ang) - f.origin[0]) / f.spacing).astype(int)
        j = np.round((30 + r * np.sin(ang) - f.origin[1]) / f.spacing).astype(int)
        assert np.allclose(top[j, i], want, atol=1e-6), (r, top[j, i])


def test_travel_limit_predicted_then_happened_in_machine_coordinates(example):
    job, moves, program = example
    # the machine's X travel ends at 65 (machine = work here): the facing passes to X68 cross it
    job = dataclasses.replace(job, limits={"x": (-100.0, 65.0)}, design=None)
    vc = virtual_controller(moves, speed=1.0, rate=50, clock="sim")
    s = Session(job, moves, program=program)
    vc.connect()
    for _ in range(50 * 12):  # the first passes are enough
        s.step(vc.poll())
    vc.close()
    lim = [f for f in s.findings if f["kind"] == "travel_limit"]
    # one finding per pass that crosses (lines 11-13 run into X68 and back), each first
    # predicted, then seen on the real motion: no second alert for it
    assert [f["line"] for f in lim] == sorted({f["line"] for f in lim}) and lim[0]["lines"][:3] == [11, 12, 13]
    assert all(f["predicted"] and f["lead_time_s"] > 0 for f in lim)
    f = lim[0]
    assert f["status"] == "happened" and f["position"][0] == pytest.approx(68.0)
    assert f["depth"] == pytest.approx(3.0) and "Xmax 65 exceeded by 3.000" in f["message"]


def test_first_state_fills_the_horizon_then_work_is_budgeted(example):
    job, moves, program = example
    s = Session(job, moves, program=program)
    s.lookahead.budget_rays = 1.0  # one row per later state
    mw = s.moves
    k = int(np.nonzero(moves["line"] == 11)[0][0])
    s.step(_state(0.0, mw["start"][k, :3]))
    assert s.lookahead.behind(s.last_sync.progress) == 0 and s.lookahead.next_row > k + 2  # not one row
    # the spindle jumps far ahead of the scratch model (the operator ran from line 30):
    # the look-ahead restarts from the live model there instead of predicting the past
    j = int(np.nonzero(moves["line"] == 30)[0][0])
    s.step(MachineState(t=0.02, mpos=tuple(mw["start"][j, :3]) + (0, 0, 0), state=RunState.RUN,
                        spindle=10000.0, line=30))
    assert s.last_sync.row == j and s.lookahead.next_row == j + 1


def test_live_fixture_collision_off_the_program(example):
    """The operator jogs the tool into the clamp (no program row goes there): found live."""
    job, moves, program = example
    job = dataclasses.replace(job, work_offset=(0.0, 0.0, 0.0), design=None)
    s = Session(job, moves, program=program)
    k = int(np.nonzero(moves["line"] == 9)[0][0])  # G0 X-8 Y2 at Z5, left of the block
    p = np.array(s.moves["end"][k, :3])
    s.step(_state(0.0, p))
    for n, y in enumerate(np.linspace(2.0, 20.0, 10)):  # along Y at X-14, Z5: through the clamp's end
        s.step(_state(0.02 * (n + 1), (-14.0, y, 5.0)))
    hits = [f for f in s.findings if f["kind"] == "fixture_collision"]
    assert hits and all(not f["predicted"] and f["status"] == "happened" for f in hits), s.findings
    assert "clamp" in hits[0]["message"]
    assert 14.0 - 3.0 <= hits[0]["position"][1] <= 26.0 + 3.0


def test_a_stopped_spindle_at_one_poll_does_not_blame_the_whole_gap(example):
    """Polls far apart (a slow link, a long pause): the spindle was on at the last poll and
    is off now (after M5); the path in between is not a stopped-spindle cut."""
    job, moves, program = example
    job = dataclasses.replace(job, work_offset=(0.0, 0.0, 0.0), design=None)
    s = Session(job, moves, program=program)
    mw = s.moves
    k = int(np.nonzero(moves["line"] == 11)[0][0])
    s.step(_state(0.0, mw["start"][k, :3], spindle=10000.0))
    s.step(_state(0.02, mw["start"][k, :3] + (1.0, 0, 0), spindle=10000.0))
    s.step(_state(0.04, mw["end"][k, :3], spindle=0.0))  # on at the last poll, off now
    assert s.stage == 2 and not [f for f in s.findings if f["kind"] == "spindle_stopped_cutting"]
    # off at both polls: it is (Y6 at X68 is off the stock; the X-8 pass of line 13 cuts)
    s.step(_state(0.06, mw["end"][k + 1, :3] - (20.0, 0, 0), spindle=0.0))
    assert [f["line"] for f in s.findings if f["kind"] == "spindle_stopped_cutting"] == [13]


def test_a_spindle_off_at_both_polls_is_not_judged_across_the_m3_and_m5_between_them(example):
    """One poll before the program's M3, the next after its M5 (a dry run at --speed 10000:
    the whole program between two polls). Both saw the spindle off, as the program has it
    there; in between the program ran it, and nothing was seen of that. Before: the whole
    facing was one false spindle_stopped_cutting (lines 11-32)."""
    job, moves, program = example
    job = dataclasses.replace(job, work_offset=(0.0, 0.0, 0.0), design=None, fixtures=[])
    s = Session(job, moves, program=program)
    mw = s.moves
    on = (mw["spindle"] > 0) & (mw["spindle_dir"] != 0)
    before, after = int(np.nonzero(on)[0][0]) - 1, int(np.nonzero(on)[0][-1]) + 1
    assert not on[before] and not on[after], "the program must start and stop its spindle"
    s.step(_state(0.0, mw["end"][before, :3], spindle=0.0, state=RunState.IDLE))
    s.step(_state(50.0, mw["end"][after, :3], spindle=0.0, state=RunState.IDLE))
    assert s.stage >= 1  # the whole program was cut
    assert not [f for f in s.findings if f["kind"] == "spindle_stopped_cutting"], s.findings
    assert {f["kind"] for f in s.findings} >= {"rapid_into_stock"}  # still judged on its path


WARM_UP_SCRIPT = """
import json, sys, tempfile
from pathlib import Path
from numba.core.registry import CPUDispatcher
from monitor.alerts import Alerter
from monitor.commands.dry_run import EXAMPLE_JOB, virtual_controller
from monitor.job import load_job
from monitor.runfile import RunWriter
from monitor.loop import run_controller
from monitor.program_moves import load_moves
from monitor.session import Session

def signatures():
    out = {}
    for name, mod in list(sys.modules.items()):
        if name.split(".")[0] in ("sim", "monitor", "drivers"):
            for attr, v in list(vars(mod).items()):
                if isinstance(v, CPUDispatcher):
                    out[name + "." + attr] = len(v.signatures)
    return out

job = load_job(EXAMPLE_JOB)
moves, program = load_moves(job)
w = RunWriter(Path(tempfile.mkdtemp()) / "r.sqlite")
s = Session(job, moves, run=w, alerter=Alerter(run=w), program=program)
s.warm_up()
before = signatures()
vc = virtual_controller(moves, speed=1.0, rate=50, clock="sim")
vc.connect()
run_controller(s, vc, 0.0, done=lambda: vc.done)
vc.close()
s.finish()
w.close()
after = signatures()
print(json.dumps({"grew": {k: [before.get(k, 0), v] for k, v in after.items() if v != before.get(k, 0)},
                  "kinds": sorted({f["kind"] for f in s.findings})}))
"""


def test_warm_up_compiles_everything_the_run_needs():
    """With a cold numba cache a kernel first met mid-run stalls the loop for seconds while
    the machine runs on: after warm_up() a whole dry run (run file and trace included)
    must not add a compiled signature to any kernel. In a fresh process, so kernels other
    tests compiled do not hide one the warm-up missed."""
    import subprocess
    import sys
    from pathlib import Path

    out = subprocess.run([sys.executable, "-c", WARM_UP_SCRIPT], capture_output=True, text=True, timeout=300,
                         cwd=Path(__file__).resolve().parents[2])
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["grew"] == {}
    assert got["kinds"] == ["gouge", "rapid_into_stock"]
