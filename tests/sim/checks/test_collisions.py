"""A planted fault of each collision kind is found at its line; a clean pocket has none."""

import numpy as np
import pytest

from sim.checks import Checker, Fixture
from sim.frame import Frame
from sim.gcode.moves import MoveKind
from sim.solids import box_grid
from sim.tools import parse_tool_spec
from tests.sim.checks.helpers import table

F, R = MoveKind.FEED, MoveKind.RAPID
SPACING = 0.5
LIMITS = {"X": (-20, 100), "Y": (-20, 80), "Z": (-10, 60)}


def stock():
    fr = Frame.top(0, 0, 60, 40, SPACING)
    return box_grid(fr, (0, 0, 0), (60, 40, 20))


def pocket(z=17.0, extra=()):
    """Lines 10..: rapid over, plunge 3 mm, a rectangle, retract (all inside the stock)."""
    rows = [(R, (10, 10, 30), (10, 10, 25)), (F, (10, 10, 25), (10, 10, z)),
            (F, (10, 10, z), (50, 10, z)), (F, (50, 10, z), (50, 30, z)),
            (F, (50, 30, z), (10, 30, z)), (F, (10, 30, z), (10, 10, z)),
            (R, (10, 10, z), (10, 10, 30))]
    return table(rows + list(extra))


def run(moves, spec="flat:6:L=20:S=6:H=30", **kw):
    kw.setdefault("limits", LIMITS)
    kw.setdefault("fixtures", [Fixture.box((62, 0, 0), (70, 40, 35), SPACING, name="jaw")])
    ch = Checker(stock(), parse_tool_spec(spec), **kw)
    res, found = ch.cut_and_check(moves)
    return ch, res, found


def kinds(found):
    return [(f.kind, f.line) for f in found]


def test_clean_pocket_has_no_finding():
    ch, res, found = run(pocket(), max_depth_of_cut=5.0)
    assert res.removed.sum() > 0
    assert found == [] and ch.all_findings() == []


def test_rapid_into_stock_at_its_line():
    m = pocket(extra=[(R, (10, 10, 30), (30, 20, 15))])  # line 80: G0 down into the stock
    _, _, found = run(m)
    assert kinds(found) == [("rapid_into_stock", 80)]
    assert found[0].volume > 0
    # placed where the rapid first meets material: on the stock top (z 20), before the
    # tip itself gets there (2/3 of the way, at (23.3, 16.7)), within a radius of the path
    x, y, z = found[0].position
    assert z == pytest.approx(20.0)
    t = ((x - 10) * 20 + (y - 10) * 10) / 500
    assert 0.4 < t < 2 / 3 + 1e-9
    assert abs(-(x - 10) * 10 + (y - 10) * 20) / np.sqrt(500) <= 3.0 + 1e-9


def test_holder_contact_when_plunging_deeper_than_the_tool_sticks_out():
    # flutes 10, shank 5 (same diameter), holder 30 mm wide from 15 above the tip
    m = table([(R, (30, 20, 40), (30, 20, 25)), (F, (30, 20, 25), (30, 20, 3)), (R, (30, 20, 3), (30, 20, 40))])
    _, _, found = run(m, spec="flat:6:L=10:S=6:SL=5:H=30:HL=10")
    assert kinds(found) == [("holder_contact", 20)]
    # it lands on the top 2 mm of the ring between r = 3 and r = 15 and drags through
    # it again on the way out: one finding for both moves, the volume of the ring once
    # (the union of what it touched, not the sum of the two moves' overlaps)
    assert found[0].lines == (20, 30)
    assert found[0].volume == pytest.approx(np.pi * (15**2 - 3**2) * 2, rel=0.1)


def test_shank_wider_than_the_tool_touches():
    m = table([(R, (30, 20, 40), (30, 20, 25)), (F, (30, 20, 25), (30, 20, 4)), (R, (30, 20, 4), (30, 20, 40))])
    _, _, found = run(m, spec="flat:6:L=10:S=10")
    assert kinds(found) == [("shank_contact", 20)]


def test_tool_above_its_flutes_touches_on_a_deep_side_move():
    m = table([(R, (10, 20, 40), (10, 20, 25)), (F, (10, 20, 25), (10, 20, 10)),
               (F, (10, 20, 10), (40, 20, 10)), (F, (40, 20, 10), (40, 20, 40))])
    _, _, found = run(m, spec="flat:6:L=5")
    # the plunge cut its own way down; the side move drags the body above the flutes
    assert kinds(found) == [("above_flute_contact", 30)]


def test_tool_entering_a_fixture():
    m = pocket(extra=[(R, (10, 10, 30), (65, 20, 30)), (R, (65, 20, 30), (10, 10, 30))])
    _, _, found = run(m)
    assert [f.kind for f in found] == ["fixture_collision"]
    assert found[0].lines == (80, 90)  # both moves through the jaw, merged
    assert "jaw" in str(found[0])


def test_material_removed_with_the_spindle_stopped():
    m = pocket()
    m["spindle_dir"][3:] = 0  # M5 before line 40
    _, _, found = run(m)
    assert found and all(f.kind == "spindle_stopped_cutting" for f in found)
    assert found[0].lines == (40, 50, 60)


def test_plunge_with_a_tool_that_does_not_cut_at_its_centre():
    _, _, found = run(pocket(), spec="flat:6:L=20:nocenter")
    assert kinds(found) == [("non_center_cutting_plunge", 20)]


def test_depth_of_cut_over_the_limit():
    _, _, found = run(pocket(z=15.0), max_depth_of_cut=4.0)
    assert [f.kind for f in found] == ["depth_of_cut"]
    assert found[0].lines == (20, 30, 40, 50, 60) and found[0].depth == pytest.approx(5.0)


