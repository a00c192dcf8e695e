"""Findings worth reading (issue 14): one cause is one finding, sizes are of the union,
``line`` is where the finding starts and ``worst_line`` where it is worst, every finding
tells its programmed point, contact point and time. Small analytic cases, no corpus."""

import json

import numpy as np
import pytest
import trimesh

from sim.checks import Checker, Fixture
from sim.checks.findings import Finding, merge_findings
from sim.checks.report import final_findings
from sim.frame import Frame
from sim.gcode.moves import MoveKind
from sim.solids import box_grid
from sim.tolerance import Tolerance
from sim.tools import parse_tool_spec
from tests.sim.checks.helpers import table

F, R = MoveKind.FEED, MoveKind.RAPID
SPACING = 0.5


def stock():
    return box_grid(Frame.top(0, 0, 60, 40, SPACING), (0, 0, 0), (60, 40, 20))


def slots(n, spindle=0.0):
    """``n`` short 1 mm deep slots along Y at X = 5, 10 ..., a rapid up and over between
    them: the cutting moves are never consecutive rows, and the slots are further apart
    than passes over one place."""
    rows = []
    for k in range(n):
        x = 5.0 + 5.0 * k
        rows += [(R, (x, 5, 25), (x, 5, 22)), (F, (x, 5, 22), (x, 5, 19)), (F, (x, 5, 19), (x, 15, 19)),
                 (R, (x, 15, 19), (x, 15, 25))]
    return table(rows, spindle=spindle)


def test_a_program_that_never_starts_the_spindle_is_one_finding_with_its_lines():
    m = slots(10)  # 20 feed moves cutting with the spindle off
    ch = Checker(stock(), parse_tool_spec("flat:2"))
    ch.check_program(m, batch=7)  # batches cut the runs apart too
    found = [f for f in final_findings(ch) if f.kind == "spindle_stopped_cutting"]
    assert len(found) == 1, [f.message for f in found]
    f = found[0]
    cutting = sorted(int(m["line"][k]) for k in range(len(m)) if m["kind"][k] == F)
    assert set(cutting) <= set(f.lines) and len(cutting) == 20
    assert f.line == min(f.lines)
    assert f"lines {f.lines[0]}-{f.lines[-1]}" in f.to_json()["message"]


def test_a_spindle_stopped_twice_is_two_findings():
    m = slots(6)
    m["spindle"][8:16] = 12000.0  # slots 3 and 4 cut with the spindle on
    m["spindle_dir"][8:16] = 1
    ch = Checker(stock(), parse_tool_spec("flat:2"))
    ch.check_program(m, batch=5)
    found = [f for f in final_findings(ch) if f.kind == "spindle_stopped_cutting"]
    assert len(found) == 2
    assert max(found[0].lines) < 90 < min(found[1].lines)


