"""The bulk path for simple lines gives exactly the rows and states of the per-line path."""

from __future__ import annotations

import numpy as np
import pytest

from sim.gcode import GCodeError, interpret, load_program
from sim.gcode.fastpath import FastLines, split_lines


def _same(a, b):
    assert a.moves.tobytes() == b.moves.tobytes()
    n = max(int(a.moves["line"].max(initial=0)), 1)
    for line in range(0, n + 2):
        sa, sb = a.state_at(line), b.state_at(line)
        assert (sa.motion, sa.feed, sa.units, sa.tool) == (sb.motion, sb.feed, sb.units, sb.tool)
        assert np.array_equal(sa.position, sb.position)


PROGRAMS = [
    "G21 G90\nG0 X0 Y0 Z5\nG1 Z-1 F300\n" + "\n".join(f"X{i * 0.1:.4f} Y{(i % 7) * 0.37:.3f}" for i in range(200)) + "\nM2",
    "G20\nG10 L2 P1 X1.5 Y-2\nG92 Z3\nF12\n" + "\n".join(f"G1 X{i / 3:.6f} Z-.{i % 9}" for i in range(100)) + "\nG0 Z1\nM30",
    "G21\n" + "\n".join(f"N{i} G0{i % 2} X{i}. Y-{i}.25 F{100 + i}" for i in range(1, 60)) + "\nM2",
    "G21 F100\r\n" + "\r\n".join(f"x{i}.5 y{i}" for i in range(40)) + "\r\n",
]


@pytest.mark.parametrize("text", PROGRAMS)
@pytest.mark.parametrize("dialect", ["linuxcnc", "grbl"])
def test_fast_equals_slow(text, dialect):
    _same(interpret(text, dialect=dialect, fast=True), interpret(text, dialect=dialect, fast=False))


def test_fast_path_refuses_and_reports_like_slow():
    text = "G21\n" + "\n".join(f"G1 X{i}" for i in range(20)) + "\nM2"
    with pytest.raises(GCodeError) as fast:
        interpret(text, fast=True)
    with pytest.raises(GCodeError) as slow:
        interpret(text, fast=False)
    assert str(fast.value) == str(slow.value) and fast.value.line == 2


def test_scanner_marks_only_simple_lines():
    text = "X1 Y2\nG1 X1.5\nG2 X1\nX1 (c)\nX[1]\nN10\nX1 X2\nx-.5z+3.\nN5 G0 F10\nX1e3\nX 1\n"
    lines, data = split_lines(text)
    fl = FastLines(lines, data)
    assert fl.simple.tolist() == [True, True, False, False, False, False, False, True, True, False, False]
    assert fl.values[7, 1] == -0.5 and fl.values[7, 3] == 3.0
    # the same decision without the numba scanner
    fl2 = FastLines(text.splitlines())
    assert fl2.simple[:3].tolist() == [True, True, False]


def test_float_parsing_is_exact():
    nums = ["0.1", "1.0000001", "-123.456789", ".3", "7.", "99999.99999", "0.000001", "1234567890.123456"]
    text = "\n".join(f"X{v}" for v in nums)
    lines, data = split_lines(text)
    fl = FastLines(lines, data)
    assert fl.values[:, 1].tolist() == [float(v) for v in nums]


def test_corpus_fast_equals_slow(shared):
    c = shared / "corpus" / "gcode"
    for name in ("camotics_flower_mold.nc", "cncjs_jsdc_jscut.gcode", "linuxcnc_arcspiral.ngc"):
        kw = dict(tool_table=c / "tooltables" / "default.tbl", machine_units="inch")
        _same(load_program(c / name, fast=True, **kw), load_program(c / name, fast=False, **kw))
