"""Where a dry run starts, the first move checked alike by ``simulate`` and ``dry-run``, and
wrong setups never reported as clean (issue 12).

The dry runs go through ``monitor.cli.main`` on the virtual controller with ``--json`` and
``--clock sim`` (the machine moves a fixed time per poll: the same run however busy the
computer is)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from monitor.cli import main

#: a short program: up to Z15, over to (5, 5), a 2 mm deep slot, back up
PROGRAM = """G21 G90 G17 G94 G54
T1 M6
S10000 M3
G0 Z15
G0 X5 Y5
G1 Z8 F600
G1 X30
G1 Y20
G0 Z{retract}
M5
M30
"""
FIRST_RAPID_LINE = 4


def write_job(tmp_path: Path, stock, tables: str = "", top: str = "", program: str | None = None,
              retract: float = 15, program_keys: str = "") -> Path:
    """A job file for ``PROGRAM`` (or ``program``) with a box stock, a 6 mm flat tool, ``top``
    (top-level keys), ``program_keys`` (more keys of [program]) and ``tables`` (TOML tables,
    at the end)."""
    (tmp_path / "p.nc").write_text(program if program is not None else PROGRAM.format(retract=retract))
    job = tmp_path / "job.toml"
    job.write_text(f"""{top}
resolution = 0.5
[program]
path = "p.nc"
{program_keys}
[stock]
box = {list(stock)}
[tools]
1 = "flat:6:L=20"
{tables}""")
    return job


def dry_run(capsys, job: Path) -> tuple[int, list[dict]]:
    """``dexmon dry-run JOB --clock sim --json``: exit status and the JSON lines."""
    code = main(["dry-run", str(job), "--clock", "sim", "--speed", "10", "--json",
                 "--run", str(job.parent / "run.sqlite")])
    out = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert out[-1]["event"] == "summary" and out[-1]["stages"] > 0 and out[-1]["ended"] == "done", out[-1]
    return code, out


def simulate(capsys, job: Path) -> tuple[int, dict]:
    code = main(["simulate", str(job), "--json"])
    return code, json.loads(capsys.readouterr().out)


def findings_of(out: list[dict]) -> list[dict]:
    return [x for x in out if x.get("event") == "finding"]


def kinds_lines(findings) -> set[tuple[str, int]]:
    return {(f["kind"], f["line"]) for f in findings}


# --- the start position -------------------------------------------------------------------

def test_a_stock_around_machine_zero_gives_no_false_finding_at_the_first_move(tmp_path, capsys):
    """The virtual machine used to start at machine (0, 0, 0), inside this stock: its first
    rapid up to Z15 went through the material (a false rapid_into_stock)."""
    job = write_job(tmp_path, [-5, -5, -10, 40, 30, 10])
    code, out = dry_run(capsys, job)
    assert findings_of(out) == [] and code == 0, findings_of(out)
    code, doc = simulate(capsys, job)
    assert doc["findings"] == [] and code == 0


def test_a_first_rapid_past_a_travel_limit_is_reported_by_simulate_and_dry_run(tmp_path, capsys):
    """simulate used to skip the first rapid for every check; it now runs from the start
    position (the top of Z travel above the first point), so a first rapid past the Z
    travel is reported, by both commands alike."""
    job = write_job(tmp_path, [2, 2, 0, 40, 30, 10], retract=11,
                    tables="[limits]\nx = [-100, 100]\ny = [-100, 100]\nz = [-50, 12]\n")
    code, doc = simulate(capsys, job)
    assert code == 1 and first_rapid_past_z(doc["findings"]), doc["findings"]
    code, out = dry_run(capsys, job)
    assert code == 1 and first_rapid_past_z(findings_of(out)), findings_of(out)


def first_rapid_past_z(findings) -> bool:
    """The findings are one travel_limit in Z from the first rapid on (up at Z15, over to
    the slot and down past Z12 again)."""
    return (len(findings) == 1 and findings[0]["kind"] == "travel_limit" and findings[0]["lines"][0] == FIRST_RAPID_LINE
            and findings[0]["detail"]["axis"].upper() == "Z")


def test_a_first_rapid_through_the_stock_is_reported_by_both(tmp_path, capsys):
    """From the start position the first rapid is checked as a rapid: one that goes down
    through the stock is a rapid_into_stock in both commands."""
    program = PROGRAM.format(retract=15).replace("G0 Z15\nG0 X5 Y5\n", "G0 X20 Y15 Z5\nG0 X5 Y5 Z15\n", 1)
    job = write_job(tmp_path, [0, 0, 0, 40, 30, 10], program=program)
    code, doc = simulate(capsys, job)
    assert code == 1 and ("rapid_into_stock", FIRST_RAPID_LINE) in kinds_lines(doc["findings"]), doc["findings"]
    code, out = dry_run(capsys, job)
    assert code == 1 and ("rapid_into_stock", FIRST_RAPID_LINE) in kinds_lines(findings_of(out)), findings_of(out)


def test_the_start_position_is_in_machine_coordinates(tmp_path, capsys):
    """``[machine] start`` is where the machine stands (machine coords, like [limits]): the
    dry-run machine starts there, simulate at its work position; without it, the top of
    the Z travel above the program's first point (G0 Z15 from machine zero: X0 Y0)."""
    import numpy as np

    from monitor.runreader import RunReader

    offset = 'work_offset = [-190, -100, -50]'
    job = write_job(tmp_path, [0, 0, 0, 40, 30, 10], top=offset, tables="[machine]\nstart = [-10, -20, -5]\n")
    code, doc = simulate(capsys, job)
    assert code == 0 and doc["start"] == [180.0, 80.0, 45.0]
    code, out = dry_run(capsys, job)
    assert code == 0 and findings_of(out) == []
    # its first poll finds it on its way from there to the first point, X0 Y0 Z15 of work
    a, b = np.array([-10.0, -20.0, -5.0]), np.array([-190.0, -100.0, -35.0])
    p = RunReader(tmp_path / "run.sqlite").states()["mpos"][0, :3]
    k = float(np.dot(p - a, b - a) / np.dot(b - a, b - a))
    assert 0 <= k < 1 and np.allclose(p, a + k * (b - a)), p
    job = write_job(tmp_path, [0, 0, 0, 40, 30, 10], top=offset, tables="[limits]\nz = [-150, -2]\n")
    code, doc = simulate(capsys, job)
    assert code == 0 and doc["start"] == [0.0, 0.0, 48.0]


