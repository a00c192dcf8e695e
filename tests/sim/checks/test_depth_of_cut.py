"""Depth of cut measured from the rays the real cut changed (the Checker's way) against
analytic depths and against the engagement walking every ray under the tool."""

import numpy as np
import pytest

from sim.checks import Checker, engagement, merge_findings, motion
from sim.cut import Cutter
from sim.frame import Frame
from sim.gcode.moves import MoveKind, Plane
from sim.solids import box_grid
from sim.tools import parse_tool_spec
from tests.sim.checks.helpers import polyline, table

F, R = MoveKind.FEED, MoveKind.RAPID


def stock(spacing=0.2):
    return box_grid(Frame.top(0, 0, 40, 40, spacing), (0, 0, 0), (40, 40, 10))


def wavy_path(rng, n=120):
    """A zig-zag of short feeds over the block at varying depth, a plunge and an arc."""
    pts = [(5.03, 5.01, 12.0), (5.03, 5.01, 8.0)]
    x, y = 5.0, 5.0
    for k in range(n):
        x = 5.0 + 30.0 * ((k // 20) % 2 == 0 and (k % 20) / 19 or 1 - (k % 20) / 19)
        y = 5.0 + 1.2 * (k // 20)
        # jittered so that no ray falls exactly on the tool's rim (where the cutter's
        # rounding decides whether it is reached)
        pts.append((x + rng.uniform(-0.05, 0.05), y + rng.uniform(-0.05, 0.05),
                    7.5 + 1.5 * np.sin(0.3 * k) + rng.uniform(-0.2, 0.2)))
    rows = [(F, pts[i], pts[i + 1]) for i in range(len(pts) - 1)]
    end = rows[-1][2]
    rows.append((MoveKind.ARC_CCW, end, (end[0] - 8.0, end[1], end[2] - 1.0),
                 {"center": (end[0] - 4.0, end[1], end[2]), "plane": int(Plane.XY), "turns": 1}))
    return table(rows)


@pytest.mark.parametrize("spec", ["flat:6", "ball:6", "bull:6:1"])
def test_changed_rays_give_the_depths_of_the_full_walk(spec):
    tool = parse_tool_spec(spec)
    m = wavy_path(np.random.default_rng(2))
    g = stock()
    full = engagement.Engagement(g.frame, g.top(), tool, chord=0.001)
    changed = engagement.Engagement(g.frame, g.top(), tool, chord=0.001)
    cutter = Cutter(g, tool)
    for a in range(0, len(m), 25):  # batches, as the live session feeds them
        part = m[a:a + 25]
        d_full, c_full = full.run(part)
        res = cutter.cut_moves(part, move_ids=np.arange(a + 1, a + len(part) + 1))
        d_chg, c_chg = changed.run(part, cut=res, grid=g)
        assert d_full.max() > 1.0
        # same depths: exact for the closed-form ends, within the sampled envelope else
        # (where the model's heights are taken after each batch)
        tol = 1e-6 if spec != "bull:6:1" else 0.05
        line = ~motion.is_arc(part)  # an arc's depth is its own lowest over all its chords there,
        # the full walk's the deepest step from one chord to the next: only lines compare
        assert np.allclose(d_chg[line], d_full[line], atol=tol), (a, np.abs(d_chg - d_full)[line].max())
        if spec != "bull:6:1":  # the full walk's own heights drift from the real bull's
            assert np.allclose(c_chg[line], c_full[line], atol=tol)
        assert np.all(d_chg[~line] >= d_full[~line] - tol)
    assert np.nanmax(np.abs(changed.top - g.top().reshape(-1))) < 1e-5


def test_checker_reports_a_slot_over_the_limit_as_one_finding_at_its_depth():
    tool = parse_tool_spec("flat:6")
    # plunge 3 mm into the 10 mm top, slot along X in 12 short moves, retract
    pts = [(5, 20, 12), (5, 20, 7)] + [(5 + 2.5 * k, 20, 7) for k in range(1, 13)] + [(35, 20, 12)]
    m = polyline(pts, kinds=[F] * 13 + [R])
    ch = Checker(stock(0.25), tool, max_depth_of_cut=2.0)
    for a in range(0, len(m), 5):
        ch.cut_and_check(m[a:a + 5], move_ids=np.arange(a + 1, min(a + 5, len(m)) + 1))
    found = [f for f in ch.all_findings() if f.kind == "depth_of_cut"]
    assert len(found) == 1
    f = found[0]
    assert f.depth == pytest.approx(3.0, abs=1e-6)
    assert f.lines == tuple(range(10, 140, 10))  # the plunge and every slot move, not the retract
    # a second pass along the same slot cuts nothing
    again = polyline([(5, 20, 7), (35, 20, 7)])
    _, batch = ch.cut_and_check(again, move_ids=[100])
    assert [x for x in batch if x.kind == "depth_of_cut"] == []


def test_ball_groove_depth_in_the_checker_is_analytic():
    ch = Checker(stock(0.25), parse_tool_spec("ball:6"), max_depth_of_cut=0.5)
    _, found = ch.cut_and_check(polyline([(5, 20, 9.2), (35, 20, 9.2)]))
    assert [(f.kind, f.line) for f in found] == [("depth_of_cut", 10)]
    assert found[0].depth == pytest.approx(0.8, abs=1e-6)


def test_runs_of_offending_moves_are_what_merging_single_findings_gives():
    m = polyline([(0, 0, 0)] + [(k, 0, 0) for k in range(1, 11)])
    doc = np.array([1, 6, 7, 6.5, 1, 9, 1, 6, 6, 1], float)
    ids = np.arange(101, 111)
    runs = engagement.depth_of_cut(m, doc, 5.0, ids)
    singles = []
    for k in np.nonzero(doc > 5.0)[0]:
        singles += engagement.depth_of_cut(m[k:k + 1], doc[k:k + 1], 5.0, ids[k:k + 1])
    merged = merge_findings(singles)
    key = [(f.lines, f.stages, f.line, f.worst_line, f.stage, f.depth, f.position) for f in runs]
    assert key == [(f.lines, f.stages, f.line, f.worst_line, f.stage, f.depth, f.position) for f in merged]
    # line: where the run starts; worst_line: its deepest move
    assert [f.depth for f in runs] == [7.0, 9.0, 6.0] and runs[0].line == 20 and runs[0].worst_line == 30


def test_look_ahead_on_a_window_finds_the_same_depth_and_leaves_the_model_alone():
    tool = parse_tool_spec("flat:6")
    m = polyline([(20, 20, 12), (20, 20, 6.5), (30, 25, 6.5), (30, 25, 12)], kinds=[F, F, R])
    ch = Checker(stock(0.25), tool, max_depth_of_cut=2.0)
    before = ch.grid.top().copy()
    ahead = [f for f in ch.predict(m) if f.kind == "depth_of_cut"]
    assert np.array_equal(ch.grid.top(), before, equal_nan=True)
    _, now = ch.cut_and_check(m)
    now = [f for f in now if f.kind == "depth_of_cut"]
    assert [(f.lines, f.depth) for f in ahead] == [(f.lines, f.depth) for f in now]
    assert now[0].depth == pytest.approx(3.5, abs=1e-6) and now[0].lines == (10, 20)


def sampled_depths(g, tool, part, heights, step=0.02):
    """Independent depth of cut of each line of ``part``: the tool's lowest height
    (``tool.lowest_height``) at tip positions every ``step`` mm along the move, on every
    ray of the grid, against the heights ``heights`` ((n_rays,) float64, lowered here)."""
    f = g.frame
    xs = f.origin[0] + np.arange(f.nu) * f.spacing
    ys = f.origin[1] + np.arange(f.nv) * f.spacing
    R = tool.cutting_radius
    out = np.zeros(len(part))
    for k in range(len(part)):
        p0 = np.array(part["start"][k, :3], float)
        p1 = np.array(part["end"][k, :3], float)
        if np.hypot(*(p1 - p0)[:2]) < 1e-9:  # a plunge: its lowest position is all that counts
            pts = (p0 if p0[2] < p1[2] else p1)[None, :]
        else:
            n = int(np.ceil(np.linalg.norm(p1 - p0) / step)) + 1
            pts = p0 + np.linspace(0.0, 1.0, n)[:, None] * (p1 - p0)
        i = np.nonzero((xs >= pts[:, 0].min() - R) & (xs <= pts[:, 0].max() + R))[0]
        j = np.nonzero((ys >= pts[:, 1].min() - R) & (ys <= pts[:, 1].max() + R))[0]
        X, Y = np.meshgrid(xs[i], ys[j])
        d = np.hypot(X.reshape(-1, 1) - pts[:, 0], Y.reshape(-1, 1) - pts[:, 1])
        low = np.nanmin(np.where(d <= R, pts[:, 2] + np.nan_to_num(tool.lowest_height(np.minimum(d, R)),
                                                                    nan=np.inf), np.inf), axis=1)
        rays = (j[:, None] * f.nu + i[None, :]).reshape(-1)
        cut = heights[rays] - low
        out[k] = max(float(np.max(cut, initial=0.0)), 0.0)
        heights[rays] = np.minimum(heights[rays], low)
    return out


@pytest.mark.parametrize("spec", ["flat:6", "ball:6", "bull:6:1"])
def test_depth_of_cut_from_the_cut_log_equals_the_full_walk(spec):
    """The Checker's depth of cut (largest ``changed_depth`` of each move) against the
    engagement walking every ray under the tool (flat, ball: the same closed forms) or
    the tool sampled every 20 um along each line (bull-nose), batch after batch."""
    tool = parse_tool_spec(spec)
    m = wavy_path(np.random.default_rng(3), n=40)
    g = stock()
    full = engagement.Engagement(g.frame, g.top(), tool, chord=0.001)
    heights = g.top().reshape(-1).astype(np.float64)
    cutter = Cutter(g, tool)
    for a in range(0, len(m), 30):
        part = m[a:a + 30]
        line = ~motion.is_arc(part)
        if spec == "bull:6:1":
            want = sampled_depths(g, tool, part[line], heights)
            d_full, _ = full.run(part)
        else:
            d_full, _ = full.run(part)
            want = d_full[line]
        doc = engagement.depth_of_cut_of(cutter.cut_moves(part))
        assert doc.shape == (len(part),) and doc.dtype == np.float64
        # float32 faces; sampling misses the true lowest point by up to ~1 um
        tol = 1e-5 if spec != "bull:6:1" else 2e-3
        assert doc[line].max() > 0.5
        assert np.allclose(doc[line], want, atol=tol), np.abs(doc[line] - want).max()
        assert np.all(doc[~line] >= d_full[~line] - 1e-5)
        full.top = g.top().reshape(-1).astype(np.float64)  # the walk follows the model
        heights = full.top.copy()


def test_depth_of_cut_below_an_overhang_is_the_length_taken_off():
    """A T-slot cutter under a ledge: the top stays, the depth is what the cut removed."""
    from sim.tools import Tool

    g = stock(0.25)
    # a slot 4..6 mm high under a roof, open up through the roof along the neck's path
    for j in range(64, 97):
        for i in range(g.frame.nu):
            g.subtract(i, j, 4.0, 10.0 if abs(j * 0.25 - 20.0) <= 1.2 else 6.0, move_id=99)
    tslot = Tool.custom([[0, 3], [1.5, 3], [1.5, 1], [20, 1]])
    m = polyline([(5, 20, 3.5), (35, 20, 3.5)])  # disc 3.5..5 mm: takes 3.5..4 off each ray
    doc = engagement.depth_of_cut_of(Cutter(g, tslot).cut_moves(m))
    assert doc[0] == pytest.approx(0.5, abs=1e-5)
    assert np.nanmax(g.top()) == pytest.approx(10.0)


def test_depth_of_cut_of_a_cut_without_changes_is_zero_and_checks_its_input():
    g = stock(0.25)
    res = Cutter(g, parse_tool_spec("flat:6")).cut_moves(polyline([(5, 20, 12), (35, 20, 12)]))
    assert np.array_equal(engagement.depth_of_cut_of(res), [0.0])
    res = Cutter(g, parse_tool_spec("flat:6")).cut_moves(polyline([(5, 20, 9), (35, 20, 9)]))
    res.changed_depth = res.changed_depth[:-1]
    with pytest.raises(Exception, match="depths"):
        engagement.depth_of_cut_of(res)
