"""The engagement seen from above: depth of cut, and plunges of tools that do not cut at
their centre (an arc's along its tangent where it enters material)."""

import math

import numpy as np
import pytest

from sim.checks import engagement
from sim.errors import InputError
from sim.frame import Frame
from sim.gcode.moves import MoveKind
from sim.tools import parse_tool_spec
from tests.sim.checks.helpers import polyline

F, R = MoveKind.FEED, MoveKind.RAPID


def flat_top(z=10.0, spacing=0.25):
    fr = Frame.top(0, 0, 40, 40, spacing)
    return fr, np.full(fr.shape, z)


def test_depth_of_cut_of_a_slot_then_zero_on_a_repeat_pass():
    fr, top = flat_top()
    eng = engagement.Engagement(fr, top, parse_tool_spec("flat:6"))
    m = polyline([(5, 20, 12), (5, 20, 7), (35, 20, 7), (35, 20, 12)], kinds=[F, F, R])
    doc, core = eng.run(m)
    assert doc == pytest.approx([3.0, 3.0, 0.0])  # the plunge and the slot cut 3 mm deep, the retract nothing
    eng = engagement.Engagement(fr, top, parse_tool_spec("flat:6"))
    m = polyline([(5, 20, 12), (5, 20, 10.5), (35, 20, 7), (35, 20, 7)])
    doc, _ = eng.run(m)
    assert doc[1] == pytest.approx(3.0, abs=1e-9)  # ramp down to 3 mm deep: the far end
    doc2, _ = eng.run(m)
    assert doc2.max() == 0.0
    found = engagement.depth_of_cut(m, doc, 2.0)
    assert [(f.kind, f.line) for f in found] == [("depth_of_cut", 20)]


def test_ball_groove_depth_and_sides():
    fr, top = flat_top()
    eng = engagement.Engagement(fr, top, parse_tool_spec("ball:6"))
    m = polyline([(5, 20, 9.2), (35, 20, 9.2)])
    doc, core = eng.run(m)
    assert doc[0] == pytest.approx(0.8, abs=1e-6) and core[0] == pytest.approx(0.8, abs=1e-6)
    h = eng.top.reshape(fr.shape)
    # groove profile at X = 20: z = 9.2 + 3 - sqrt(9 - dy^2) where below the top
    y = np.arange(fr.nv) * fr.spacing
    expect = np.minimum(10.0, 9.2 + 3 - np.sqrt(np.maximum(9 - (y - 20) ** 2, 0)))
    assert np.allclose(h[:, 80], np.where(np.abs(y - 20) < 3, expect, 10.0), atol=1e-3)


def test_plunge_with_a_non_center_cutting_tool_only():
    fr, top = flat_top()
    m = polyline([(20, 20, 15), (20, 20, 8), (30, 20, 8), (35, 20, 7.5)])
    for spec, expected in (("flat:6", []), ("flat:6:nocenter", [10])):
        tool = parse_tool_spec(spec)
        eng = engagement.Engagement(fr, top, tool)
        doc, core = eng.run(m)
        out = engagement.plunges(m, core, tool)
        assert [f.line for f in out] == expected
    # the vertical plunge is found; the 5.7 degree ramp at line 30 is not a plunge
    assert out[0].kind == "non_center_cutting_plunge" and out[0].depth == pytest.approx(2.0)


def test_engagement_needs_a_top_view_frame():
    fr = Frame(np.zeros(3), (1, 0, 0), (0, 1, 0), 1.0, 4, 4)
    with pytest.raises(InputError, match="top-view"):
        engagement.Engagement(fr, np.zeros((4, 4)), parse_tool_spec("flat:6"))


# --- the entry angle of an arc: along its tangent where it enters material ------------------

def _plunges(program, spec="flat:6:L=20:nocenter", checker=True):
    """Plunge findings of ``program`` (G-code) cut into the box X0..60 Y0..30 Z-20..0: through
    the Checker (the engagement after the real cut) or a standalone Engagement."""
    from sim.checks import Checker
    from sim.gcode import interpret
    from sim.solids import box_grid

    moves = interpret(program).moves
    tool = parse_tool_spec(spec)
    fr = Frame.top(0, 0, 60, 30, 0.2)
    if checker:
        _, found = Checker(box_grid(fr, (0, 0, -20), (60, 30, 0)), tool).cut_and_check(moves)
        return [f for f in found if f.kind == "non_center_cutting_plunge"]
    eng = engagement.Engagement(fr, np.zeros(fr.shape), tool)
    _, core = eng.run(moves)
    return engagement.plunges(moves, core, tool, entry_deg=eng.entry_deg, entry_at=eng.entry_at)


HELIX = ("G21 G90 G17\nM3 S10000\nG0 X25 Y15 Z5\nG1 Z0.1 F200\nG3 X25 Y15 I-5 J0 Z-0.5\n"
         "G3 X25 Y15 I-5 J0 Z-1.0\nG3 X25 Y15 I-5 J0 Z-1.0\nG0 Z5\nM2\n")
# G18 half circle of radius 10 about (X20, Z1): straight down at X10, 9 mm below the top at X20;
# it enters the top (Z0) 1 mm below its centre, where its tangent is atan(sqrt(99)) = 84.26 deg
DIP = "G21 G90 G18\nM3 S10000\nG0 X10 Y15 Z5\nG1 Z1 F200\nG2 X30 Z1 I10 K0\nG0 Z10\nM2\n"
QUARTER = "G21 G90 G18\nM3 S10000\nG0 X10 Y15 Z5\nG1 Z1 F200\nG2 X20 Z-9 I10 K0\nG1 X35\nG0 Z10\nM2\n"
ENTRY_DEG = math.degrees(math.atan(math.sqrt(99.0)))


@pytest.mark.parametrize("checker", [True, False])
def test_a_full_turn_helix_ramp_is_no_plunge(checker):
    # 0.6 then 0.5 mm a turn on a 5 mm radius: 1.1 deg down, though each turn ends where
    # it started (its chord is vertical)
    assert _plunges(HELIX, checker=checker) == []
    # the first turn (0.6 mm) on a 0.6 mm radius: 9.0 deg, still a ramp; on 0.4 mm: 13.4 deg
    steep = HELIX.replace("I-5 J0", "I-0.6 J0")
    assert _plunges(steep, checker=checker) == []
    f = _plunges(steep.replace("I-0.6 J0", "I-0.4 J0"), checker=checker)[0]
    assert f.line == 5
    assert f.detail["angle_deg"] == pytest.approx(math.degrees(math.atan(0.6 / (0.8 * math.pi))), abs=0.05)


@pytest.mark.parametrize("checker", [True, False])
def test_an_arc_diving_into_the_stock_is_a_plunge_at_its_entry_tangent(checker):
    (f,) = _plunges(DIP, checker=checker)
    assert f.line == 5 and f.detail["angle_deg"] == pytest.approx(ENTRY_DEG, abs=0.2)
    # placed where it entered: on the top, 10 - sqrt(99) mm past its start
    assert f.position == pytest.approx((20 - math.sqrt(99.0), 15.0, 0.0), abs=0.005)
    (f,) = _plunges(QUARTER, checker=checker)  # not the 45 deg of its chord
    assert f.line == 5 and f.detail["angle_deg"] == pytest.approx(ENTRY_DEG, abs=0.2)
