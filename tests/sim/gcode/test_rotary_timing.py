"""Rotary axes in the timing (6-axis block length, G93 inverse time) and in the grbl
dialect (a grblHAL with rotary axes takes their words; Grbl 1.1 refuses them)."""

from __future__ import annotations

import pytest

from sim.gcode import GCodeError
from sim.gcode.program import interpret
from sim.gcode.timing import cycle_time

#: acceleration so high the ramps take no time worth counting: seconds are distance / rate
FAST = {"max_rate": (6000.0,) * 6, "acceleration": (1e9,) * 6, "junction_deviation": 0.01}


def seconds(text, dialect="linuxcnc", machine=FAST):
    prog = interpret(text, dialect=dialect)
    return cycle_time(prog.moves, machine)


def test_a_only_move_takes_the_time_a_needs():
    """G1 A360 F3600: 360 deg at 3600 deg/min is 6 s (it used to take 0 s: XYZ length 0)."""
    total, per_row = seconds("G21 G90 G94\nG1 A360 F3600\n")
    assert total == pytest.approx(6.0, rel=1e-4)


def test_linear_and_rotary_share_the_length():
    """X 30 mm with A 40 deg: a 50 'mm' block (degrees counted as mm, as grblHAL) at 3000."""
    total, _ = seconds("G21 G90 G94\nG1 X30 A40 F3000\n")
    assert total == pytest.approx(1.0, rel=1e-4)


def test_rotary_rate_caps_the_block():
    """A's own max rate (6 values: deg/min) caps a rotary block; 3 values give A the largest."""
    slow_a = dict(FAST, max_rate=(6000.0, 6000.0, 6000.0, 600.0, 600.0, 600.0))
    total, _ = seconds("G21 G90 G94\nG1 A60 F3600\n", machine=slow_a)
    assert total == pytest.approx(6.0, rel=1e-4)
    three = dict(FAST, max_rate=(6000.0, 6000.0, 1200.0))
    total, _ = seconds("G21 G90 G94\nG0 A600\n", machine=three)
    assert total == pytest.approx(6.0, rel=1e-4)


def test_inverse_time_feed_takes_one_over_f_minutes():
    """G93 F2: every feed row takes half a minute, whatever it moves (X, A, or both)."""
    total, per_row = seconds("G21 G90\nG93 G1 X10 A90 F2\nG1 A0 F2\nG1 X0 F2\n")
    assert per_row[-3:].tolist() == pytest.approx([30.0, 30.0, 30.0], rel=1e-4)


def test_grbl_refuses_a_words_unless_the_machine_has_an_a_axis():
    with pytest.raises(GCodeError, match="GRBL does not support the A word.*kinematics with A"):
        interpret("G21 G90\nG1 X1 A90 F100\n", dialect="grbl")
    prog = interpret("G21 G90\nG1 X1 A90 F100\n", dialect="grbl+A")
    assert prog.moves["end"][-1][3] == 90.0
    with pytest.raises(GCodeError, match="B word"):
        interpret("G21 G90\nG1 X1 B90 F100\n", dialect="grbl+A")
    with pytest.raises(GCodeError, match="unknown dialect"):
        interpret("G0 X1\n", dialect="grbl+Q")


def test_job_reads_a_grbl_program_with_a_words_on_a_4th_axis_machine():
    from monitor.job import parse_job_text

    job = parse_job_text('[program]\ndialect = "grbl"\n[machine]\nkinematics = "xyza"\n')
    assert job.program_dialect == "grbl+A"
    assert parse_job_text('[program]\ndialect = "grbl"\n').program_dialect == "grbl"