def rub(x, z, passes=3):
    """Back and forth along Y at X ``x``, tip at Z ``z``: ``passes`` moves over one place."""
    ys = [5.0, 35.0] * (passes // 2 + 1)
    rows = [(R, (x, 5, 100), (x, 5, z))]
    rows += [(F, (x, ys[k], z), (x, ys[k + 1], z)) for k in range(passes)]
    rows += [(R, (x, ys[passes], z), (x, ys[passes], 100))]
    return table(rows)


TOOL = "flat:6:L=20:S=6:H=30"  # holder: diameter 30 from 50 mm above the tip


def test_a_holder_rubbing_a_clamp_over_3_moves_is_one_finding_no_bigger_than_the_union():
    # the holder (radius 15, axis at X 75) overlaps the clamp X 62..70 between its bottom
    # (Z -20 + 50 = 30) and the clamp top 35: at most the slab 8 x 40 x 5 mm, on the grid
    # (rays count as cells of 0.5 mm: X 62..70 is 17 rays) 8.5 x 40.5 x 5 mm
    clamp = Fixture.box((62, 0, 0), (70, 40, 35), SPACING, name="clamp")
    ch = Checker(stock(), parse_tool_spec(TOOL), fixtures=[clamp])
    ch.cut_and_check(rub(75, -20))
    found = [f for f in final_findings(ch) if f.kind == "fixture_collision"]
    assert len(found) == 1, [f.message for f in found]
    f = found[0]
    assert "holder" in f.detail["group"] and len(f.stages) >= 3  # the rapid down too
    assert 0 < f.volume <= 8.5 * 40.5 * 5 + 1e-6


def test_many_passes_over_a_clamp_never_weigh_more_than_the_clamp():
    clamp = Fixture.box((62, 0, 0), (70, 40, 35), SPACING, name="clamp")
    ch = Checker(stock(), parse_tool_spec(TOOL), fixtures=[clamp])
    ch.check_program(rub(75, -20, passes=12), batch=4)
    (f,) = [f for f in final_findings(ch) if f.kind == "fixture_collision"]
    assert f.volume <= 8.5 * 40.5 * 5 + 1e-6


def test_a_holder_rubbing_a_wall_over_3_moves_is_one_contact_of_the_union():
    # holder axis at X 70: it overlaps the stock X 55..60 from its bottom (-35 + 50 = 15)
    # to the stock top 20, along Y 0..40: at most 5 x 40 x 5 mm (5.5 x 40.5 x 5 on the grid)
    ch = Checker(stock(), parse_tool_spec(TOOL))
    ch.cut_and_check(rub(70, -35))
    found = [f for f in final_findings(ch) if f.kind == "holder_contact"]
    assert len(found) == 1, [f.message for f in found]
    assert len(found[0].stages) >= 3
    assert 0 < found[0].volume <= 5.5 * 40.5 * 5 + 1e-6


def test_line_is_where_the_finding_starts_and_worst_line_where_it_is_worst():
    hits = [Finding(kind="rapid_into_stock", line=10 * s, stage=s, position=(s, 0, 0), depth=d, volume=1.0)
            for s, d in ((3, 0.5), (4, 1.5), (5, 0.2))]
    (f,) = merge_findings(hits)
    assert f.line == 30 and f.worst_line == 40 and f.stage == 4 and f.position == (4.0, 0.0, 0.0)
    j = json.loads(json.dumps(f.to_json()))
    assert j["line"] == 30 and j["worst_line"] == 40 and "lines 30-50" in j["message"]


def test_every_finding_tells_programmed_point_contact_point_and_time():
    m = table([(R, (10, 10, 30), (10, 10, 25)), (F, (10, 10, 25), (10, 10, 15)),
               (F, (10, 10, 15), (40, 10, 15)), (R, (40, 10, 15), (40, 10, 30)),
               (R, (40, 10, 30), (30, 20, 15))])  # line 50: a rapid into the stock
    ch = Checker(stock(), parse_tool_spec("flat:6"))
    ch.set_move_times(np.array([0.0, 1.0, 3.0, 7.0, 8.0]))  # start of each move, s
    ch.cut_and_check(m)
    (f,) = [f for f in final_findings(ch) if f.kind == "rapid_into_stock"]
    j = f.to_json()
    assert j["programmed"] == [30.0, 20.0, 15.0]     # the end of its line's move (tip)
    assert j["contact"] == j["position"] and j["contact"][2] == pytest.approx(20.0)  # where it met the stock
    assert j["time_s"] == pytest.approx(8.0) and j["stage"] == 5


def ball_raster(z, stepover, y0=0.0, y1=40.0):
    """Passes of a ball along X (past both ends of the stock) at tip height ``z``,
    ``stepover`` mm apart in Y from ``y0`` to ``y1`` (a zig-zag)."""
    rows = [(R, (-4, y0, 30), (-4, y0, z + 1)), (F, (-4, y0, z + 1), (-4, y0, z))]
    y, x, back = y0, -4.0, False
    while True:
        x1 = -4.0 if back else 64.0
        rows.append((F, (x, y, z), (x1, y, z)))
        x, back = x1, not back
        if y + stepover > y1 + 1e-9:
            break
        rows.append((F, (x, y, z), (x, y + stepover, z)))
        y += stepover
    rows.append((R, (x, y, z), (x, y, 30)))
    return table(rows)


def flat_design(tmp_path, top=15.0):
    """A block whose top is at ``top``, wider than the stock (every ray is over it)."""
    path = tmp_path / "part.stl"
    trimesh.creation.box(bounds=[(-10, -10, 0), (70, 50, top)]).export(path)
    return path


def raster_checker(tmp_path, z, **kw):
    # ball 6 at 1.6 mm stepover: scallops 3 - sqrt(9 - 0.8^2) = 0.109 mm high, over the
    # 0.05 mm undercut default; the path is right for its stepover
    ch = Checker(box_grid(Frame.top(0, 0, 60, 40, 0.25), (0, 0, 0), (60, 40, 16)), parse_tool_spec("ball:6"),
                 design=flat_design(tmp_path), **kw)
    ch.check_program(ball_raster(z, 1.6))
    return ch


def test_scallops_of_a_clean_raster_are_no_finding_at_the_default_tolerance(tmp_path):
    ch = raster_checker(tmp_path, 15.0)
    assert final_findings(ch) == []


def test_scallops_asked_for_with_an_undercut_tolerance_are_one_region(tmp_path):
    ch = raster_checker(tmp_path, 15.0, tol=Tolerance(undercut=0.05), undercut_from_path=False)
    und = [f for f in final_findings(ch) if f.kind == "undercut"]
    assert len(und) == 1, [f.message for f in und]
    assert und[0].depth == pytest.approx(0.109, abs=0.01)


def test_gouge_strips_of_one_raster_are_one_region(tmp_path):
    # the same raster 0.05 mm too deep: a gouge under each pass, the crests between them
    # above the part; one cause (the path is too deep), one finding
    ch = raster_checker(tmp_path, 14.95)
    gouges = [f for f in final_findings(ch) if f.kind == "gouge"]
    assert len(gouges) == 1, [f.message for f in gouges]
    g = gouges[0]
    assert g.depth == pytest.approx(0.05, abs=0.005)
    assert g.line == min(g.lines) and g.worst_line in g.lines
    assert f"lines {g.lines[0]}-{g.lines[-1]}" in g.to_json()["message"]


def test_a_holder_rubbing_a_wall_batch_after_batch_weighs_the_union():
    # the live monitor cuts what the tool travelled a poll at a time: one move a batch
    ch = Checker(stock(), parse_tool_spec(TOOL))
    m = rub(70, -35, passes=6)
    for k in range(len(m)):
        ch.cut_and_check(m[k:k + 1], move_ids=[k + 1])
    (f,) = [f for f in final_findings(ch) if f.kind == "holder_contact"]
    assert len(f.stages) >= 6 and 0 < f.volume <= 5.5 * 40.5 * 5 + 1e-6
