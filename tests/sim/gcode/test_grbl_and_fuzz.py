"""GRBL dialect (streamed lines, GRBL error numbers) and fuzzing: only GCodeError ever escapes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sim.gcode import GCodeError, Interpreter, MoveKind, interpret
from sim.gcode.limits import Limits


@pytest.mark.parametrize("line,code", [
    ("G1 X10", 22),            # no feed rate yet
    ("G83 X1 Z-1 R1 Q1", 20),  # canned cycles
    ("M6", 20),
    ("M7", 20),
    ("G41 X1", 20),
    ("o100 sub", 20),
    ("#1=5", 1),
    ("X[1+2]", 2),             # GRBL reads a number after the letter: bad number format
    ("G4", 28),
    ("G0 X", 2),
    ("%", 1),
    ("G0 G1 X1", 21),
    ("G0 X1 X2", 25),
    ("G1.7 X1", 23),
    ("G28 G0 X1", 24),
    ("G2 X0 Y0 R0 F100", 33),
    ("G2 X10 Y0 R2 F100", 34),
    ("G2 X10 Y0 R0 F100", 34),
    ("G2 X10 Y0 I3 F100", 33),
    ("G2 Z3 I3 F100", 32),
    ("G0 X1 I3", 36),
    ("G80 X1", 31),
    ("T300", 38),
    ("G43.1 X1", 37),
    ("A5", 20),
    ("!", 1),
])
def test_grbl_refuses_with_its_error_number(line, code):
    it = Interpreter(dialect="grbl")
    with pytest.raises(GCodeError) as info:
        it.execute_line(line, line_no=1)
    assert info.value.grbl_code == code, str(info.value)


def test_grbl_stream_produces_rows_and_keeps_state():
    it = Interpreter(dialect="grbl")
    assert len(it.execute_line("G21 G90 (setup)")) == 0
    rows = it.execute_line("G1 X10 F300", line_no=2)
    assert rows["kind"].tolist() == [MoveKind.FEED] and rows["line"][0] == 2
    assert rows["feed"][0] == 300
    rows = it.execute_line("G2 X20 Y0 R5")
    np.testing.assert_allclose(rows["center"][0, :2], [15, 0])
    it.execute_line("G10 L20 P1 X0")
    st = it.state
    np.testing.assert_allclose(st.work_offset[:3], [20, 0, 0])
    np.testing.assert_allclose(st.work_position[:3], [0, 0, 0])
    assert st.gcodes()[:6] == ["G2", "G54", "G17", "G21", "G90", "G94"]
    # an arc with no axis words moves nothing in GRBL, and its offsets are then unused
    with pytest.raises(GCodeError) as info:
        it.execute_line("G2 I5")
    assert info.value.grbl_code == 36
    # a refused line leaves the position and modes alone
    np.testing.assert_allclose(it.state.position[:3], [20, 0, 0])
    with pytest.raises(GCodeError) as info:
        it.execute_line("G0 G91 X1 I3")
    assert info.value.grbl_code == 36
    np.testing.assert_allclose(it.state.position[:3], [20, 0, 0])
    assert it.state.distance == 900 and it.state.motion == 20


def test_grbl_m2_resets_modes_but_keeps_running():
    it = Interpreter(dialect="grbl")
    it.execute_line("G91 G1 X1 F100 M3 S1000")
    rows = it.execute_line("M2")
    assert rows["kind"].tolist() == [MoveKind.END]
    assert it.state.distance == 900 and it.state.spindle_dir == 0
    assert len(it.execute_line("G1 X5")) == 1
    it.execute_line("G92 X0")
    it.execute_line("M2")
    np.testing.assert_allclose(it.state.g92_offset[0], 5)  # GRBL keeps G92 through M2


def test_linuxcnc_streaming_execute_line():
    it = Interpreter()
    it.execute_line("#1 = 3")
    rows = it.execute_line("G0 X[#1 * 2]")
    assert rows["end"][0, 0] == 6


GCODE_WORDS = st.sampled_from(list("GMXYZIJKRFSTPQLHDNABC@^#[]O<>=+-*/. ;()%") + [
    "G0", "G1", "G2", "G3", "G17", "G18", "G19", "G20", "G21", "G40", "G41", "G42", "G43", "G49", "G54", "G55",
    "G81", "G83", "G73", "G80", "G90", "G91", "G92", "G28", "G10 L2 P1", "G10 L20 P0", "G53", "G93", "G94",
    "M3", "M5", "M6", "M2", "o1 if", "o1 endif", "o1 while", "o1 endwhile", "o1 sub", "o1 endsub", "o1 call",
    "SIN", "ATAN", "SQRT", "EXISTS", "#<a>", "#<_b>", "MOD", "EQ", "AND", "\n", "\n", "\n"])
NUMBERS = st.one_of(st.integers(-1000, 1000).map(str),
                    st.floats(-1e6, 1e6, allow_nan=False).map(lambda f: f"{f:.4f}"))
TOKENS = st.one_of(GCODE_WORDS, NUMBERS)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(TOKENS, max_size=40).map(" ".join), st.sampled_from(["linuxcnc", "grbl"]))
def test_fuzz_only_gcode_errors(text, dialect):
    try:
        p = interpret(text, dialect=dialect, keep_going=True, limits=Limits(max_loop=200))
    except GCodeError:
        return
    assert p.moves.dtype.names[0] == "file"
    for e in p.errors:
        assert isinstance(e, GCodeError) and str(e)
    p.linearize(0.01)
    p.cycle_time()


@settings(max_examples=100, deadline=None)
@given(st.text(max_size=60))
def test_fuzz_any_text_streamed(text):
    for dialect in ("grbl", "linuxcnc"):
        it = Interpreter(dialect=dialect)
        for line in text.splitlines() or [text]:
            try:
                it.execute_line(line)
            except GCodeError:
                pass
