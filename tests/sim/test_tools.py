"""Tools as solids of revolution, tool specs and LinuxCNC tool tables."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.errors import InputError
from sim.tools import Body, Tool, parse_tool_spec
from sim.tooltable import read_tool_table, tool_from_entry


@pytest.mark.parametrize("spec, kind, d, rc, L", [
    ("flat:6", "flat", 6.0, 0.0, 24.0),
    ("ball:6", "ball", 6.0, 3.0, 24.0),
    ("bull:6:1:L=20", "bull", 6.0, 1.0, 20.0),
    ("vbit:6:90", "vbit", 6.0, 0.0, 24.0),
    ("drill:5", "drill", 5.0, 0.0, 20.0),
    ("BALL:3.175:L=12.7", "ball", 3.175, 1.5875, 12.7),
])
def test_parse_tool_spec(spec, kind, d, rc, L):
    t = parse_tool_spec(spec)
    assert (t.kind, t.diameter, t.radius, t.corner_radius, t.flute_length) == (kind, d, d / 2, rc, L)
    assert t.shank is None and t.holder is None and t.center_cutting
    assert parse_tool_spec(t.describe()).describe() == t.describe()


def test_drill_default_angle_and_vbit_angle():
    assert parse_tool_spec("drill:5").angle == 118.0
    assert parse_tool_spec("vbit:6:60").angle == 60.0


def test_shank_and_holder_bodies_sit_above_the_flutes():
    t = parse_tool_spec("flat:6:L=20:S=6:SL=25:H=30:HL=40:nocenter")
    assert not t.center_cutting
    assert (t.shank.bottom, t.shank.top, t.shank.max_radius) == (20.0, 45.0, 3.0)
    assert (t.holder.bottom, t.holder.top, t.holder.max_radius) == (45.0, 85.0, 15.0)
    assert t.shank.volume() == pytest.approx(math.pi * 9 * 25)
    assert [b.name for b in t.bodies()] == ["shank", "holder"]


@pytest.mark.parametrize("bad, fragment", [
    ("cone:6", "unknown tool spec"),
    ("ball", "unknown tool spec"),
    ("", "unknown tool spec"),
    ("ball:-2", "diameter"),
    ("ball:abc", "bad field"),
    ("bull:6:4", "corner radius"),
    ("bull:6", "takes 2"),
    ("vbit:6:180", "angle"),
    ("flat:6:Q=3", "unknown option"),
    ("flat:6:L=0", "flute length"),
])
def test_bad_specs_say_what_was_expected(bad, fragment):
    with pytest.raises(InputError) as exc:
        parse_tool_spec(bad)
    assert fragment in str(exc.value)
    assert "\n" not in str(exc.value)


def test_lowest_height_is_the_analytic_tip_shape():
    d = np.linspace(0, 3, 31)
    ball = parse_tool_spec("ball:6")
    np.testing.assert_allclose(ball.lowest_height(d), 3 - np.sqrt(9 - d * d), atol=1e-12)
    bull = parse_tool_spec("bull:6:1")
    want = np.where(d <= 2, 0.0, 1 - np.sqrt(np.maximum(1 - (d - 2) ** 2, 0)))
    np.testing.assert_allclose(bull.lowest_height(d), want, atol=1e-12)
    vbit = parse_tool_spec("vbit:6:90")
    np.testing.assert_allclose(vbit.lowest_height(d), d, atol=1e-12)
    assert np.isnan(ball.lowest_height([3.01])[0])
    np.testing.assert_allclose(parse_tool_spec("flat:6").lowest_height(d), 0.0)


@pytest.mark.parametrize("spec", ["ball:6", "bull:8:2", "ball:1"])
def test_polyline_profile_is_within_the_chord_tolerance(spec):
    t = parse_tool_spec(spec)
    rc, a = t.corner_radius, t.radius - t.corner_radius
    p = t.profile[(t.profile[:, 0] <= rc) & (t.profile[:, 1] >= a)]
    f = np.linspace(0, 1, 50)[:, None, None]
    pts = (p[:-1] + f * (p[1:] - p[:-1])).reshape(-1, 2)  # points along every chord
    dist = np.hypot(pts[:, 0] - rc, pts[:, 1] - a)        # from the corner centre
    assert dist.max() <= rc + 1e-12                       # chords lie inside the arc
    assert rc - dist.min() <= 0.001 * 1.0001              # sagitta within tol.chord
    np.testing.assert_allclose(np.hypot(p[:, 0] - rc, p[:, 1] - a), rc, atol=1e-12)


def test_volumes_are_analytic():
    R = 3.0
    assert parse_tool_spec("flat:6:L=10").volume() == pytest.approx(math.pi * R * R * 10)
    assert parse_tool_spec("ball:6:L=10").volume() == pytest.approx(
        2 / 3 * math.pi * R**3 + math.pi * R * R * 7)
    # bull-nose against the polyline of its own profile (frusta), a fine check of both
    t = parse_tool_spec("bull:6:1:L=10")
    assert t.volume() == pytest.approx(Body("b", t.profile).volume(), rel=1e-4)


def test_custom_profiles_and_convexity():
    tslot = Tool.custom([[0, 5], [2, 5], [2, 1], [20, 1]])
    assert tslot.kind == "custom" and tslot.diameter == 10 and tslot.flute_length == 20
    assert not tslot.is_convex
    assert Tool.custom([[0, 0], [3, 3], [10, 3]]).is_convex
    assert parse_tool_spec("bull:6:1").is_convex
    with pytest.raises(InputError):
        Tool.custom([[1, 2], [3, 2]])  # must start at the tip
    with pytest.raises(InputError):
        Tool.custom([[0, 2], [-1, 2]])


def test_read_tool_table_mm(data):
    path = data / "tools_mm.tbl"
    table = read_tool_table(path)
    assert sorted(table) == [1, 2, 3, 17]
    t1, t2, t3, t17 = (table[k] for k in (1, 2, 3, 17))
    assert (t1.pocket, t1.diameter, t1.z_offset, t1.comment, t1.line) == (1, 6.0, 12.5, "6 mm flat end mill", 2)
    assert (t2.pocket, t2.line) == (5, 4)
    assert t3.z_offset == -1.25 and t3.offsets["X"] == 0.1 and t3.diameter == 3.175
    assert (t17.front_angle, t17.back_angle, t17.orientation) == (30.0, 60.0, 2)
    assert [table[k].guess_kind() for k in (1, 2, 3, 17)] == ["flat", "ball", "drill", "vbit"]
    tool = tool_from_entry(t2)
    assert (tool.kind, tool.diameter, tool.number) == ("ball", 6.0, 2)


def test_read_tool_table_inches(tmp_path):
    p = tmp_path / "in.tbl"
    p.write_text("T1 P1 D0.25 Z+1.0 A90 ;quarter inch\n")
    e = read_tool_table(p, units="inch")[1]
    assert e.diameter == pytest.approx(6.35) and e.z_offset == pytest.approx(25.4)
    assert e.offsets["A"] == 90.0  # angles are not scaled


@pytest.mark.parametrize("text, line, fragment", [
    ("T1 P1 D6\nT1 P2 D3\n", 2, "already defined on line 1"),
    ("T1 P1 D6\n\nP2 D3\n", 3, "missing T"),
    ("T1 P1 Dx6\n", 1, "bad word"),
    ("T1 P1 K6\n", 1, "unknown word K"),
    ("T1.5 P1\n", 1, "integer"),
    ("T1 P1 D-3\n", 1, "diameter"),
    ("T1 P1 D6 # oops\n", 1, "unexpected character"),
])
def test_tool_table_errors_name_file_and_line(tmp_path, text, line, fragment):
    p = tmp_path / "bad.tbl"
    p.write_text(text)
    with pytest.raises(InputError) as exc:
        read_tool_table(p)
    msg = str(exc.value)
    assert f"bad.tbl:{line}:" in msg and fragment in msg


def test_missing_tool_table_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="cannot read tool table"):
        read_tool_table(tmp_path / "nope.tbl")


def test_corpus_tool_tables_read(shared):
    tables = sorted((shared / "corpus" / "gcode" / "tooltables").glob("*.tbl"))
    assert tables
    for path in tables:
        table = read_tool_table(path, units="inch")
        assert table and all(e.diameter >= 0 for e in table.values())
    ball = read_tool_table(shared / "corpus/gcode/tooltables/parts_ball6.tbl", units="inch")[1]
    assert ball.diameter == pytest.approx(6.0, abs=1e-4) and ball.guess_kind() == "ball"
