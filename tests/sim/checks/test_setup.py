"""Wrong setups are never "clean": a path that misses the stock, a design outside it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sim.checks.setup import cutting_boxes, material_box, setup_findings
from sim.gcode import interpret

SLOT = "G21 G90\nG0 Z5\nG0 X0 Y10\nM3 S10000\nG1 Z-2 F200\nG1 X60 F600\nG0 Z5\nM2\n"


def boxes(stock=((-5, 0, -20), (65, 40, 0))):
    return tuple(np.asarray(v, float) for v in stock)


def test_a_path_that_cuts_the_stock_is_no_setup_finding():
    assert setup_findings(interpret(SLOT).moves, boxes(), 3.0) == []


def test_a_path_beside_the_stock_is_a_setup_finding():
    moves = interpret(SLOT.replace("Y10", "Y100")).moves
    (f,) = setup_findings(moves, boxes(), 3.0)
    assert f.kind == "setup" and f.detail["check"] == "path_misses_stock" and f.line == 5
    assert "never reach the stock" in f.message and "work offset" in f.message


def test_the_tool_radius_counts():
    moves = interpret(SLOT.replace("Y10", "Y42")).moves   # 2 mm beyond the stock's edge
    assert setup_findings(moves, boxes(), 3.0) == []
    assert len(setup_findings(moves, boxes(), 1.0)) == 1


def test_an_inch_program_against_a_mm_stock_names_the_units():
    inch = "G20 G90\nG0 Z0.2\nG0 X0 Y0.4\nM3 S10000\nG1 Z-0.08 F8\nG1 X2.4 F24\nG0 Z0.2\nM2\n"
    stock = ((300, 300, -20), (400, 400, 0))
    program = interpret(inch)
    (f,) = setup_findings(program.moves, boxes(stock), 3.0, inch=program.inch)
    assert program.inch and "inches (G20)" in f.message


def test_a_missing_g20_is_suspected():
    mm_meant_inch = "G90\nG0 Z0.2\nG0 X0 Y0.4\nM3 S10000\nG1 Z-0.08 F8\nG1 X2.4 F24\nG0 Z0.2\nM2\n"
    stock = ((-5, 0, -20), (65, 40, 0))
    # at 0.4 mm the tip is inside the stock box: not a setup finding
    assert setup_findings(interpret(mm_meant_inch).moves, boxes(stock), 0.5) == []
    far = mm_meant_inch.replace("Y0.4", "Y1.0").replace("X0 ", "X1.0 ")
    stock = ((20, 20, -20), (70, 40, 0))
    (f,) = setup_findings(interpret(far).moves, boxes(stock), 0.5)
    assert "G20 missing" in f.message


def test_arcs_count_with_their_whole_circle():
    arc = "G21 G90\nG0 X-10 Y20 Z5\nG1 Z-1 F100\nG2 X-10 Y20 I40 J0 F300\nG0 Z5\nM2\n"
    rows, lo, hi = cutting_boxes(interpret(arc).moves, 0.0)
    assert hi[1][0] == pytest.approx(70.0)
    assert setup_findings(interpret(arc).moves, boxes(((60, 15, -5), (75, 25, 0))), 0.0) == []


def test_a_design_outside_the_stock_is_a_setup_finding():
    moves = interpret(SLOT).moves
    (f,) = setup_findings(moves, boxes(), 3.0, design_box=(np.array([100, 100, -10]), np.array([150, 150, 0])))
    assert f.detail["check"] == "design_outside_stock" and "design" in f.message


def test_material_box_of_a_grid():
    from monitor.commands.simulate import build_stock

    grid = build_stock("box:0,0,-10,30,20,0", 0.5, 4096)
    lo, hi = material_box(grid)
    assert lo[:2] == pytest.approx([0, 0]) and hi == pytest.approx([30, 20, 0]) and lo[2] == -np.inf


def test_simulate_reports_a_stock_the_path_never_touches(tmp_path, capsys):
    from monitor.cli import main

    prog = tmp_path / "slot.nc"
    prog.write_text(SLOT.replace("Y10", "Y100"))
    code = main(["simulate", str(prog), "--stock", "box:-5,0,-20,65,40,0", "--tool", "flat:6:L=20", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 1 and [f["kind"] for f in out["findings"]] == ["setup"]
    prog.write_text(SLOT)
    assert main(["simulate", str(prog), "--stock", "box:-5,0,-20,65,40,0", "--tool", "flat:6:L=20", "--json"]) == 0


def test_a_long_tool_that_cuts_the_stock_is_no_setup_finding():
    # G43 moves the controlled point up by the tool length: the tip at Z-2 cuts the stock
    # (0..-20) whatever the length; the controlled point (Z98) is not what meets it
    long_tool = SLOT.replace("G0 Z5\n", "G43.1 Z100\nG0 Z5\n", 1)
    moves = interpret(long_tool).moves
    assert moves["tool_length"].max() == 100.0
    assert setup_findings(moves, boxes(), 3.0) == []
    (f,) = setup_findings(interpret(long_tool.replace("Y10", "Y100")).moves, boxes(), 3.0)
    assert "Z-2..5" in f.message and f.position == (0.0, 100.0, -2.0)   # the tip's


def test_the_span_holds_the_moves_starts_and_an_arcs_bulge():
    # a CCW half circle about (10, 20) from (10, 10) to (10, 30) bulges out to X20; the
    # stock is far away
    lim = "G21 G90 G17\nG0 X10 Y10 Z-5\nG3 X10 Y30 I0 J10 F500\nG0 Z0\nM2\n"
    (f,) = setup_findings(interpret(lim).moves, boxes(((100, 100, -20), (200, 200, 0))), 3.0)
    assert "they span X10..20 Y10..30 Z-5..-5 mm" in f.message
    rows, lo, hi = cutting_boxes(interpret(lim).moves, 0.0)
    assert lo[0] == pytest.approx([10, 10, -5]) and hi[0][:2] == pytest.approx([20, 30])
