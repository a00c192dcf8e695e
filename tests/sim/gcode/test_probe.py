"""G38.2-G38.5 as LinuxCNC's rs274 simulates them (sim/gcode/probe.py)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.gcode import GCodeError, MoveKind, interpret, work_end


def test_probe_sets_5061_to_5070_and_backs_off_towards_its_start():
    p = interpret("G21 G10 L2 P1 X5\nG0 X0 Y0 Z10\nG38.2 Z-5 F100\nG0 X[#5061] Y[#5063] Z[#5070]\nM2")
    m = p.moves
    probes = m[m["kind"] == MoveKind.PROBE]
    # the probing move to the target, then the retract (feed 0) 0.254 mm back up
    np.testing.assert_allclose(work_end(probes)[:, 2], [-5.0, -5.0 + 0.254])
    assert probes["feed"].tolist() == [100.0, 0.0]
    last = m[m["kind"] == MoveKind.RAPID][-1]
    # #5061/#5063 are the probed point in work coordinates, #5070 = 0: never tripped
    np.testing.assert_allclose(work_end(last[None])[0, :3], [0.0, -5.0, 0.0])
    np.testing.assert_array_equal(m["start"][1:], m["end"][:-1])


def test_probe_results_are_in_program_units():
    p = interpret("G20 G0 X0 Y0 Z1\nG38.2 Z-0.5 F5\nG0 X[#5063]\nM2")
    assert work_end(p.moves)[-2, 0] == pytest.approx(-0.5 * 25.4)


def test_a_probing_macro_loop_on_5070_ends():
    text = "G21 F100\n#5070=1\no1 while [#5070 NE 0]\n  G38.5 Z5\n  G38.3 X1\no1 endwhile\nG0 X0\nM2\n"
    m = interpret(text).moves
    assert (m["kind"] == MoveKind.PROBE).sum() >= 2


def test_g38_2_starting_at_its_target_is_refused_at_its_line_but_g38_3_is_not():
    with pytest.raises(GCodeError, match="probe target") as info:
        interpret("G21 G0 Z10\nG38.2 Z10 F100\nM2")
    assert info.value.line == 2
    m = interpret("G21 G0 Z10\nG38.3 Z10 F100\nG38.5 Z10\nM2").moves
    assert (m["kind"] == MoveKind.PROBE).sum() == 2   # no motion: no retract rows


@pytest.mark.parametrize("text,what", [
    ("G21 G0 Z10\nG38.2 Z5\nM2", "zero feed"),
    ("G21 G93 G0 Z10\nG38.2 Z5 F1\nM2", "zero feed"),
    ("G21 G95 S100 G0 Z10\nG38.2 Z5 F1\nM2", "feed per revolution"),
])
def test_probe_refused_where_rs274_refuses(text, what):
    with pytest.raises(GCodeError, match=what):
        interpret(text)
