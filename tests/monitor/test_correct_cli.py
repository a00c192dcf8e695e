"""``dexmon correct``: gouging paths come out gouge-free as ``dexmon simulate --design``
sees them, with every line that needs no change kept byte for byte."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from monitor.cli import main

EXAMPLE = Path(__file__).resolve().parents[2] / "monitor" / "examples" / "clamp_job"
CARPET_STOCK = "box:0,-82,-10,152,66,5.197857"


def run(capsys, *argv) -> tuple[int, dict | None, str]:
    rc = main(["correct", *map(str, argv)])
    out, err = capsys.readouterr()
    doc = json.loads(out) if "--json" in argv and rc != 2 else None
    return rc, doc, err


def example_job(tmp_path: Path, program_text: str) -> Path:
    """The bundled example job with its program replaced by ``program_text``."""
    prog = tmp_path / "face.nc"
    prog.write_bytes(program_text.encode())
    text = (EXAMPLE / "job.toml").read_text()
    text = text.replace('path = "face.nc"', f'path = "{prog}"')
    text = text.replace('table = "tools.tbl"', f'table = "{EXAMPLE / "tools.tbl"}"')
    text = text.replace('stl = "design.stl"', f'stl = "{EXAMPLE / "design.stl"}"')
    job = tmp_path / "job.toml"
    job.write_text(text)
    return job


def test_the_bundled_jobs_planted_dip_comes_out_clean_and_nothing_else_changes(tmp_path, capsys):
    from monitor.commands.dry_run import EXAMPLE_JOB

    out = tmp_path / "fixed.nc"
    rc, doc, err = run(capsys, EXAMPLE_JOB, "-o", out, "--json")
    assert rc == 0, err
    assert doc["verified"]["gouges"] == 0 and doc["changed_lines"] == [22]
    before = (EXAMPLE / "face.nc").read_bytes().splitlines(keepends=True)
    after = out.read_bytes().splitlines(keepends=True)
    assert len(after) == len(before)
    for k, (a, b) in enumerate(zip(before, after), start=1):
        if k != 22:
            assert a == b, k
    assert b"(dexmon: corrected line 22)" in after[21] and b"planted gouge" in after[21]
    assert 0.45 < doc["gouge_before_mm"] < 0.55
    # the corrected line no longer dips: it stays on the design's top face (Z-5)
    assert b"Z-5.0000" in after[21]


def test_a_path_with_no_gouge_comes_out_byte_identical(tmp_path, capsys):
    text = (EXAMPLE / "face.nc").read_text().replace("G1 X30 Z-5.5 (planted", "G1 X30 Z-5 (no longer planted")
    job = example_job(tmp_path, text)
    out = tmp_path / "fixed.nc"
    rc, doc, err = run(capsys, job, "-o", out, "--json")
    assert rc == 0, err
    assert doc["lines_changed"] == 0 and doc["verified"]["gouges"] == 0
    assert out.read_bytes() == (tmp_path / "face.nc").read_bytes()


# --- small parts of our own: a block design 5 mm under a stock top ----------------------------

def block_design(tmp_path: Path) -> Path:
    import trimesh

    path = tmp_path / "block.stl"
    trimesh.creation.box(bounds=[[0, 0, -20], [40, 30, -5]]).export(path)
    return path


def correct_program(tmp_path, capsys, text: str, *extra):
    prog = tmp_path / "p.nc"
    prog.write_bytes(text.encode())
    out = tmp_path / "fixed.nc"
    rc, doc, err = run(capsys, prog, "--stock", "box:-5,-5,-20,45,35,0", "--tool", "flat:6:L=20",
                       "--design", block_design(tmp_path), "--resolution", "0.25", "--tolerance", "0.01",
                       "-o", out, "--json", *extra)
    return rc, doc, err, out


def simulate_gouges(capsys, tmp_path, program: Path, stock="box:-5,-5,-20,45,35,0", tool="flat:6:L=20",
                    design=None, resolution="0.25", tolerance="0.01") -> list:
    rc = main(["simulate", str(program), "--stock", stock, "--tool", tool, "--design",
               str(design or block_design(tmp_path)), "--resolution", resolution, "--tolerance", tolerance, "--json"])
    out, _ = capsys.readouterr()
    assert rc in (0, 1), out
    return [f for f in json.loads(out)["findings"] if f["kind"] == "gouge"]


def test_inch_program_is_corrected_in_inches(tmp_path, capsys):
    # the block's top is Z-5 mm = -0.19685 in; the pass dips to -0.2 in between X 0.8 and 1.0 in
    text = "G20 G90 G17\nG0 Z0.5\nG0 X-0.3 Y0.6\nG1 Z-0.19685 F20\nG1 X0.8\nG1 X0.9 Z-0.2\nG1 X1.7 Z-0.19685\nG0 Z0.5\nM2\n"
    prog = tmp_path / "p.nc"
    prog.write_text(text)
    assert simulate_gouges(capsys, tmp_path, prog)  # reproduced: it gouges
    rc, doc, err, out = correct_program(tmp_path, capsys, text)
    assert rc == 0, err
    assert doc["changed_lines"] == [6]
    fixed = out.read_text().splitlines()
    assert fixed[5].startswith("G1 X0.90000 Y0.60000 Z-0.19") and "(dexmon: corrected line 6)" in fixed[5]
    assert [a for a in fixed if "dexmon" not in a] == [a for k, a in enumerate(text.splitlines()) if k != 5]
    assert simulate_gouges(capsys, tmp_path, out) == []


def test_g91_lines_after_a_moved_point_get_their_increments_from_where_the_tool_stands(tmp_path, capsys):
    text = "G21 G90\nG0 Z5\nG0 X-8 Y15\nG1 Z-5 F600\nG91\nG1 X20\nG1 X4 Z-0.8\nG1 X4 Z0.8\nG1 X25\nG90 G0 Z5\nM2\n"
    prog = tmp_path / "p.nc"
    prog.write_text(text)
    assert simulate_gouges(capsys, tmp_path, prog)
    rc, doc, err, out = correct_program(tmp_path, capsys, text)
    assert rc == 0, err
    assert doc["verified"]["gouges"] == 0
    assert 7 in doc["changed_lines"] and 8 in doc["changed_lines"] and 9 not in doc["changed_lines"]
    assert simulate_gouges(capsys, tmp_path, out) == []
    # the program still ends where it did: the increments after the dip add up
    from sim.gcode import load_program

    a = load_program(prog).moves
    b = load_program(out).moves
    assert np.allclose(a["end"][-2, :3], b["end"][-2, :3], atol=1e-6)


def test_a_work_offset_is_kept_in_the_written_coordinates(tmp_path, capsys):
    # G55 puts work zero at X10 Y5: the program's coordinates are 10 and 5 less than the part's
    text = "G21 G90\nG10 L2 P2 X10 Y5\nG55\nG0 Z5\nG0 X-18 Y10\nG1 Z-5 F600\nG1 X15 Z-5.4\nG1 X40 Z-5\nG0 Z5\nM2\n"
    rc, doc, err, out = correct_program(tmp_path, capsys, text)
    assert rc == 0, err
    line = out.read_text().splitlines()[6]
    assert line.startswith("G1 X15.0000 Y10.0000 Z-5.0") and "corrected line 7" in line
    assert simulate_gouges(capsys, tmp_path, out) == []


def test_an_arc_that_gouges_is_refused_naming_its_line(tmp_path, capsys):
    text = "G21 G90\nG0 Z5\nG0 X-8 Y15\nG1 Z-5 F600\nG1 X10\nG2 X20 Y15 I5 J-2\nG1 X48\nG0 Z5\nM2\n"
    # the arc through (15, 12.3) lies at Z-5 on the part's top: make it dip
    text = text.replace("G2 X20 Y15 I5 J-2", "G2 X20 Y15 Z-5.5 I5 J-2")
    rc, doc, err, out = correct_program(tmp_path, capsys, text)
    assert rc == 2
    assert f"{tmp_path / 'p.nc'}:6" in err and "arc" in err and "\n" not in err.strip()
    assert not out.exists()


def test_a_loop_line_that_needs_a_correction_is_refused_naming_it(tmp_path, capsys):
    text = ("G21 G90\nG0 Z5\nG0 X-8 Y5\nG1 Z-5 F600\n#1 = 0\no100 while [#1 LT 2]\nG1 X20 Z-5.3\nG1 X48 Z-5\n"
            "G0 Z5\nG0 X-8 Y[10 + #1 * 10]\nG1 Z-5\n#1 = [#1 + 1]\no100 endwhile\nG0 Z5\nM2\n")
    rc, doc, err, out = correct_program(tmp_path, capsys, text)
    assert rc == 2 and f"{tmp_path / 'p.nc'}:7" in err and "more than once" in err


@pytest.mark.parametrize("argv, says", [
    (["--stock", "box:0,0,0,1,1,1", "--tool", "ball:6"], "--design"),
    (["--design", "nope.stl", "--stock", "box:0,0,-1,10,10,0", "--tool", "ball:6"], "nope.stl"),
    (["--design", "DESIGN", "--stock", "box:0,0,-1,10,10,0", "--tool", "ball:6", "--tolerance", "-1"], "--tolerance"),
])
def test_bad_input_is_one_line_naming_what(tmp_path, capsys, argv, says):
    prog = tmp_path / "p.nc"
    prog.write_text("G0 X1\nM2\n")
    argv = [a.replace("DESIGN", str(block_design(tmp_path))) for a in argv]
    rc, _, err = run(capsys, prog, *argv, "-o", tmp_path / "o.nc")
    assert rc == 2 and says in err and len(err.strip().splitlines()) == 1


def test_bad_gcode_names_file_and_line(tmp_path, capsys):
    prog = tmp_path / "p.nc"
    prog.write_text("G21 G90\nG1 X1 Q\nM2\n")
    rc, _, err = run(capsys, prog, "--stock", "box:-5,-5,-20,45,35,0", "--tool", "flat:6",
                     "--design", block_design(tmp_path), "-o", tmp_path / "o.nc")
    assert rc == 2 and f"{prog}:2" in err


# --- the corpus: carpet1 with an 8 mm ball on its 6 mm ball path -----------------------------

def test_carpet_with_an_8mm_ball_comes_out_gouge_free_with_its_undercut_reported(tmp_path, capsys, shared):
    """The first passes of the carpet path (the whole path is the benchmark's): the 8 mm
    ball gouges them by about 0.34 mm; corrected, ``dexmon simulate --design`` finds no
    gouge at 0.002 mm, and the report says how much material the correction leaves."""
    parts = shared / "corpus" / "parts"
    lines = (parts / "carpet1_ball6_finish.ngc").read_text().splitlines(keepends=True)
    prog = tmp_path / "carpet_start.ngc"
    prog.write_text("".join(lines[:2500]) + "G0 Z10.1979\nM5\nM30\n")
    design = parts / "carpet1.stl"
    common = ["--stock", CARPET_STOCK, "--tool", "ball:8", "--design", design, "--resolution", "0.4"]
    before = simulate_gouges(capsys, tmp_path, prog, CARPET_STOCK, "ball:8", design, "0.4", "0.002")
    assert before and max(g["depth"] for g in before) == pytest.approx(0.34, abs=0.02)
    out = tmp_path / "fixed.ngc"
    rc, doc, err = run(capsys, prog, *common, "--tolerance", "0.002", "-o", out, "--json")
    assert rc == 0, err
    assert doc["verified"]["gouges"] == 0
    assert doc["gouge_before_mm"] == pytest.approx(0.34, abs=0.02)
    assert doc["largest_shift_mm"] >= doc["gouge_before_mm"] - 0.01
    u = doc["undercut_left"]
    # material the 8 mm ball can no longer take out of the creases its path dug into
    assert 0 < u["max_mm"] < 1.0 and u["volume_mm3"] > 0 and len(u["at"]) == 3
    # independent of the command's own check: simulate itself on the written file
    assert simulate_gouges(capsys, tmp_path, out, CARPET_STOCK, "ball:8", design, "0.4", "0.002") == []
    # unchanged lines are the original's, byte for byte, in order
    kept = [ln for ln in out.read_bytes().splitlines(keepends=True) if b"(dexmon:" not in ln]
    orig = prog.read_bytes().splitlines(keepends=True)
    it = iter(orig)
    assert all(any(k == o for o in it) for k in kept)


def test_with_linearize_a_gouging_arc_becomes_chords_and_the_next_modal_arc_is_restated(tmp_path, capsys):
    text = ("G21 G90\nG0 Z5\nG0 X-8 Y15\nG1 Z-5 F600\nG1 X10\nG2 X20 Y15 Z-5.5 I5 J-2\nX30 Y15 Z-4 I5 J-2\n"
            "X40 Y15 I5 J-2\nG1 X48\nG0 Z5\nM2\n")
    rc, doc, err, out = correct_program(tmp_path, capsys, text, "--linearize", "0.01")
    assert rc == 0, err
    fixed = out.read_text().splitlines()
    assert "(dexmon: corrected line 6, the arc as chords)" in "\n".join(fixed)
    # line 7 starts where the correction moved line 6's end: chords too; line 8 leaned on
    # the modal G2 the chords replaced, so it says G2 again and is still an arc
    restated = [ln for ln in fixed if "G2 restated" in ln]
    assert len(restated) == 1 and restated[0].startswith("G2 X40 Y15 I5 J-2")
    assert doc["changed_lines"] == [6, 7, 8]
    assert simulate_gouges(capsys, tmp_path, out) == []
    from sim.gcode import MoveKind, load_program

    m = load_program(out).moves
    k = [i for i in range(len(m)) if "G2 restated" in fixed[m["line"][i] - 1]]
    assert k and m["kind"][k[0]] == MoveKind.ARC_CW
    assert [a for a in fixed if "dexmon" not in a] == [a for i, a in enumerate(text.splitlines()) if i not in (5, 6, 7)]


@pytest.mark.parametrize("dip, says", [
    ("/G1 X20 Z-5.3", "block delete"),
    ("G1 X20 Z#1", "expressions"),
    ("G53 G1 X20 Z-5.3", "G53"),
])
def test_a_line_that_cannot_be_rewritten_safely_is_refused_naming_it(tmp_path, capsys, dip, says):
    text = f"G21 G90\n#1 = -5.3\nG0 Z5\nG0 X-8 Y15\nG1 Z-5 F600\n{dip}\nG1 X48 Z-5\nG0 Z5\nM2\n"
    rc, doc, err, out = correct_program(tmp_path, capsys, text)
    assert rc == 2 and f"{tmp_path / 'p.nc'}:6" in err and says in err, err
    assert not out.exists()


def test_refine_corrects_on_denser_rays_so_a_finer_check_finds_no_gouge_either(tmp_path, capsys, shared):
    """The correction sees the design on its rays only: corrected on the 0.4 mm rays, a
    0.2 mm check still finds what lay between them; ``--refine 2`` corrects on 0.2 mm rays."""
    parts = shared / "corpus" / "parts"
    lines = (parts / "carpet1_ball6_finish.ngc").read_text().splitlines(keepends=True)
    prog = tmp_path / "carpet_start.ngc"
    prog.write_text("".join(lines[:1200]) + "G0 Z10.1979\nM5\nM30\n")
    design = parts / "carpet1.stl"
    found = {}
    for refine in ("1", "2"):
        out = tmp_path / f"fixed{refine}.ngc"
        rc, doc, err = run(capsys, prog, "--stock", CARPET_STOCK, "--tool", "ball:8", "--design", design,
                           "--resolution", "0.4", "--refine", refine, "-o", out, "--json")
        assert rc == 0 and doc["verified"]["gouges"] == 0, err
        found[refine] = simulate_gouges(capsys, tmp_path, out, "box:0,-82,-10,10,66,5.197857", "ball:8", design,
                                        "0.2", "0.002")
    assert found["1"] and found["2"] == []


def test_a_canned_cycle_that_gouges_is_refused_naming_its_line_even_with_linearize(tmp_path, capsys):
    text = "G21 G90\nG0 Z5\nG0 X20 Y15\nG81 X20 Y15 Z-6 R1 F100\nG80\nG0 Z5\nM2\n"
    for extra in ((), ("--linearize", "0.01")):
        rc, doc, err, out = correct_program(tmp_path, capsys, text, *extra)
        assert rc == 2 and f"{tmp_path / 'p.nc'}:4" in err and "cycle" in err, err
        assert not out.exists()


def test_the_text_report_says_what_changed_and_what_the_check_found(tmp_path, capsys):
    from monitor.commands.dry_run import EXAMPLE_JOB

    rc = main(["correct", str(EXAMPLE_JOB), "-o", str(tmp_path / "fixed.nc")])
    out = capsys.readouterr().out
    assert rc == 0
    assert "1 lines changed, 0 inserted" in out and "deepest gouge before 0.5000 mm" in out
    assert "check: gouge-free at 0.05 mm" in out and "rapid_into_stock 1" in out
    assert f"wrote {tmp_path / 'fixed.nc'}" in out


def test_a_move_in_a_subroutine_file_that_needs_a_correction_is_refused_naming_that_file(tmp_path, capsys):
    (tmp_path / "dip.ngc").write_text("o<dip> sub\nG1 X20 Z-5.3\nG1 X48 Z-5\no<dip> endsub\nM2\n")
    text = "G21 G90\nG0 Z5\nG0 X-8 Y15\nG1 Z-5 F600\no<dip> call\nG0 Z5\nM2\n"
    rc, doc, err, out = correct_program(tmp_path, capsys, text)
    assert rc == 2 and f"{tmp_path / 'dip.ngc'}:2" in err and "subroutine" in err, err


def test_the_added_length_counts_every_move_the_correction_reshaped_or_restarted(tmp_path, capsys):
    # the dip's two legs (4 mm along X, 0.8 mm down and up) become two level 4 mm moves
    text = "G21 G90\nG0 Z5\nG0 X-8 Y15\nG1 Z-5 F600\nG1 X12\nG1 X16 Z-5.8\nG1 X20 Z-5\nG1 X48\nG0 Z5\nM2\n"
    rc, doc, err, out = correct_program(tmp_path, capsys, text)
    assert rc == 0, err
    assert doc["added_length_mm"] == pytest.approx(8.0 - 2 * math.hypot(4.0, 0.8), abs=1e-3)


def test_a_job_with_a_var_file_that_is_not_there_is_a_clear_error(tmp_path, capsys):
    """correct reads a job's flags as simulate does (simulate.apply_job_flags): a --var
    file that does not exist is named, not read as an empty parameter file."""
    from monitor.commands.dry_run import EXAMPLE_JOB

    missing = tmp_path / "nowhere.var"
    rc, _, err = run(capsys, EXAMPLE_JOB, "-o", tmp_path / "fixed.nc", "--var", missing)
    assert rc == 2 and f"--var {missing}" in err and "no such parameter (.var) file" in err, err
    assert not (tmp_path / "fixed.nc").exists()


def test_a_head_tilted_plunge_is_checked_where_the_head_puts_the_tool(tmp_path, capsys):
    """On a head-head machine the written program is checked with the job's kinematics
    and the tool's G43 length (pivot to tip), as ``simulate`` cuts it: the tilted plunge
    that gouges the design 3.5 mm (line 9) is not reported gouge-free. Checked at the
    gauge point (3-axis, or with the head but without the G43 length) the tool lands
    beside the design and the check found nothing."""
    from tests.monitor.test_rotary_job import _tilted_plunge_job

    job = _tilted_plunge_job(tmp_path, "G0 Z60\n")
    job.write_text(job.read_text() + '[design]\nbox = [20, 0, 0, 40, 20, 18]\n'
                   '[tolerance]\ngouge = 0.05\nundercut = 5\ninterest = 6\n')
    assert main(["simulate", str(job), "--json"]) == 1
    simulated = [f for f in json.loads(capsys.readouterr().out)["findings"] if f["kind"] == "gouge"]
    rc, doc, err = run(capsys, job, "-o", tmp_path / "fixed.nc", "--json")
    assert rc == 1, (err, doc)
    assert doc["verified"]["gouges"] == 1 and doc["verified"]["gouge_lines"] == [f["line"] for f in simulated] == [9]
    assert doc["verified"]["worst_mm"] == pytest.approx(simulated[0]["depth"], abs=1e-4)


TURNED_WHY = "turned by A/B/C: correction works on 3-axis lines only"


def lines_of_file(path: Path) -> list:
    return path.read_bytes().splitlines(keepends=True)


def test_the_rotary_example_keeps_its_turned_lines_as_written_and_names_them(tmp_path, capsys):
    """The bundled 4th-axis job: its line 35 plunges 1 mm into the bar at A225. The
    correction works on 3-axis lines only: every line the A axis turns (A not 0 at either
    end) is left exactly as written and named, so the gouge stays and the check (on the
    bar the A axis turns, as ``simulate`` cuts it) says so: exit status 1. (The 3-axis
    model had reshaped line 35 as if the tool stood upright over the unturned bar.) The
    original's reference cut is placed as the check's: no undercut is made up."""
    job = Path(__file__).resolve().parents[2] / "monitor" / "examples" / "rotary_job" / "job.toml"
    out = tmp_path / "fixed.nc"
    rc, doc, err = run(capsys, job, "-o", out, "--json")
    assert rc == 1, (err, doc)
    assert out.read_bytes() == (job.parent / "engrave.nc").read_bytes()
    assert doc["lines_changed"] == 0 and doc["lines_inserted"] == 0
    left = doc["left_turned"]
    assert left["why"] == TURNED_WHY
    # A0 at both ends: lines 6-9 and the flute at A0 (14-17) are 3-axis lines
    assert 35 in left["lines"] and 10 in left["lines"] and 18 in left["lines"]
    assert not {6, 7, 9, 14, 15, 16, 17} & set(left["lines"]), left
    assert left["count"] == len(left["lines"])
    assert doc["verified"]["gouges"] == 1 and doc["verified"]["gouge_lines"] == [35, 36]
    assert doc["undercut_left"]["max_mm"] == 0.0, doc["undercut_left"]


def test_a_head_tilted_job_keeps_its_turned_lines_and_the_check_still_finds_the_gouge(tmp_path, capsys):
    """A head-head job: lines 6-15 run with the head at B30 (or turn it). The 3-axis model
    sees the tool upright at the gauge point less its G43 length; there line 13 (G1 X30)
    runs 7 mm deep through the design and was reshaped. Turned, every such line is left as
    written and named in the JSON and the text report; the tilted plunge's real gouge
    (line 9) is still reported, exit status 1."""
    from tests.monitor.test_rotary_job import _tilted_plunge_job

    job = _tilted_plunge_job(tmp_path, "G91\nG0 Z15\nG90\nG1 X30 F300\nG0 Z60\nG0 B0\nG0 X5 Y5\n")
    job.write_text(job.read_text() + '[design]\nbox = [20, 0, 0, 40, 20, 18]\n'
                   '[tolerance]\ngouge = 0.05\nundercut = 5\ninterest = 6\n')
    out = tmp_path / "fixed.nc"
    rc, doc, err = run(capsys, job, "-o", out, "--json")
    assert rc == 1, (err, doc)
    assert out.read_bytes() == (tmp_path / "tilt.nc").read_bytes()
    assert doc["left_turned"]["lines"] == [6, 7, 8, 9, 11, 13, 14, 15]
    assert doc["left_turned"]["why"] == TURNED_WHY
    assert doc["verified"]["gouge_lines"] == [9]


def test_the_text_report_names_the_turned_lines_it_left(tmp_path, capsys):
    from tests.monitor.test_rotary_job import _tilted_plunge_job

    job = _tilted_plunge_job(tmp_path, "G0 Z60\n")
    job.write_text(job.read_text() + '[design]\nbox = [20, 0, 0, 40, 20, 18]\n'
                   '[tolerance]\ngouge = 0.05\nundercut = 5\ninterest = 6\n')
    rc = main(["correct", str(job), "-o", str(tmp_path / "fixed.nc")])
    text = capsys.readouterr().out
    assert rc == 1
    assert f"left as written, {TURNED_WHY}: 5 lines [6, 7, 8, 9, 10]" in text, text
    assert "check: STILL GOUGES" in text


def test_a_3axis_correction_names_no_turned_lines(tmp_path, capsys):
    text = "G21 G90\nG0 Z5 A0\nG0 X-8 Y15\nG1 Z-5 F600\nG1 X12\nG1 X16 Z-5.8\nG1 X20 Z-5\nG1 X48\nG0 Z5\nM2\n"
    rc, doc, err, out = correct_program(tmp_path, capsys, text)
    assert rc == 0, err
    assert doc["changed_lines"] == [6] and doc["left_turned"] == {"count": 0, "lines": [], "why": TURNED_WHY}


def test_a_line_turned_after_a_corrected_3axis_line_is_refused_naming_it(tmp_path, capsys):
    """Line 6's end is lifted out of the design; line 7 turns A from there, a move the
    correction may not reshape: refused (exit 2), naming line 7 and why."""
    text = "G21 G90\nG0 Z5\nG0 X-8 Y15\nG1 Z-5 F600\nG1 X12\nG1 X16 Z-5.8\nG1 X20 A10\nG0 Z5\nM2\n"
    rc, doc, err, out = correct_program(tmp_path, capsys, text)
    assert rc == 2 and f"{tmp_path / 'p.nc'}:7" in err and "turned by A/B/C" in err, err
    assert not out.exists()


def test_a_tool_length_change_without_motion_leaves_a_gouge_free_program_unchanged(tmp_path, capsys):
    """``G43.1 Z10`` on a line of its own: the machine stays, the tip is 10 mm lower and the
    table's next row starts there. The correction went on from the old tip: it counted
    the jump as added path (a head job reported ``added_length_mm: 50``) and rewrote line
    4, which omits Z, with a Z word."""
    text = "G21 G90\nG0 Z30\nG43.1 Z10\nG0 X-8 Y15\nG1 Z-4 F600\nG1 X48\nG0 Z5\nG49\nG0 X50\nM2\n"
    rc, doc, err, out = correct_program(tmp_path, capsys, text)
    assert rc == 0, err
    assert doc["lines_changed"] == 0 and doc["added_length_mm"] == 0.0 and doc["largest_shift_mm"] == 0.0
    assert out.read_bytes() == (tmp_path / "p.nc").read_bytes()


def test_an_arc_right_after_a_tool_length_change_is_not_refused(tmp_path, capsys):
    """The arc starts where the table puts it after ``G43.1`` (10 mm lower tip): not a
    start the correction moved."""
    text = "G21 G90\nG0 X-8 Y15 Z30\nG43.1 Z10\nG2 X-8 Y15 Z20 I-2 J0 F600\nG0 Z5\nM2\n"
    rc, doc, err, out = correct_program(tmp_path, capsys, text)
    assert rc == 0, err
    assert doc["lines_changed"] == 0 and doc["added_length_mm"] == 0.0
    assert out.read_bytes() == (tmp_path / "p.nc").read_bytes()


def test_the_head_job_reports_no_added_length_for_its_tool_length_change(tmp_path, capsys):
    """The head job's ``G43.1 Z50`` has no motion: the 50 mm the tip drops there is no
    path the correction added."""
    from tests.monitor.test_rotary_job import _tilted_plunge_job

    job = _tilted_plunge_job(tmp_path, "G0 Z60\n")
    job.write_text(job.read_text() + '[design]\nbox = [20, 0, 0, 40, 20, 18]\n'
                   '[tolerance]\ngouge = 0.05\nundercut = 5\ninterest = 6\n')
    rc, doc, err = run(capsys, job, "-o", tmp_path / "fixed.nc", "--json")
    assert rc == 1, err
    assert doc["added_length_mm"] == 0.0 and doc["lines_changed"] == 0
