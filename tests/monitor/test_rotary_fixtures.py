"""Fixtures on a rotary table turn with the part (``[[fixtures]] on_table``, default true
when the kinematics has a table): a clamp clear of the tool at A0 is turned into its
path at A90, and one in the path at A0 is turned out of it; a fixture bolted to the
machine (``on_table = false``) stays where it is given."""

from __future__ import annotations

import json

import pytest

from monitor.cli import main
from monitor.job import JobError, parse_job_text

#: a 25 mm bar on an A axis along X (xyza: A = +90 turns the part's +Y to +Z)
JOB = """work_offset = [0, 0, 0]
resolution = 0.5
[program]
path = "{program}"
dialect = "linuxcnc"
[machine]
kinematics = "xyza"
rot_point = [0, 0, 0]
[stock]
cylinder = [0, 0, 12.5, 0, 60]
axis = "x"
[tools]
1 = "flat:2:L=8"
[[fixtures]]
name = "clamp"
box = {clamp}
{extra}
"""
#: beside the bar on its +Y side at A0 (the tool above the bar misses it) ...
SIDE = "[50, 13, -2, 55, 17, 2]"
#: ... and on top of it (in the way of a tool coming down at Y0)
TOP = "[50, -2, 13, 55, 2, 17]"
#: the tool comes down over the clamp's X at A0 to 2.5 mm above the bar, then A turns to 90
TURN_UNDER_TOOL = "G21 G90 G94\nT1 M6\nM3 S10000\nG0 Z30\nG0 X52 Y0\nG1 Z15 F300\nG1 A90 F900\nG0 Z30\nM5\nM2\n"
#: A turns to 90 first, up high, then the tool comes down there
TURN_THEN_DOWN = "G21 G90 G94\nT1 M6\nM3 S10000\nG0 Z30\nG0 A90\nG0 X52 Y0\nG1 Z15 F300\nG0 Z30\nM5\nM2\n"


def fixture_findings(tmp_path, capsys, program: str, clamp: str, extra: str = ""):
    (tmp_path / "p.nc").write_text(program)
    (tmp_path / "job.toml").write_text(JOB.format(program="p.nc", clamp=clamp, extra=extra))
    main(["simulate", str(tmp_path / "job.toml"), "--json"])
    doc = json.loads(capsys.readouterr().out)
    return [(f["kind"], f["line"]) for f in doc["findings"] if f["kind"] == "fixture_collision"]


def test_a_clamp_on_the_table_turned_into_the_tool(tmp_path, capsys):
    # line 7 (G1 A90) turns the clamp from beside the bar into the standing tool
    assert fixture_findings(tmp_path, capsys, TURN_UNDER_TOOL, SIDE) == [("fixture_collision", 7)]


def test_a_clamp_on_the_table_turned_out_of_the_way(tmp_path, capsys):
    # at A0 the clamp sits where the tool comes down; turned to A90 first, it is not there
    assert fixture_findings(tmp_path, capsys, TURN_THEN_DOWN, TOP) == []


def test_a_fixture_fixed_to_the_machine_does_not_turn(tmp_path, capsys):
    off = "on_table = false"
    assert fixture_findings(tmp_path, capsys, TURN_UNDER_TOOL, SIDE, off) == []
    assert fixture_findings(tmp_path, capsys, TURN_THEN_DOWN, TOP, off) == [("fixture_collision", 7)]


def test_on_table_errors():
    base = '[machine]\nkinematics = "xyza"\n[[fixtures]]\nbox = [0, 0, 0, 1, 1, 1]\n'
    assert parse_job_text(base).fixtures[0].on_table is None
    job = parse_job_text(base)
    assert job.fixture_on_table(job.fixtures[0])
    assert not parse_job_text(base + "on_table = false\n").fixtures[0].on_table
    with pytest.raises(JobError, match=r"\[\[fixtures\]\] #1 on_table: expected true .* or false .*, got \"yes\""):
        parse_job_text(base + 'on_table = "yes"\n')
    with pytest.raises(JobError, match=r"\[\[fixtures\]\] #1 on_table: kinematics 'xyzbc-head' has no rotary table"):
        parse_job_text('[machine]\nkinematics = "xyzbc-head"\n[[fixtures]]\nbox = [0, 0, 0, 1, 1, 1]\n'
                       "on_table = true\n")
    with pytest.raises(JobError, match=r"\[\[fixtures\]\] #1: unknown key 'rides'; expected one of .*on_table"):
        parse_job_text(base + 'rides = "A"\n')
    # a plain 3-axis machine: the fixture is fixed
    job = parse_job_text("[[fixtures]]\nbox = [0, 0, 0, 1, 1, 1]\n")
    assert not job.fixture_on_table(job.fixtures[0])


def test_a_fixture_fixed_on_a_head_machine_meets_the_tilted_tool():
    """On a head-head machine nothing turns the part: a fixture sees the head's tilt. A
    tool tilted B = 90 (5axiskins: the tip swung toward +X, 50 + 20 mm from the pivot,
    50 mm above the gauge point) reaches a block 70 mm in +X that the vertical tool's X Y Z
    never come near; B = 0 at the same X Y Z misses it."""
    from sim.checks.collisions import Fixture
    from sim.gcode.moves import MoveKind, empty_moves
    from sim.kinematics import HeadHead, head_only
    from sim.tools import parse_tool_spec

    kin = HeadHead("B", pivot_length=50.0)
    assert head_only(kin).rotaries == ("C", "B") and head_only(kin).pivot_length == 50.0
    # the rows' tips at Z20, the tool 20 long: the gauge point at Z40, the pivot at Z90;
    # at B90 the tip is pivot - 70 k, k = (-1, 0, 0): X70 Z90
    clamp = Fixture.box((66, -5, 85), (76, 5, 95), 0.5, name="block")
    clamp = Fixture(clamp.name, clamp.grid, kinematics=kin)
    tool = parse_tool_spec("flat:4:L=10")
    moves = empty_moves(2)
    moves["kind"] = MoveKind.FEED
    moves["start"] = [[0, -10, 20, 0, 90, 0], [0, -10, 20, 0, 0, 0]]  # tips (tool_length 0 ...
    moves["end"] = [[0, 10, 20, 0, 90, 0], [0, 10, 20, 0, 0, 0]]
    moves["tool"] = 1
    moves["line"] = [5, 6]
    # ... with its 20 mm given per tool: the gauge point is 20 mm above the rows' Z
    clamp.tool_lengths = {1: 20.0}
    found = clamp.check(moves, tool)
    assert [(f.kind, f.line) for f in found] == [("fixture_collision", 5)]
    # without the head's tilt (the fixture as it was: 3-axis) the tool misses it
    assert Fixture(clamp.name, clamp.grid).check(moves, tool) == []
