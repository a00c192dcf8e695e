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
