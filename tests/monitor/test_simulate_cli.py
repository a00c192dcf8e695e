"""``dexmon simulate`` through ``main(argv)``: results, output files and one-line errors."""

from __future__ import annotations

import json
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
    assert doc["first_rapid_skipped"] and doc["removed_by_rapids_mm3"] == 0
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
    rc, out, err = run(capsys, EXAMPLE, "--stock", STOCK, "--tool", "flat:6", "--resolution", 1)
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