# --- wrong setups are never clean ---------------------------------------------------------

INCH_PROGRAM = """G20 G90 G17 G94 G54
T1 M6
S10000 M3
G0 Z0.6
G0 X2 Y2
G1 Z0.3 F20
G1 X3
G1 Y2.5
G0 Z0.6
M5
M30
"""


def setup_first(out: list[dict], check: str) -> dict:
    """The run's one setup finding of ``check``: alerted before any other finding, right
    after the start line when it is known before the machine moves."""
    found = findings_of(out)
    setups = [f for f in found if f["kind"] == "setup"]
    assert [f["detail"]["check"] for f in setups] == [check], found
    assert found[0] is setups[0] and setups[0]["status"] == "setup" and setups[0]["lead_time_s"] is None
    return setups[0]


def test_dry_run_says_the_path_never_reaches_the_stock(tmp_path, capsys):
    job = write_job(tmp_path, [100, 100, 0, 140, 130, 10])
    code, out = dry_run(capsys, job)
    f = setup_first(out, "path_misses_stock")
    assert code == 1 and out[1] is f and "work offset" in f["message"], out
    assert out[-1]["kinds"] == ["setup"]
    # the run file keeps it, with what to check
    assert main(["replay", str(tmp_path / "run.sqlite"), "--findings"]) == 1
    assert "Setup: the program's cutting moves never reach the stock" in capsys.readouterr().out


