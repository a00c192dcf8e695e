"""The bulk path for simple lines gives exactly the rows and states of the per-line path."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.gcode import GCodeError, fastpath, interpret, load_program
from sim.gcode.fastpath import scan, split_lines


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


def _scan_all(text):
    lines = split_lines(text)
    return scan(lines, 0, len(lines))


def test_scanner_marks_only_simple_lines():
    text = ("X1 Y2\nG1 X1.5\nG2 X1\nX1 (c)\nX[1]\nN10\nX1 X2\nx-.5z+3.\nN5 G0 F10\nX1e3\nX 1\n"
            "G1X2Y3\nX1-2\nX1.2.3\nX-\nX.\nG0.5 X1\nN-3 X1\nN2.5 X1\n\t G00\tX+0 \nX1 \u00e9\nX123456789012345678\n")
    simple, values = _scan_all(text)
    assert simple.tolist() == [True, True, False, False, False, False, False, True, True, False, False,
                               True, False, False, False, False, False, False, False, True, False, False]
    assert values[7, 1] == -0.5 and values[7, 3] == 3.0
    assert values[11, :3].tolist() == [1.0, 2.0, 3.0] and np.isnan(values[11, 3:]).all()
    assert np.isnan(values[2]).all()  # not simple: nothing kept


def test_float_parsing_is_exact():
    nums = ["0.1", "1.0000001", "-123.456789", ".3", "7.", "99999.99999", "0.000001", "1234567890.123456",
            "-0", "+2.5", "9007199254740992", "0.300000000000004"]
    simple, values = _scan_all("\n".join(f"X{v}" for v in nums))
    assert simple.all()
    assert values[:, 1].tolist() == [float(v) for v in nums]
    assert math.copysign(1.0, values[8, 1]) == -1.0  # -0 stays -0.0, like float("-0")
    # beyond 2**53 digits the line is left to the per-line parser
    assert not _scan_all("X9007199254740993")[0][0] and not _scan_all("X0.30000000000000004")[0][0]


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(st.sampled_from("GXYZFNgxyzfnAI ;(.+-"), st.from_regex(r"[+-]?[0-9]{0,9}\.?[0-9]{0,9}",
                                                                                  fullmatch=True)),
                max_size=6))
def test_scanner_is_sound(words):
    """Whatever the scanner calls simple, the regular expression of a simple line accepts,
    with float() of its numbers."""
    line = " ".join(a + b for a, b in words)
    simple, values = _scan_all(line + "\n")
    if not simple[0]:
        return
    found = {}
    for a, b in words:
        if a == " " and b == "":
            continue  # a blank word is only white space, which a simple line may hold
        assert a.upper() in "GXYZFN" and a.upper() not in found
        found[a.upper()] = float(b)
    assert set(found) - {"N"}
    for k, letter in enumerate("GXYZF"):
        got = values[0, k]
        assert (np.isnan(got) and letter not in found) or got == found[letter]
    assert found.get("G", 0.0) in (0.0, 1.0)


def test_source_lines_like_splitlines():
    for text in ["a\nb\r\nc", "a\n\nb\n", "", "\n", "x\ry\n", "a\x0bb\u2028c\nd", "caf\u00e9\nX1\n"]:
        lines = split_lines(text)
        assert list(lines) == text.splitlines() and len(lines) == len(text.splitlines())
    raw = "G0 X1 (\u00e9)\r\nX2\r\n".encode()
    assert list(split_lines(raw)) == raw.decode().splitlines()
    assert list(split_lines(b"X1\xff\nX2")) == ["X1\ufffd", "X2"]


def test_chunks_loops_percent_offsets_and_carry(monkeypatch):
    """Runs split at chunk boundaries, o-word loops over simple lines, '%' programs, G20,
    work offsets and axes carried through many lines give the per-line rows exactly."""
    monkeypatch.setattr(fastpath, "CHUNK", 37)
    body = "\n".join(f"X{i * 0.013:.4f}" + (f" Y{-i / 7:.5f}" if i % 5 == 0 else "") for i in range(300))
    text = ("%\nG20 G10 L2 P1 X1.1 Y-2.3 Z0.7 A0.1\nG92 Z0.3\nG1 Z-0.1 F20\n" + body +
            "\n#1 = 0\no100 while [#1 lt 3]\n" + "\n".join(f"G1 X{k}.25 Y0.1" for k in range(12)) +
            "\n#1 = [#1 + 1]\no100 endwhile\nG0 Z1\n%\nG0 X99\n")
    fast, slow = interpret(text, fast=True), interpret(text, fast=False)
    _same(fast, slow)
    assert len(fast.moves) == 1 + 300 + 36 + 1
    assert fast.moves["line"][-1] == text.splitlines().index("G0 Z1") + 1  # the second '%' ends it


def test_memory_stays_one_copy_of_the_text():
    """The source is kept as its bytes (no str per line, no parsed block per executed line)."""
    text = "G21 F100\n" + "\n".join(f"G1 X{i % 50}.5 Y{i % 7} (c)" for i in range(3000)) + "\nM2\n"
    prog_runner_lines = split_lines(text)
    assert isinstance(prog_runner_lines.data, bytes) and prog_runner_lines.starts.dtype == np.int32
    from sim.gcode.program import _prepare

    src = _prepare("<t>", 0, text, "linuxcnc")
    for i in range(len(src.lines)):
        src.block(i, "linuxcnc")
    assert src.blocks == {}  # straight-line programs keep no parsed blocks


def test_corpus_fast_equals_slow(shared):
    c = shared / "corpus" / "gcode"
    for name in ("camotics_flower_mold.nc", "cncjs_jsdc_jscut.gcode", "linuxcnc_arcspiral.ngc"):
        kw = dict(tool_table=c / "tooltables" / "default.tbl", machine_units="inch")
        _same(load_program(c / name, fast=True, **kw), load_program(c / name, fast=False, **kw))