def test_travel_limit_exceeded():
    m = pocket(extra=[(R, (10, 10, 30), (110, 10, 30)), (R, (110, 10, 30), (10, 10, 30))])
    _, _, found = run(m, fixtures=[])
    assert kinds(found) == [("travel_limit", 80)]
    assert found[0].depth == pytest.approx(10.0) and found[0].lines == (80, 90)


def test_predict_finds_the_same_without_touching_the_live_model():
    m = pocket(extra=[(R, (10, 10, 30), (30, 20, 15))])
    ch = Checker(stock(), parse_tool_spec("flat:6:L=20:S=6:H=30"), limits=LIMITS)
    before = ch.grid.volume()
    predicted = ch.predict(m)
    assert ch.grid.volume() == before
    assert kinds(predicted) == [("rapid_into_stock", 80)]
    _, found = ch.cut_and_check(m)
    assert kinds(found) == kinds(predicted)
    assert found[0].volume == pytest.approx(predicted[0].volume)


def test_a_rapid_is_placed_on_the_material_it_met_not_what_later_moves_left():
    # line 30: G0 at Z-0.5 across the stock's edge (its top at Z20): it meets the edge X0 at
    # the top; lines 60/70 later cut the same rays 5 mm deep in the same batch
    m = table([(R, (-10, 15, 30), (-10, 15, 19.5)), (R, (-10, 15, 19.5), (10, 15, 19.5)),
               (R, (10, 15, 19.5), (10, 15, 30)), (R, (10, 15, 30), (-10, 15, 30)),
               (F, (-10, 15, 30), (-10, 15, 15)), (F, (-10, 15, 15), (30, 15, 15)), (R, (30, 15, 15), (30, 15, 30))])
    ch = Checker(stock(), parse_tool_spec("flat:6:L=20"))
    _, found = ch.cut_and_check(m)
    (f,) = [f for f in found if f.kind == "rapid_into_stock"]
    # (its volume on 0.5 mm rays: the slot and half disc X0..13, 0.5 mm deep, 37 mm^3)
    assert f.line == 20 and f.volume == pytest.approx(6 * 10 * 0.5 + 9 * np.pi / 2 * 0.5, rel=0.1)
    assert f.position == pytest.approx((0.0, 15.0, 20.0))


# --- a finding's position is where the tool met what it should not, not the move's end -----

def test_a_body_contact_is_placed_where_the_body_first_met_the_stock():
    # 8 mm deep from outside the stock (X0) to X30: the body above 5 mm flutes meets the
    # stock's edge at X0 on its top (Z20), not at the move's end 10 mm further in
    m = table([(R, (-10, 20, 30), (-10, 20, 12)), (F, (-10, 20, 12), (30, 20, 12)), (R, (30, 20, 12), (30, 20, 30))])
    _, _, found = run(m, spec="flat:6:L=5:S=6:SL=30:H=30", fixtures=[])
    (f,) = [f for f in found if f.kind == "shank_contact"]
    assert f.line == 20 and f.position == pytest.approx((0.0, 20.0, 20.0))


def test_a_fixture_collision_is_placed_on_the_fixture():
    # the jaw X62..70 is 35 high: a ball 0.01 below its top crosses it from X40 to X90
    m = table([(R, (40, 20, 40), (40, 20, 34.99)), (R, (40, 20, 34.99), (90, 20, 34.99))])
    _, _, found = run(m, spec="ball:6:L=10", limits={})
    (f,) = [f for f in found if f.kind == "fixture_collision"]
    assert f.line == 20 and f.position == pytest.approx((62.0, 20.0, 35.0))


def test_spindle_stopped_is_placed_where_the_tool_met_the_stock():
    m = table([(R, (-10, 20, 30), (-10, 20, 19)), (F, (-10, 20, 19), (30, 20, 19))], spindle=0.0)
    _, _, found = run(m, fixtures=[])
    (f,) = [f for f in found if f.kind == "spindle_stopped_cutting"]
    assert f.position == pytest.approx((0.0, 20.0, 20.0))


def test_depth_of_cut_is_placed_at_the_floor_of_the_deepest_cut():
    from sim.gcode import interpret

    # a G18 arc of radius ~54 from X-5 to X45 at Z25 whose bottom (X20) is 0.999 mm below
    # the top (Z20): deepest under X20 on the path (Y20), not at its end (X45, Z25)
    arc = "G21 G90 G18\nM3 S10000\nG0 Z30\nG0 X-5 Y20\nG0 Z25\nG2 X45 Z25 I25 K49.0833333 F500\nG0 Z30\nM2\n"
    _, _, found = run(interpret(arc).moves, spec="flat:6:L=10", max_depth_of_cut=0.9, fixtures=[])
    (f,) = [f for f in found if f.kind == "depth_of_cut" and f.line == 6]  # (the program starts in the stock)
    assert f.depth == pytest.approx(0.999, abs=0.01)
    assert f.position == pytest.approx((20.0, 20.0, 19.001), abs=0.5 * SPACING + 0.01)


def test_a_plunge_is_placed_where_the_tip_entered_the_stock():
    # a line from (10, 20, 21) to (11, 20, 11) crosses the top (Z20) at X10.1
    m = table([(R, (10, 20, 30), (10, 20, 21)), (F, (10, 20, 21), (11, 20, 11)), (R, (11, 20, 11), (11, 20, 30))])
    _, _, found = run(m, spec="flat:6:L=20:nocenter", fixtures=[])
    (f,) = found
    assert f.kind == "non_center_cutting_plunge" and f.position == pytest.approx((10.1, 20.0, 20.0))