def test_live_says_the_path_never_reaches_the_stock(tmp_path, capsys):
    job = write_job(tmp_path, [100, 100, 0, 140, 130, 10])
    url = f"virtual://{tmp_path / 'p.nc'}?clock=sim&speed=10&rate=50"
    code = main(["live", str(job), "--controller", url, "--json", "--run", str(tmp_path / "live.sqlite")])
    out = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    f = setup_first(out, "path_misses_stock")
    assert code == 1 and out[1] is f and out[-1]["ended"] == "program end", out


def test_dry_run_says_an_inch_program_misses_a_stock_in_mm(tmp_path, capsys):
    job = write_job(tmp_path, [0, 0, 0, 40, 30, 10], program=INCH_PROGRAM)
    code, out = dry_run(capsys, job)
    f = setup_first(out, "path_misses_stock")
    assert code == 1 and out[1] is f and "inches (G20)" in f["message"], f


def test_dry_run_says_the_design_is_not_in_the_stock(tmp_path, capsys):
    import trimesh

    trimesh.creation.box(bounds=[[200, 200, 0], [210, 210, 5]]).export(tmp_path / "design.stl")
    job = write_job(tmp_path, [0, 0, 0, 40, 30, 10], tables='[design]\nstl = "design.stl"\n')
    code, out = dry_run(capsys, job)
    f = setup_first(out, "design_outside_stock")
    assert code == 1 and out[1] is f and "design" in f["message"], f


def test_dry_run_says_the_controller_reports_another_work_offset(tmp_path, capsys):
    """The virtual controller takes its offsets from the job's .var file (G54 at X-200
    Y-100 Z-50); the job says its work zero is 10 mm further in X."""
    (tmp_path / "m.var").write_text("5221 -200\n5222 -100\n5223 -50\n")
    job = write_job(tmp_path, [0, 0, 0, 40, 30, 10], top="work_offset = [-190, -100, -50]",
                    program_keys='var = "m.var"')
    code, out = dry_run(capsys, job)
    f = setup_first(out, "work_offset_differs")
    assert code == 1, out
    assert "X-200.000 Y-100.000 Z-50.000" in f["message"] and "X-190.000 Y-100.000 Z-50.000" in f["message"]
    assert f["detail"]["controller_wco"] == [-200, -100, -50] and f["detail"]["job_work_offset"] == [-190, -100, -50]


def test_a_dry_run_sets_the_machine_up_at_the_jobs_work_offset(tmp_path, capsys):
    """Without a .var file the virtual machine is set up as the job says, its work zero at
    the job's work_offset: no setup finding, and the job's findings where the job has them
    (the first rapid down into the stock and the next one out of it)."""
    program = PROGRAM.format(retract=15).replace("G0 Z15\nG0 X5 Y5\n", "G0 X20 Y15 Z5\nG0 X5 Y5 Z15\n", 1)
    job = write_job(tmp_path, [0, 0, 0, 40, 30, 10], top="work_offset = [-190, -100, -50]", program=program)
    code, out = dry_run(capsys, job)
    found = findings_of(out)
    assert code == 1 and {f["kind"] for f in found} == {"rapid_into_stock"}, found
    assert {n for f in found for n in f["lines"]} == {4, 5}, found


# --- simulate and dry-run report the same findings ----------------------------------------

#: lines of a corpus program kept (its start, a few passes): the whole programs take minutes
CORPUS_LINES = 1000


def corpus_job(tmp_path: Path, shared: Path, part: str, tool: str) -> Path:
    """A job for the start of a corpus finishing path (../shared/corpus/parts/README.md):
    the README's suggested stock, the part's STL bounding box (its .json ``bbox``), which
    holds machine zero; the design STL; work offset G54 = the STL origin; ``tool``."""
    parts = shared / "corpus" / "parts"
    meta = json.loads((parts / f"{part}_ball6_finish.json").read_text())
    lines = (parts / f"{part}_ball6_finish.ngc").read_text().splitlines()[:CORPUS_LINES]
    prog = tmp_path / f"{part}.ngc"
    prog.write_text("\n".join(lines + [f"G0 Z{meta['safe_z']:.4f}", "M5", "M30"]) + "\n")
    job = tmp_path / f"{part}.toml"
    job.write_text(f"""resolution = 0.5
[program]
path = "{prog.name}"
[stock]
box = {list(meta["bbox"])}
[tools]
1 = "{tool}:L=20"
[design]
stl = "{parts / meta['stl']}"
[tolerance]
gouge = 0.01
""")
    return job


