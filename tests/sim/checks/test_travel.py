"""Travel limits of the controlled point (lines and arcs) and the --limits text."""

import pytest

from sim.checks import merge_findings, travel
from sim.errors import InputError
from sim.gcode.moves import MoveKind, Plane
from tests.sim.checks.helpers import polyline, table


def test_travel_limit_found_at_first_offending_line_with_distance_past_it():
    m = polyline([(0, 0, 5), (50, 0, 5), (120, 0, 5), (130, 0, 5), (50, 0, 5)])
    out = merge_findings(travel.travel_limits(m, {"X": (0, 100), "Z": (-50, 10)}))
    assert len(out) == 1
    f = out[0]
    # line: the first move past the limit; worst_line: the one furthest past it
    assert f.kind == "travel_limit" and f.lines == (20, 30, 40) and f.line == 20 and f.worst_line == 30
    assert f.depth == pytest.approx(30.0) and f.position[0] == pytest.approx(130.0)
    assert f.detail["axis"] == "X" and f.detail["limit"] == 100


def test_travel_limit_includes_the_controlled_point_not_the_tip():
    m = polyline([(0, 0, 0), (0, 0, -5)], tool_length=50.0)  # controlled point at Z 50 .. 45
    assert travel.travel_limits(m, {"Z": (-10, 40)})[0].depth == pytest.approx(10.0)


def test_arc_bulging_past_a_limit_between_in_limit_ends():
    # CCW half circle of radius 10 about the origin from (10, 0) to (-10, 0): reaches Y = 10
    m = table([(MoveKind.ARC_CCW, (10, 0, 0), (-10, 0, 0), {"center": (0, 0, 0), "plane": int(Plane.XY), "turns": 1})])
    out = travel.travel_limits(m, {"Y": (-20, 5)})
    assert len(out) == 1 and out[0].depth == pytest.approx(5.0, abs=0.02)
    # the same ends clockwise go through Y = -10 instead
    m["kind"] = int(MoveKind.ARC_CW)
    assert travel.travel_limits(m, {"Y": (-20, 5)}) == []
    assert travel.travel_limits(m, {"Y": (-8, 5)})[0].depth == pytest.approx(2.0, abs=0.02)


def test_parse_limits_and_its_errors():
    assert travel.parse_limits("X0:300, Y-10:200,z-100:0") == {"X": (0, 300), "Y": (-10, 200), "Z": (-100, 0)}
    for bad in ("X0", "Q0:1", "X5:1", ""):
        with pytest.raises(InputError, match="--limits"):
            travel.parse_limits(bad)
