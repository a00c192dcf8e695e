"""``dexmon simulate`` through ``main(argv)``: results, output files and one-line errors."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from monitor.cli import main

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "monitor" / "examples" / "pocket.nc"
STOCK = "box:0,0,0,60,40,20"


def run(capsys, *argv):
    rc = main(["simulate", *map(str, argv)])
    out, err = capsys.readouterr()
    return rc, out, err


def test_example_json_and_heights(capsys, tmp_path):
    heights = tmp_path / "h.npy"
    rc, out, err = run(capsys, EXAMPLE, "--stock", STOCK, "--tool", "flat:6", "--resolution", 0.5,
                       "--heights", heights, "--json")
    assert rc == 0, err
    doc = json.loads(out)
    assert doc["moves"] > 40 and doc["cutting_moves"] > 20
    assert doc["removed_mm3"] > 0 and doc["seconds"] >= 0
    assert doc["remaining_mm3"] == pytest.approx(doc["stock_mm3"] - doc["removed_mm3"], abs=0.01)
    # from the start position: 10 mm above the stock and the program's highest point (Z25),
    # over its first point (G0 Z25: X0 Y0)
    assert doc["start"] == [0.0, 0.0, 35.0] and doc["removed_by_rapids_mm3"] == 0
    h = np.load(heights)
    assert h.dtype == np.float32 and h.shape == (81, 121)  # (ny, nx), both ends included

    def at(x, y):
        return h[int(round(y / 0.5)), int(round(x / 0.5))]

    assert at(20, 20) == 15.0   # pocket floor
    assert at(30, 20) == 10.0   # helical bore
    assert at(1, 20) == 17.0    # outside contour, 3 mm deep
    assert at(58, 20) == 17.0
    assert at(5, 20) == 20.0    # untouched between contour and pocket


def test_text_output(capsys):
    rc, out, err = run(capsys, EXAMPLE, "--stock", STOCK, "--tool", "flat:6:L=20", "--resolution", 1)
    assert rc == 0 and err == ""
    assert "moves" in out and "removed" in out and "mm^3" in out


def test_heights_nan_where_no_material_is_left(capsys, tmp_path):
    prog = tmp_path / "through.nc"
    prog.write_text("G21 G90\nM3 S10000\nG0 X10 Y10 Z30\nG1 Z-1 F100\nG0 Z30\nM2\n")
    heights = tmp_path / "h.npy"
    rc, out, err = run(capsys, prog, "--stock", "box:0,0,0,20,20,5", "--tool", "flat:4",
                       "--resolution", 0.5, "--heights", heights)
    assert rc == 0, err
    h = np.load(heights)
    assert np.isnan(h[20, 20]) and h[0, 0] == 5.0


def test_stl_output(capsys, tmp_path):
    stl = tmp_path / "cut.stl"
    rc, out, err = run(capsys, EXAMPLE, "--stock", STOCK, "--tool", "flat:6", "--resolution", 1,
                       "--stl", stl, "--json")
    assert rc == 0, err
    assert json.loads(out)["stl"] == str(stl)
    assert stl.stat().st_size > 1000


def test_tool_table_gives_the_tool(capsys, data):
    rc, out, err = run(capsys, EXAMPLE, "--stock", STOCK, "--tool-table", data / "tools_mm.tbl",
                       "--resolution", 1, "--json")
    assert rc == 0, err
    via_table = json.loads(out)
    rc, out, _ = run(capsys, EXAMPLE, "--stock", STOCK, "--tool", "flat:6", "--resolution", 1, "--json")
    assert via_table["removed_mm3"] == pytest.approx(json.loads(out)["removed_mm3"])


def _open_mesh(path: Path) -> Path:
    import trimesh

    trimesh.Trimesh(vertices=[[0, 0, 0], [10, 0, 0], [0, 10, 5]], faces=[[0, 1, 2]]).export(str(path))
    return path


@pytest.mark.parametrize("argv, fragment", [
    (["--tool", "cone:6"], "unknown tool spec"),
    (["--tool", "flat:6", "--resolution", "0"], "resolution"),
    (["--tool", "flat:6", "--resolution", "-1"], "resolution"),
    (["--tool", "flat:6", "--resolution", "0.0005"], "MB"),
    (["--tool", "flat:6", "--stock", "box:0,0,0,60,40"], "X0,Y0,Z0,X1,Y1,Z1"),
    (["--tool", "flat:6", "--stock", "box:0,0,20,60,40,0"], "greater"),
    ([], "--tool"),
])
def test_bad_input_is_one_line_and_exit_2(capsys, argv, fragment):
    if "--stock" not in argv:
        argv = ["--stock", STOCK, *argv]
    rc, out, err = run(capsys, EXAMPLE, *argv)
    assert rc == 2
    assert fragment in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_grid_too_large_names_estimate_and_limit(capsys):
    rc, out, err = run(capsys, EXAMPLE, "--stock", STOCK, "--tool", "flat:6", "--resolution", 0.01,
                       "--memory-limit", 10)
    assert rc == 2 and "about 595 MB" in err and "10 MB limit" in err


def test_empty_program(capsys, tmp_path):
    prog = tmp_path / "empty.nc"
    prog.write_text("(nothing here)\nG21 G90\nM2\n")
    rc, out, err = run(capsys, prog, "--stock", STOCK, "--tool", "flat:6")
    assert rc == 2 and "no motion" in err and "empty.nc" in err


def test_missing_program_and_open_mesh_stock(capsys, tmp_path):
    rc, out, err = run(capsys, tmp_path / "nope.nc", "--stock", STOCK, "--tool", "flat:6")
    assert rc == 2 and "nope.nc" in err and "Traceback" not in err
    mesh = _open_mesh(tmp_path / "open.stl")
    rc, out, err = run(capsys, EXAMPLE, "--stock", mesh, "--tool", "flat:6", "--resolution", 1)
    assert rc == 2 and "open.stl" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


# --- checks through the command line ----------------------------------------------------

CARPET_STOCK = "box:0,-82,-10,152,66,5.197857"


@pytest.mark.parametrize("tool,gouges", [("ball:8", True), ("ball:6", False)])
def test_carpet_finishing_path_gouges_with_an_8mm_ball_only(capsys, shared, tool, gouges):
    parts = shared / "corpus" / "parts"
    rc, out, err = run(capsys, parts / "carpet1_ball6_finish.ngc", "--stock", CARPET_STOCK, "--tool", tool,
                       "--resolution", 0.5, "--design", parts / "carpet1.stl", "--tolerance", 0.002, "--json")
    doc = json.loads(out)
    found = [f for f in doc["findings"] if f["kind"] == "gouge"]
    if gouges:
        assert rc == 1, err
        assert len(found) >= 1
        worst = max(found, key=lambda f: f["depth"])
        assert worst["depth"] == pytest.approx(0.34, abs=0.02)
        assert worst["line"] > 0 and len(worst["position"]) == 3 and worst["volume"] > 0
    else:
        assert found == []
    # what a 6 mm ball cannot reach is undercut (README: expected), never a collision
    assert {f["kind"] for f in doc["findings"]} <= {"gouge", "undercut"}


JOB = ROOT / "monitor" / "examples" / "clamp_job" / "job.toml"


def test_job_file_finds_both_planted_faults(capsys):
    rc, out, err = run(capsys, JOB, "--json")
    assert rc == 1, err
    doc = json.loads(out)
    assert doc["job"] == str(JOB) and doc["resolution"] == 0.25
    by_kind = {f["kind"]: f for f in doc["findings"]}
    assert by_kind["gouge"]["line"] == 22 and by_kind["gouge"]["depth"] == pytest.approx(0.5, abs=0.01)
    assert by_kind["rapid_into_stock"]["line"] == 36
    assert all(math.isfinite(v) for f in doc["findings"] for v in f["position"])


def test_job_file_text_table_and_flag_overrides(capsys):
    rc, out, err = run(capsys, JOB, "--resolution", 0.5, "--no-checks")
    assert rc == 0 and "finding" not in out
    rc, out, err = run(capsys, JOB, "--resolution", 0.5)
    assert rc == 1
    assert "gouge" in out and "rapid_into_stock" in out and "line" in out.splitlines()[3]


def test_clean_program_exits_0_and_says_so(capsys, tmp_path):
    prog = tmp_path / "clean.nc"
    prog.write_text("G21 G90\nM3 S10000\nG0 X10 Y10 Z8\nG1 Z4 F100\nG1 X20\nG0 Z8\nM5\nM2\n")
    rc, out, err = run(capsys, prog, "--stock", "box:0,0,0,30,20,5", "--tool", "flat:4", "--resolution", 0.5)
    assert rc == 0, out + err
    assert "no findings" in out


def test_bad_job_file_is_one_line_exit_2(capsys, tmp_path):
    job = tmp_path / "bad.toml"
    job.write_text("[stock]\nbox = [0, 0, 0]\n")
    rc, out, err = run(capsys, job)
    assert rc == 2 and "bad.toml" in err and "Traceback" not in err


def test_rapid_into_stock_is_placed_where_the_rapid_enters_material(capsys):
    rc, out, err = run(capsys, JOB, "--json")
    rapid = next(f for f in json.loads(out)["findings"] if f["kind"] == "rapid_into_stock")
    x, y, z = rapid["position"]
    # line 36: G0 from X-8 to X68 at Y1 Z-10 through the stock (X 0..60): it enters at X 0
    assert x == pytest.approx(0.0, abs=0.3) and y == pytest.approx(1.0, abs=0.3)
    assert -10 < z <= 0


# --- QA 4: the interpreter's options, as `moves` has them -------------------------------------

def test_var_file_places_each_fixture_at_its_work_offset(capsys, tmp_path):
    # G55 and G56 come only from the .var file (X of G55 = param 5241, of G56 = 5261)
    prog = tmp_path / "two_stations.ngc"
    prog.write_text("G21 G90\nM3 S10000\n"
                    "G55 G0 X0 Y10 Z8\nG1 Z3 F100\nG0 Z8\n"
                    "G56 G0 X0 Y10 Z8\nG1 Z3 F100\nG0 Z8\nM2\n")
    var = tmp_path / "sim.var"
    # in inches (--machine-units inch): 0.393701 in = 10 mm, 1.181102 in = 30 mm
    var.write_text("5241\t0.393701\n5242\t0.000000\n5243\t0.000000\n"
                   "5261\t1.181102\n5262\t0.000000\n5263\t0.000000\n")
    heights = tmp_path / "h.npy"
    rc, out, err = run(capsys, prog, "--stock", "box:0,0,0,40,20,5", "--tool", "flat:4", "--resolution", 0.5,
                       "--var", var, "--machine-units", "inch", "--heights", heights, "--no-checks")
    assert rc == 0, err
    h = np.load(heights)
    assert h[20, 20] == 3.0 and h[20, 60] == 3.0   # holes at X10 (G55) and X30 (G56)
    assert h[20, 0] == 5.0 and h[20, 40] == 5.0     # G54 (X0) untouched, between stations untouched
    # without the .var file both stations are at offset 0
    rc, out, err = run(capsys, prog, "--stock", "box:0,0,0,40,20,5", "--tool", "flat:4", "--resolution", 0.5,
                       "--heights", heights, "--no-checks")
    h = np.load(heights)
    assert h[20, 0] == 3.0 and h[20, 20] == 5.0


def test_missing_var_file_and_subroutine_dir_are_one_line_errors(capsys, tmp_path):
    rc, out, err = run(capsys, EXAMPLE, "--stock", STOCK, "--tool", "flat:6", "--var", tmp_path / "no.var")
    assert rc == 2 and "no.var" in err and len(err.strip().splitlines()) == 1
    rc, out, err = run(capsys, EXAMPLE, "--stock", STOCK, "--tool", "flat:6", "--subroutine-path",
                       tmp_path / "nodir")
    assert rc == 2 and "nodir" in err and len(err.strip().splitlines()) == 1


def test_subroutine_path_finds_called_files(capsys, tmp_path):
    lib = tmp_path / "lib"
    lib.mkdir()
    (lib / "spot.ngc").write_text("o<spot> sub\nG0 X#1 Y10 Z8\nG1 Z3 F100\nG0 Z8\no<spot> endsub\nM2\n")
    prog = tmp_path / "main.ngc"
    prog.write_text("G21 G90\nM3 S10000\no<spot> call [10]\nM2\n")
    heights = tmp_path / "h.npy"
    rc, out, err = run(capsys, prog, "--stock", "box:0,0,0,40,20,5", "--tool", "flat:4", "--resolution", 0.5,
                       "--subroutine-path", lib, "--heights", heights, "--no-checks")
    assert rc == 0, err
    assert np.load(heights)[20, 20] == 3.0


def test_tool_table_units_is_an_alias_of_machine_units(capsys, data):
    base = [EXAMPLE, "--stock", STOCK, "--tool-table", data / "tools_mm.tbl", "--resolution", 1, "--json"]
    rc, out, err = run(capsys, *base, "--tool-table-units", "mm")
    rc2, out2, _ = run(capsys, *base, "--machine-units", "mm")
    assert rc == rc2 == 0 and json.loads(out)["removed_mm3"] == json.loads(out2)["removed_mm3"]
    rc, out, err = run(capsys, *base, "--machine-units", "mm", "--tool-table-units", "inch")
    assert rc == 2 and "--machine-units" in err


# --- QA 5: undercut within the range of interest, scallop-sized t_h, worst point ------------

def test_job_stock_margin_around_the_design_is_not_an_undercut(capsys):
    rc, out, err = run(capsys, JOB, "--json")
    kinds = sorted(f["kind"] for f in json.loads(out)["findings"])
    assert kinds == ["gouge", "rapid_into_stock"]


def test_sphere_finishing_pass_leaves_undercut_only_in_the_dome_corner(capsys, shared):
    parts = shared / "corpus" / "parts"
    rc, out, err = run(capsys, parts / "sphere_on_plate_ball6_finish.ngc", "--stock",
                       "box:0,0,-1,76.4923,76.4923,30.8718", "--tool", "ball:6", "--resolution", 0.25,
                       "--design", parts / "sphere_on_plate.stl", "--tolerance", 0.002, "--json")
    doc = json.loads(out)
    assert not [f for f in doc["findings"] if f["kind"] != "undercut"]
    und = doc["findings"]
    assert und  # the 6 mm ball cannot enter the concave corner where the dome meets the block
    big = max(und, key=lambda f: f["volume"])
    x, y, z = big["position"]  # the worst point of the region, not a corner of it
    assert abs(math.hypot(x - 38.2461, y - 38.2461) - 19.10) < 3.0 and 14.93 < z < 14.94 + 3.0
    assert 0.5 < big["depth"] <= 1.0 and big["lines"][-1] - big["lines"][0] < 20000
    for f in und:
        # the rest are scallop crests on the steep dome flanks, where the raster's stepover
        # measured along the surface grows: just over t_h, a few rays each
        if f is not big:
            assert f["depth"] < 0.06 and f["detail"]["rays"] < 30


# --- QA 8: the stock's true volume --------------------------------------------------------

def test_box_stock_volume_is_exact_and_removal_is_trapezoid_weighted(capsys, tmp_path):
    rc, out, err = run(capsys, JOB, "--json", "--no-checks")
    assert json.loads(out)["stock_mm3"] == pytest.approx(48000.0)
    rc, out, err = run(capsys, JOB, "--no-checks")
    assert "of 48000.000 mm^3 stock" in out
    # a 2 mm deep full-width facing pass (flat:6 past every edge) removes 60 x 40 x 2
    prog = tmp_path / "face.nc"
    rows = "".join(f"G0 Y{y}\nG1 Z18\nG1 X68\nG0 Z25\nG0 X-8\n" for y in range(-2, 44, 4))
    prog.write_text("G21 G90\nM3 S10000 F500\nG0 X-8 Y-2 Z25\n" + rows + "M2\n")
    rc, out, err = run(capsys, prog, "--stock", "box:0,0,0,60,40,20", "--tool", "flat:6", "--resolution", 0.5,
                       "--json", "--no-checks")
    doc = json.loads(out)
    assert doc["stock_mm3"] == pytest.approx(48000.0)
    assert doc["removed_mm3"] == pytest.approx(4800.0, abs=1e-3)
    assert doc["remaining_mm3"] == pytest.approx(43200.0, abs=1e-3)


# --- QA 6: many hits of one kind, the assumed flute length -----------------------------------

def test_flute_length_note_when_not_given(capsys):
    rc, out, err = run(capsys, EXAMPLE, "--stock", STOCK, "--tool", "ball:3.175", "--resolution", 1)
    assert err.strip() == "note: flute length not given for --tool ball:3.175: assumed 4xD = 12.7 mm (give it as :L=)"
    rc, out, err = run(capsys, EXAMPLE, "--stock", STOCK, "--tool", "ball:3.175", "--resolution", 1, "--json")
    assert json.loads(out)["notes"] == ["flute length not given for --tool ball:3.175: assumed 4xD = 12.7 mm "
                                        "(give it as :L=)"]
    rc, out, err = run(capsys, EXAMPLE, "--stock", STOCK, "--tool", "ball:3.175:L=30", "--resolution", 1, "--json")
    assert json.loads(out)["notes"] == []


def test_a_raster_rubbing_one_feature_is_one_finding(capsys, tmp_path):
    # a 3 mm ball with 5 mm of flute rasters 8 mm deep along X, 1 mm stepover: every pass
    # rubs the stock above its flutes (without grouping: one finding per pass)
    prog = tmp_path / "deep.nc"
    rows = "".join(f"G0 X-5 Y{y}\nG1 Z12\nG1 X65\nG0 Z25\n" for y in np.arange(2, 38, 1.0))
    prog.write_text("G21 G90\nM3 S10000 F500\nG0 Z25\n" + rows + "M2\n")
    rc, out, err = run(capsys, prog, "--stock", "box:0,0,0,60,40,20", "--tool", "ball:3:L=5", "--resolution", 0.5,
                       "--json")
    doc = json.loads(out)
    above = [f for f in doc["findings"] if f["kind"] == "above_flute_contact"]
    assert len(above) == 1, [f["lines"][:3] for f in above]   # 36 passes over one place
    assert above[0]["detail"]["hits"] >= 30 and above[0]["lines"][0] == 6  # the first pass


def test_many_findings_of_a_kind_are_summarised_in_text(capsys, tmp_path):
    from monitor.commands.simulate import findings_table
    from sim.checks.findings import Finding

    fs = [Finding("shank_contact", line=10 * k, stage=k, position=(k, 0, 0), volume=float(k)) for k in range(1, 9)]
    text = findings_table(fs)
    assert "shank_contact: 8 findings on lines 10-80, worst at line 80" in text
    body = [ln for ln in text.splitlines() if ln.startswith("shank_contact ")]
    assert len(body) == 5 and all("8.0 mm^3" in text for _ in body)


def test_table_rows_do_not_repeat_their_columns(capsys):
    rc, out, err = run(capsys, JOB)
    row = next(ln for ln in out.splitlines() if ln.startswith("gouge"))
    assert row.count("30.000") == 1 and row.count("22-23") == 1 and "cut into the part" in row


# --- QA 7: open design surfaces -----------------------------------------------------------

def _box_missing_faces(path: Path) -> Path:
    import trimesh

    m = trimesh.creation.box(bounds=[(10, 10, 0), (50, 30, 15)])
    keep = np.abs(m.face_normals[:, 0]) < 0.5  # drop the two X faces: open, top and bottom both there
    trimesh.Trimesh(m.vertices, m.faces[keep]).export(str(path))
    return path


def test_open_design_that_is_not_a_height_field_is_refused(capsys, tmp_path):
    hole = _box_missing_faces(tmp_path / "hole.stl")
    rc, out, err = run(capsys, EXAMPLE, "--stock", STOCK, "--tool", "flat:6", "--resolution", 1, "--design", hole)
    assert rc == 2 and "hole.stl" in err and "height field" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    # as a stock: refused in words a CLI user can act on
    rc, out, err = run(capsys, EXAMPLE, "--stock", hole, "--tool", "flat:6", "--resolution", 1)
    assert rc == 2 and "not watertight" in err and "heightfield_grid" not in err


def test_open_height_field_design_is_taken_with_a_note(capsys, tmp_path):
    import trimesh

    sheet = tmp_path / "sheet.stl"
    trimesh.Trimesh([[-1, -1, 15], [61, -1, 15], [61, 41, 15], [-1, 41, 15]], [[0, 1, 2], [0, 2, 3]]).export(str(sheet))
    rc, out, err = run(capsys, EXAMPLE, "--stock", STOCK, "--tool", "flat:6:L=20", "--resolution", 1,
                       "--design", sheet, "--json")
    doc = json.loads(out)
    assert any("open surface" in n and "sheet.stl" in n for n in doc["notes"])
    # the pocket floor at 15 is on the sheet, the bore to 10 goes 5 mm below it
    g = [f for f in doc["findings"] if f["kind"] == "gouge"]
    assert g and max(f["depth"] for f in g) == pytest.approx(5.0, abs=0.01)