def run_findings(path: Path) -> list[dict]:
    """The findings a run file holds, as they ended (grown, happened)."""
    from monitor.runreader import RunReader

    return RunReader(path).findings()


def covered(f: dict, others: list[dict], radius: float = 5.0) -> bool:
    """``f`` is among ``others``: one of its kind shares a line with it or lies within
    ``radius`` mm (simulate merges a long finding into one, the live alerter into pieces of
    its radius; JSON line lists stop at 200)."""
    import numpy as np

    for g in others:
        if g["kind"] != f["kind"]:
            continue
        if set(f["lines"]) & set(g["lines"]) or np.linalg.norm(np.subtract(f["position"], g["position"])) <= radius:
            return True
    return False


def assert_same_findings(capsys, job: Path, speed: float = 20) -> list[dict]:
    """simulate and dry-run of ``job`` find the same: every finding of one is among the
    other's, and the deepest of each kind is as deep. Undercut is left out: it judges the
    finished part, which only simulate sees. Returns simulate's findings."""
    code, doc = simulate(capsys, job)
    sim = [f for f in doc["findings"] if f["kind"] != "undercut"]
    run = job.with_suffix(".sqlite")
    main(["dry-run", str(job), "--clock", "sim", "--speed", str(speed), "--quiet", "--run", str(run)])
    live = run_findings(run)
    assert {f["kind"] for f in sim} == {f["kind"] for f in live}, (sim, live)
    assert all(covered(f, live) for f in sim), (sim, live)
    assert all(covered(f, sim) for f in live), (sim, live)
    for kind in {f["kind"] for f in sim}:
        deepest = [max(f.get("depth", 0.0) for f in fs if f["kind"] == kind) for fs in (sim, live)]
        assert abs(deepest[0] - deepest[1]) <= 0.01, (kind, deepest)
    return sim


def test_simulate_and_dry_run_agree_on_the_bundled_example(tmp_path, capsys):
    import shutil

    from monitor.commands.dry_run import EXAMPLE_JOB

    shutil.copytree(EXAMPLE_JOB.parent, tmp_path / "ex")
    sim = assert_same_findings(capsys, tmp_path / "ex" / EXAMPLE_JOB.name)
    assert {(f["kind"], f["line"]) for f in sim} == {("gouge", 22), ("rapid_into_stock", 36)}


@pytest.mark.parametrize("part, tool", [("sphere_on_plate", "ball:6"), ("carpet1", "ball:6"), ("carpet1", "ball:8")])
def test_simulate_and_dry_run_agree_on_the_corpus_parts(tmp_path, capsys, shared, part, tool):
    """Both stocks hold machine zero, where the dry-run machine used to start: the first
    move is now judged alike. The 6 mm ball paths are clean; an 8 mm ball gouges the
    carpet's creases (README "useful negative tests")."""
    sim = assert_same_findings(capsys, corpus_job(tmp_path, shared, part, tool))
    assert {f["kind"] for f in sim} == (set() if tool == "ball:6" else {"gouge"}), sim


