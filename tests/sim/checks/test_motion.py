import math

import numpy as np
import pytest

from sim.checks import merge_findings, motion
from sim.errors import InputError
from sim.frame import Frame
from sim.gcode.moves import MoveKind, Plane
from sim.tools import parse_tool_spec
from tests.sim.checks.helpers import polyline, table

F, R = MoveKind.FEED, MoveKind.RAPID


def test_travel_limit_found_at_first_offending_line_with_distance_past_it():
    m = polyline([(0, 0, 5), (50, 0, 5), (120, 0, 5), (130, 0, 5), (50, 0, 5)])
    out = merge_findings(motion.travel_limits(m, {"X": (0, 100), "Z": (-50, 10)}))
    assert len(out) == 1
    f = out[0]
    # line: the first move past the limit; worst_line: the one furthest past it
    assert f.kind == "travel_limit" and f.lines == (20, 30, 40) and f.line == 20 and f.worst_line == 30
    assert f.depth == pytest.approx(30.0) and f.position[0] == pytest.approx(130.0)
    assert f.detail["axis"] == "X" and f.detail["limit"] == 100


def test_travel_limit_includes_the_controlled_point_not_the_tip():
    m = polyline([(0, 0, 0), (0, 0, -5)], tool_length=50.0)  # controlled point at Z 50 .. 45
    assert motion.travel_limits(m, {"Z": (-10, 40)})[0].depth == pytest.approx(10.0)


def test_arc_bulging_past_a_limit_between_in_limit_ends():
    # CCW half circle of radius 10 about the origin from (10, 0) to (-10, 0): reaches Y = 10
    m = table([(MoveKind.ARC_CCW, (10, 0, 0), (-10, 0, 0), {"center": (0, 0, 0), "plane": int(Plane.XY), "turns": 1})])
    out = motion.travel_limits(m, {"Y": (-20, 5)})
    assert len(out) == 1 and out[0].depth == pytest.approx(5.0, abs=0.02)
    # the same ends clockwise go through Y = -10 instead
    m["kind"] = int(MoveKind.ARC_CW)
    assert motion.travel_limits(m, {"Y": (-20, 5)}) == []
    assert motion.travel_limits(m, {"Y": (-8, 5)})[0].depth == pytest.approx(2.0, abs=0.02)


def test_arc_points_stay_on_the_circle_within_chord():
    m = table([(MoveKind.ARC_CW, (10, 0, 0), (10, 0, -3), {"center": (0, 0, 0), "plane": int(Plane.XY), "turns": 2})])
    pts = motion.arc_points(m[0], 0.001)
    r = np.hypot(pts[:, 0], pts[:, 1])
    assert np.allclose(r, 10.0)
    mid = (pts[1:] + pts[:-1]) / 2
    assert (10.0 - np.hypot(mid[:, 0], mid[:, 1])).max() <= 0.001 + 1e-9
    ang = np.unwrap(np.arctan2(pts[:, 1], pts[:, 0]))
    assert ang[-1] - ang[0] == pytest.approx(-4 * math.pi)  # two full clockwise turns
    assert pts[-1, 2] == pytest.approx(-3.0)


def test_parse_limits_and_its_errors():
    assert motion.parse_limits("X0:300, Y-10:200,z-100:0") == {"X": (0, 300), "Y": (-10, 200), "Z": (-100, 0)}
    for bad in ("X0", "Q0:1", "X5:1", ""):
        with pytest.raises(InputError, match="--limits"):
            motion.parse_limits(bad)


def test_spindle_stopped_cutting_needs_removed_material_and_a_stopped_spindle():
    m = polyline([(0, 0, 5), (0, 0, -1), (10, 0, -1), (20, 0, -1)])
    m["spindle_dir"][1:] = 0
    out = motion.spindle_stopped_cutting(m, np.array([0.0, 4.0, 0.0]))
    assert [(f.kind, f.line, f.volume) for f in out] == [("spindle_stopped_cutting", 20, 4.0)]


def flat_top(z=10.0, spacing=0.25):
    fr = Frame.top(0, 0, 40, 40, spacing)
    return fr, np.full(fr.shape, z)


def test_depth_of_cut_of_a_slot_then_zero_on_a_repeat_pass():
    fr, top = flat_top()
    eng = motion.Engagement(fr, top, parse_tool_spec("flat:6"))
    m = polyline([(5, 20, 12), (5, 20, 7), (35, 20, 7), (35, 20, 12)], kinds=[F, F, R])
    doc, core = eng.run(m)
    assert doc == pytest.approx([3.0, 3.0, 0.0])  # the plunge and the slot cut 3 mm deep, the retract nothing
    eng = motion.Engagement(fr, top, parse_tool_spec("flat:6"))
    m = polyline([(5, 20, 12), (5, 20, 10.5), (35, 20, 7), (35, 20, 7)])
    doc, _ = eng.run(m)
    assert doc[1] == pytest.approx(3.0, abs=1e-9)  # ramp down to 3 mm deep: the far end
    doc2, _ = eng.run(m)
    assert doc2.max() == 0.0
    found = motion.depth_of_cut(m, doc, 2.0)
    assert [(f.kind, f.line) for f in found] == [("depth_of_cut", 20)]


def test_ball_groove_depth_and_sides():
    fr, top = flat_top()
    eng = motion.Engagement(fr, top, parse_tool_spec("ball:6"))
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
        eng = motion.Engagement(fr, top, tool)
        doc, core = eng.run(m)
        out = motion.plunges(m, core, tool)
        assert [f.line for f in out] == expected
    # the vertical plunge is found; the 5.7 degree ramp at line 30 is not a plunge
    assert out[0].kind == "non_center_cutting_plunge" and out[0].depth == pytest.approx(2.0)


def test_engagement_needs_a_top_view_frame():
    fr = Frame(np.zeros(3), (1, 0, 0), (0, 1, 0), 1.0, 4, 4)
    with pytest.raises(InputError, match="top-view"):
        motion.Engagement(fr, np.zeros((4, 4)), parse_tool_spec("flat:6"))


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
    eng = motion.Engagement(fr, np.zeros(fr.shape), tool)
    _, core = eng.run(moves)
    return motion.plunges(moves, core, tool, entry_deg=eng.entry_deg, entry_at=eng.entry_at)


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


def test_spindle_stopped_names_where_it_stopped_or_that_it_never_started():
    m = polyline([(0, 0, 5), (0, 0, 1), (10, 0, 1), (10, 0, -1), (20, 0, -1)])
    m["spindle_dir"][2:] = 0  # M5 between line 20 (the last move it ran for) and line 30
    (f,) = motion.spindle_stopped_cutting(m, np.array([0.0, 0.0, 0.0, 4.0]))
    assert f.line == 40 and f.detail["cause"] == "spindle off after line 20"
    m["spindle_dir"][:] = 0  # never started
    (f,) = motion.spindle_stopped_cutting(m, np.array([0.0, 0.0, 0.0, 4.0]))
    assert f.detail["cause"] == "spindle off: never started"
    # the same across batches: the carry holds the last line it ran for
    m["spindle_dir"][:2] = 1
    carry = tuple(motion.spindle_off_from(m[:3])[-1])
    (f,) = motion.spindle_stopped_cutting(m[3:], np.array([4.0]), move_ids=[4], carry=carry)
    assert f.detail["cause"] == "spindle off after line 20" and f.detail["off_from_move"] == 3
