"""LinuxCNC's predefined named parameters and expression rules as rs274 gives them
(interp_namedparams.cc ``lookup_named_param``, interp_execute.cc ``execute_binary1``).
The same programs run against rs274 itself in tests/data/rs274/programs/named_*.ngc and
expr_mod.ngc (tests/sim/gcode/test_rs274.py)."""

from __future__ import annotations

import pytest

from sim.gcode import GCodeError, interpret, work_end
from sim.tooltable import ToolEntry


def values(text, *exprs, **kw):
    """The values of ``exprs`` read on one line after ``text``, as X positions of moves."""
    body = "".join(f"G0 X[{e}]\n" for e in exprs)
    rows = work_end(interpret("G21 G90\n" + text + "\n" + body + "M2", **kw).moves)
    return rows[-1 - len(exprs):-1, 0].tolist()   # the last rows but the end


# ------------------------------------------------------------------ modal codes times ten
@pytest.mark.parametrize("text, name, value", [
    ("G55", "_coord_system", 550), ("G59.1", "_coord_system", 591), ("", "_coord_system", 540),
    ("G18", "_plane", 180), ("G19", "_plane", 190), ("", "_plane", 170),
    ("G1 F100 X0", "_motion_mode", 10), ("G2 X0 Y0 I1 F100", "_motion_mode", 20), ("G80", "_motion_mode", 800),
])
def test_modal_codes_are_the_g_code_times_ten(text, name, value):
    assert values(text, f"#<{name}>") == [value]


def test_the_work_offset_is_restored_from_coord_system():
    # what probing and tool-change subroutines do to put the user's work offset back
    got = values("G59.1\n#<wcs>=#<_coord_system>\nG54\nG[#<wcs>/10]", "#<_coord_system>")
    assert got == [591]


# ------------------------------------------------------------------ MOD
@pytest.mark.parametrize("a, b, result", [
    (-7, -3, 2), (-1, -4, 3), (7, -3, 1), (-7, 3, 2), (7.5, -2, 1.5), (-7.5, -2, 0.5), (-6, -3, 0), (7, 3, 1),
])
def test_mod_makes_a_negative_result_non_negative_by_the_divisors_size(a, b, result):
    assert values("", f"[{a} MOD {b}]") == [pytest.approx(result)]


# ------------------------------------------------------------------ version
def test_version_is_major_minor_and_patch():
    # LinuxCNC 2.9.0: sscanf("2.9.0", "%lf%lf") reads 2.9 and .0
    assert values("", "#<_vmajor>", "#<_vminor>") == [pytest.approx(2.9), 0.0]


# ------------------------------------------------------------------ machine state
STATE = ("_spindle_on _spindle_cw _mist _flood _speed_override _feed_override _adaptive_feed _feed_hold "
         "_tool_offset _call_level _remap_level _ccomp _inverse_time _units_per_minute _units_per_rev "
         "_spindle_css_mode _spindle_rpm_mode _ijk_absolute_mode _metric_machine").split()


def test_machine_state_parameters_at_the_start():
    got = values("", *[f"#<{n}>" for n in STATE])
    # overrides enabled and feed hold allowed as rs274 starts; no INI file: _metric_machine -1
    assert dict(zip(STATE, got)) == {
        "_spindle_on": 0, "_spindle_cw": 0, "_mist": 0, "_flood": 0, "_speed_override": 1, "_feed_override": 1,
        "_adaptive_feed": 0, "_feed_hold": 1, "_tool_offset": 0, "_call_level": 0, "_remap_level": 0,
        "_ccomp": 400, "_inverse_time": 0, "_units_per_minute": 1, "_units_per_rev": 0,
        "_spindle_css_mode": 0, "_spindle_rpm_mode": 1, "_ijk_absolute_mode": 0, "_metric_machine": -1}


def test_machine_state_parameters_follow_the_program():
    tools = {2: ToolEntry(number=2, pocket=12, z_offset=10.0, offsets={"Z": 10.0})}
    text = "M3 S1000 M7\nM8\nM49\nM52 P1\nM53 P0\nG43 H2 G90.1 G93"
    names = ["_spindle_on", "_spindle_cw", "_mist", "_flood", "_speed_override", "_feed_override",
             "_adaptive_feed", "_feed_hold", "_tool_offset", "_ijk_absolute_mode", "_inverse_time",
             "_units_per_minute", "_spindle_css_mode", "_spindle_rpm_mode"]   # G96 is refused: always G97
    got = values(text, *[f"#<{n}>" for n in names], tool_table=tools)
    assert got == [1, 1, 1, 1, 0, 0, 1, 0, 1, 1, 1, 0, 0, 1]
    assert values("M4 M48\nM50 P0\nM51 P1\nG95", "#<_spindle_cw>", "#<_speed_override>", "#<_feed_override>",
                  "#<_units_per_rev>") == [0, 1, 0, 1]


def test_pockets_follow_the_tool_table():
    tools = {n: ToolEntry(number=n, pocket=10 + n, line=n) for n in (1, 3, 5)}
    # rs274's stand-alone canon starts with the table's first entry as the current pocket
    assert values("", "#<_current_pocket>", "#<_selected_pocket>", tool_table=tools) == [11, -1]
    assert values("T3 M6", "#<_current_pocket>", "#<_selected_pocket>", tool_table=tools) == [13, 13]
    assert values("T3 M6\nM61 Q5 T1", "#<_current_pocket>", "#<_selected_pocket>", tool_table=tools) == [15, 11]


def test_call_level_counts_the_subroutines_running():
    text = "o1 sub\nG0 X[#<_call_level>]\no2 call\no1 endsub\no2 sub\nG0 X[#<_call_level>]\no2 endsub\no1 call\n"
    ends = work_end(interpret("G21\n" + text + "G0 X[#<_call_level>]\nM2").moves)[:3, 0]
    assert ends.tolist() == [1, 2, 0]


# ------------------------------------------------------------------ set and read on one line
def test_a_name_set_on_a_line_reads_as_its_old_value_after_the_setting():
    assert values("#<depth>=3 #<half>=[#<depth>/2+1]", "#<half>") == [1]   # new: 0 until the line ends
    assert values("#<a>=3\n#<a>=5 #<b>=#<a>", "#<b>") == [3]
    assert values("#<q>=[#<q>+1]", "#<q>") == [1]
    assert values("#<_g>=2 #<_h>=[#<_g>+1]", "#<_h>") == [1]
    ends = work_end(interpret("G21\n#<zz>=4 G0 X[#<zz>+1]\nM2").moves)[0, 0]
    assert ends == 1


def test_a_name_read_before_its_setting_on_the_line_is_not_defined():
    with pytest.raises(GCodeError, match="not defined"):
        interpret("G21\nG0 X[#<zz>+1] #<zz>=4\nM2")