def test_work_offset_check_allows_the_programs_own_offsets_and_tells_once():
    """A WCO that is the job's work offset plus the program's tool length offset (or G92)
    is the job's; another one is told once, naming both."""
    from drivers.state import MachineState, RunState
    from monitor.setup_check import WorkOffsetCheck
    from sim.gcode.moves import empty_moves

    moves = empty_moves(3)
    moves["wco"][1, 2] = 25.0            # G43: tool length 25 mm
    moves["wco"][2, :3] = (5.0, 0.0, 25.0)  # G92 X-5 on top
    check = WorkOffsetCheck((-190, -100, -50), moves, (0, 0, 0, 0, 0, 0))

    def state(wco, kind=RunState.RUN):
        return MachineState(t=1.0, mpos=(0, 0, 0), wco=wco, state=kind)

    for ok in [(-190, -100, -50), (-190, -100, -25), (-185, -100, -25), (-190.004, -100, -50)]:
        assert check.see(state(ok), (0, 0, 0)) == [], ok
    assert check.see(state((-180, -100, -50), RunState.MISSED), (0, 0, 0)) == []  # not fresh: not the controller's
    (rec,) = check.see(state((-180, -100, -50)), (1, 2, 3))
    assert rec["kind"] == "setup" and rec["detail"]["check"] == "work_offset_differs" and rec["position"] == [1, 2, 3]
    assert "X-180.000 Y-100.000 Z-50.000" in rec["message"] and "X-190.000" in rec["message"]
    assert check.see(state((-170, -100, -50)), (0, 0, 0)) == []  # once


def test_no_work_offset_check_for_a_controller_that_does_not_report_it():
    import dataclasses

    from monitor.commands.dry_run import EXAMPLE_JOB
    from monitor.job import load_job
    from monitor.program_moves import load_moves
    from monitor.session import Session

    job = dataclasses.replace(load_job(EXAMPLE_JOB), work_offset=(-190.0, -100.0, -50.0))
    moves, _ = load_moves(job)
    s = Session(job, moves)
    assert s.check_setup(reports_wco=False) == [] and s._offset_check is None
    assert s.check_setup(reports_wco=True) == [] and s._offset_check is not None


def test_a_modbus_map_without_the_work_offset_does_not_report_it():
    import dataclasses

    from drivers.modbus.driver import ModbusController
    from drivers.modbus.regmap import load_map

    full = load_map("generic")
    assert ModbusController(full, host="127.0.0.1").reports_wco
    bare = dataclasses.replace(full, fields={k: v for k, v in full.fields.items() if not k.startswith("wco_")})
    assert not ModbusController(bare, host="127.0.0.1").reports_wco


def test_start_at_moves_only_what_comes_before_the_first_point():
    import numpy as np

    from monitor.start import start_at, start_point
    from sim.gcode.moves import MoveKind, empty_moves

    def same(a, b):  # bit for bit (arc centres are NaN)
        return a.tobytes() == b.tobytes()

    m = empty_moves(3)
    m["kind"] = [MoveKind.TOOL_CHANGE, MoveKind.RAPID, MoveKind.FEED]
    m["end"][1:, :3] = [[5, 6, 7], [9, 6, 7]]
    m["start"][2, :3] = [5, 6, 7]
    m["tool_length"] = 20.0  # the table holds the controlled point: 20 mm above the tip
    p = start_point(m, material_top=30.0)
    assert p.tolist() == [5.0, 6.0, 30.0 + 10.0 + 20.0]  # over the first point, 10 mm above the top
    out = start_at(m, p)
    assert out["start"][0, :3].tolist() == out["end"][0, :3].tolist() == out["start"][1, :3].tolist() == p.tolist()
    assert same(out[2:], m[2:]) and np.array_equal(out["end"][1], m["end"][1])
    m["kind"][1] = MoveKind.ARC_CW  # an arc from another point would be another arc
    assert same(start_at(m, p), m)
    m["kind"][1:] = MoveKind.DWELL
    assert start_point(m) is None and same(start_at(m, (1, 2, 3)), m)


def test_a_setup_finding_is_told_by_its_message_on_the_terminal():
    from monitor.alerts import format_finding

    rec = {"kind": "setup", "line": 6, "position": [5, 5, 8], "lead_time_s": None,
           "message": "setup: the design does not lie in the stock: check the design's offset"}
    assert format_finding(rec) == "SETUP: the design does not lie in the stock: check the design's offset"
