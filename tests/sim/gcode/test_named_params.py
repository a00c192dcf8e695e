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
