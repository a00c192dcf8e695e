"""Material removal against analytic oracles, and the invariants of cutting."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.cut import Cutter
from sim.errors import InputError
from sim.frame import Frame
from sim.gcode.moves import MoveKind, Plane, empty_moves
from sim.grid import DexelGrid
from sim.tools import Tool, parse_tool_spec

SP = 0.25


def stock(x1=40.0, y1=20.0, z0=0.0, z1=10.0, sp=SP, x0=0.0, y0=0.0) -> DexelGrid:
    f = Frame.top(x0, y0, x1, y1, sp)
    return DexelGrid.from_intervals(f, np.full(f.shape, z0), np.full(f.shape, z1))


def moves_of(*rows) -> np.ndarray:
    """Rows of (kind, start xyz, end xyz[, center xyz]) -> a move table."""
    mv = empty_moves(len(rows))
    for k, row in enumerate(rows):
        mv["kind"][k] = row[0]
        mv["start"][k, :3] = row[1]
        mv["end"][k, :3] = row[2]
        if len(row) > 3:
            mv["center"][k] = row[3]
            mv["turns"][k] = 1
            mv["plane"][k] = Plane.XY
        mv["line"][k] = k + 1
    return mv


def dist_to_segment_2d(pts, a, b):
    a, b = np.asarray(a, float)[:2], np.asarray(b, float)[:2]
    d = b - a
    L2 = d @ d
    t = np.zeros(len(pts)) if L2 == 0 else np.clip(((pts[:, :2] - a) @ d) / L2, 0, 1)
    return np.linalg.norm(pts[:, :2] - (a + t[:, None] * d), axis=1)


def all_segments(g: DexelGrid):
    return g.segments_of(np.arange(g.frame.n_rays))


def same_model(a: DexelGrid, b: DexelGrid) -> bool:
    return all(np.array_equal(x, y) for x, y in zip(all_segments(a), all_segments(b)))


# --- analytic oracles ------------------------------------------------------------------

def test_flat_slot_volume_is_the_ray_columns_inside_the_stadium():
    g = stock()
    # the ray (8.25, 12.5) lies on the rim (3-4-5 from the start): the tool is closed, it is cut
    p0, p1 = (10.05, 10.1, 7.0), (30.05, 10.1, 7.0)
    removed = Cutter(g, parse_tool_spec("flat:6")).cut_segment(p0, p1, 1)
    pts = g.frame.ray_points().reshape(-1, 3)
    inside = dist_to_segment_2d(pts, p0, p1) <= 3 + 1e-9
    assert removed == pytest.approx(inside.sum() * 3.0 * SP**2, rel=1e-9)
    assert removed == pytest.approx(3 * (6 * 20 + math.pi * 9), rel=0.01)  # the continuous slot
    top = g.top().reshape(-1)
    np.testing.assert_array_equal(top[inside], 7.0)
    np.testing.assert_array_equal(top[~inside], 10.0)


def test_ball_groove_cross_section():
    g = stock()
    Cutter(g, parse_tool_spec("ball:6")).cut_segment((5, 10, 6), (35, 10, 6), 1)
    e = np.arange(g.frame.nv) * SP - 10.0
    col = g.top()[:, 80]  # x = 20
    inside = np.abs(e) <= 3  # rays on the rim meet the ball's equator
    want = np.minimum(10.0, 6 + 3 - np.sqrt(np.maximum(9 - e * e, 0)))
    np.testing.assert_allclose(col[inside], want[inside], atol=2e-6)
    np.testing.assert_array_equal(col[~inside], 10.0)


@pytest.mark.parametrize("step", [0.5, 1.0, 2.0])
def test_scallop_height_between_two_ball_passes(step):
    R = 3.0
    g = stock()
    c = Cutter(g, parse_tool_spec("ball:6"))
    c.cut_moves(moves_of((MoveKind.FEED, (5, 8, 6), (35, 8, 6)),
                         (MoveKind.FEED, (35, 8 + step, 6), (5, 8 + step, 6))))
    j_mid = int(round((8 + step / 2) / SP))
    ridge = g.top()[j_mid, 40:120]
    np.testing.assert_allclose(ridge, 6 + R - math.sqrt(R * R - (step / 2) ** 2), atol=2e-6)
    # the ridge is the highest point between the passes
    j0, j1 = int(round(8 / SP)), int(round((8 + step) / SP))
    assert g.top()[j0:j1 + 1, 40:120].max() == pytest.approx(ridge.max(), abs=2e-6)


def test_plunge_hole_volume():
    g = stock()
    c = Cutter(g, parse_tool_spec("flat:6"))
    p = (20.05, 10.1)  # (18.25, 12.5) and its mirrors lie on the rim (3-4-5): cut, the tool is closed
    res = c.cut_moves(moves_of((MoveKind.FEED, (*p, 12.0), (*p, 4.0))))
    pts = g.frame.ray_points().reshape(-1, 3)
    inside = np.hypot(pts[:, 0] - p[0], pts[:, 1] - p[1]) <= 3 + 1e-9
    assert res.removed[0] == pytest.approx(inside.sum() * 6.0 * SP**2, rel=1e-9)
    assert res.removed[0] == pytest.approx(math.pi * 9 * 6, rel=0.02)
    np.testing.assert_array_equal(np.sort(res.changed(0)), np.nonzero(inside)[0])


def test_ball_plunge_leaves_a_spherical_dimple():
    g = stock()
    Cutter(g, parse_tool_spec("ball:6")).cut_moves(moves_of((MoveKind.FEED, (20, 10, 15), (20, 10, 8))))
    pts = g.frame.ray_points()
    d2 = (pts[..., 0] - 20) ** 2 + (pts[..., 1] - 10) ** 2
    want = np.where(d2 < 9, np.minimum(10, 8 + 3 - np.sqrt(np.maximum(9 - d2, 0))), 10)
    np.testing.assert_allclose(g.top(), want, atol=2e-6)


def test_bull_nose_groove_profile():
    g = stock()
    Cutter(g, parse_tool_spec("bull:8:1.5")).cut_segment((5, 10, 5), (35, 10, 5), 1)
    e = np.abs(np.arange(g.frame.nv) * SP - 10.0)
    a = 4 - 1.5
    want = np.where(e <= a, 5.0, 5 + 1.5 - np.sqrt(np.maximum(1.5**2 - (e - a) ** 2, 0)))
    want = np.where(e <= 4, want, 10.0)
    np.testing.assert_allclose(g.top()[:, 80], np.minimum(want, 10.0), atol=2e-6)


def test_tilted_flat_end_mill_cut_matches_its_analytic_section():
    th = math.radians(20)
    axis = np.array([math.sin(th), 0, math.cos(th)])
    tip = np.array([20.0, 10.0, 7.0])
    g = stock()
    removed = Cutter(g, parse_tool_spec("flat:6:L=20")).cut_poses(tip, axis, 5)
    assert removed > 0
    pts = g.frame.ray_points().reshape(-1, 3)
    zp = tip[2] - (pts[:, 0] - tip[0]) * axis[0] / axis[2]
    foot = np.stack([pts[:, 0], pts[:, 1], zp], axis=1) - tip
    rho = np.linalg.norm(foot - (foot @ axis)[:, None] * axis, axis=1)
    on_disk = (rho < 3 - 1e-6) & (zp < 10)
    # the lowest material left on each of those rays ends on the bottom plane (on the far
    # side the ray leaves through the tool's flank below the stock top: material stays above)
    rays = np.nonzero(on_disk)[0]
    _, fars, _, _, counts = g.segments_of(rays)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    np.testing.assert_allclose(fars[first], zp[on_disk], atol=2e-6)
    assert (counts == 2).any() and (counts == 1).any()
    assert g.face_ids(80, 40)[0, 1] == 5


def test_undercut_from_below_leaves_two_segments_on_a_ray():
    # a T-slot cutter (head 10 mm x 2 mm, neck 2 mm) fed sideways into the stock at z 4..6
    tslot = Tool.custom([[0, 5], [2, 5], [2, 1], [20, 1]])
    g = stock()
    c = Cutter(g, tslot)
    v0 = g.volume()
    res = c.cut_moves(moves_of((MoveKind.FEED, (-8, 10, 4), (25, 10, 4))))
    i_lo, i_hi = int(2 / SP), int(18 / SP)
    e = np.abs(np.arange(g.frame.nv) * SP - 10)
    under_head = (e > 1.2) & (e < 4.8)
    for j in np.nonzero(under_head)[0]:
        for i in range(i_lo, i_hi, 7):
            segs = g.segments(i, j)
            np.testing.assert_allclose(segs, [[0, 4], [6, 10]], atol=1e-5)
            np.testing.assert_array_equal(g.face_ids(i, j), [[0, 1], [1, 0]])
    neck = e < 0.8
    for j in np.nonzero(neck)[0]:
        np.testing.assert_allclose(g.segments(40, j), [[0, 4]], atol=1e-5)
    assert (g.counts == 2).sum() > 1024  # more splits than the initial pool holds
    assert res.removed[0] == pytest.approx(v0 - g.volume(), rel=1e-9)


def test_full_circle_arc_cuts_an_annulus():
    g = stock()
    c = Cutter(g, parse_tool_spec("flat:6"))
    res = c.cut_moves(moves_of((MoveKind.ARC_CW, (25, 10, 7), (25, 10, 7), (20, 10, 7))))
    pts = g.frame.ray_points().reshape(-1, 3)
    r = np.hypot(pts[:, 0] - 20, pts[:, 1] - 10)
    top = g.top().reshape(-1)
    assert np.all(top[(r > 2.002) & (r < 7.998)] == 7.0)
    assert np.all(top[(r < 1.998) | (r > 8.002)] == 10.0)
    assert res.removed[0] == pytest.approx(3 * math.pi * (64 - 4), rel=0.02)


def test_arc_by_instances_agrees_with_the_exact_chords():
    flat_custom = Tool.custom([[0, 3], [24, 3]])  # a flat end mill the cutter must sweep by instances
    row = (MoveKind.ARC_CCW, (25, 10, 7), (20, 15, 6), (20, 10, 7))
    g1, g2 = stock(), stock()
    r1 = Cutter(g1, parse_tool_spec("flat:6")).cut_moves(moves_of(row))
    r2 = Cutter(g2, flat_custom).cut_moves(moves_of(row))
    assert r2.removed[0] == pytest.approx(r1.removed[0], rel=0.01)
    # instances 0.125 mm apart on a helix descending 1 mm over 7.9 mm: steps of 0.016 mm
    diff = np.abs(g1.top() - g2.top())
    assert (diff > 0.02).sum() < 0.02 * (g1.top() < 10).sum()  # beyond that only rim rays differ


def test_rows_that_are_not_motion_remove_nothing():
    g = stock()
    mv = moves_of(*[(k, (20, 10, 0), (20, 10, 0)) for k in (MoveKind.DWELL, MoveKind.TOOL_CHANGE,
                                                           MoveKind.PAUSE, MoveKind.END)])
    res = Cutter(g, parse_tool_spec("flat:6")).cut_moves(mv)
    assert not res.removed.any() and g.volume() == pytest.approx(40 * 20 * 10 + 0, rel=0.1)
    assert res.changed_ptr.tolist() == [0, 0, 0, 0, 0]


def test_tool_length_offset_is_taken_off_z():
    g = stock()
    mv = moves_of((MoveKind.FEED, (5, 10, 57), (35, 10, 57)))
    mv["tool_length"] = 50.0
    Cutter(g, parse_tool_spec("flat:6")).cut_moves(mv)
    assert g.top()[40, 80] == 7.0


def test_face_ids_default_to_row_index_plus_one_and_can_be_given():
    g = stock()
    mv = moves_of((MoveKind.FEED, (5, 5, 8), (35, 5, 8)), (MoveKind.FEED, (5, 15, 7), (35, 15, 7)))
    c = Cutter(g, parse_tool_spec("flat:4"))
    c.cut_moves(mv)
    assert g.face_ids(80, 20)[0, 1] == 1 and g.face_ids(80, 60)[0, 1] == 2
    g2 = stock()
    Cutter(g2, parse_tool_spec("flat:4")).cut_moves(mv, move_ids=[70, 71])
    assert g2.face_ids(80, 20)[0, 1] == 70 and g2.face_ids(80, 60)[0, 1] == 71
    with pytest.raises(InputError):
        c.cut_moves(mv, move_ids=[1])


def test_cut_moves_follows_the_tool_column():
    g = stock()
    mv = moves_of((MoveKind.FEED, (5, 5, 8), (35, 5, 8)), (MoveKind.FEED, (5, 15, 8), (35, 15, 8)))
    mv["tool"] = [1, 2]
    tools = {1: parse_tool_spec("flat:6"), 2: parse_tool_spec("flat:2")}
    res = Cutter(g, tools[1], tools=tools).cut_moves(mv)
    pts = g.frame.ray_points().reshape(-1, 3)
    for k, R in ((0, 3.0), (1, 1.0)):  # rays on the rim count: the cut reaches them
        n = (dist_to_segment_2d(pts, mv["start"][k], mv["end"][k]) <= R + 1e-9).sum()
        assert res.removed[k] == pytest.approx(n * 2.0 * SP**2, rel=1e-9)
    assert g.top()[20, 80] == 8.0 and g.top()[60, 80] == 8.0 and g.top()[60 + 6, 80] == 10.0


# --- probing ---------------------------------------------------------------------------

def test_probe_moves_measures_without_cutting():
    g = stock()
    c = Cutter(g, parse_tool_spec("ball:6"))
    mv = moves_of((MoveKind.FEED, (5, 10, 6), (35, 10, 6)),
                  (MoveKind.FEED, (5, 10, 6), (35, 10, 6)),       # the same again: probes the same
                  (MoveKind.ARC_CCW, (25, 10, 7), (15, 10, 7), (20, 10, 7)),
                  (MoveKind.RAPID, (5, 10, 30), (35, 10, 30)))     # above the stock
    before = [a.copy() for a in all_segments(g)]
    probed = c.probe_moves(mv)
    assert all(np.array_equal(a, b) for a, b in zip(before, all_segments(g)))
    for k in range(len(mv)):
        scratch = g.copy()
        want = Cutter(scratch, c.tool).cut_moves(mv[k:k + 1]).removed[0]
        assert probed[k] == pytest.approx(want, rel=1e-9, abs=1e-9)
    assert probed[0] == probed[1] > 0 and probed[3] == 0


def test_probe_with_the_shank_finds_contact_only_when_deep():
    tool = parse_tool_spec("flat:6:L=5:S=6:SL=20")
    g = stock()
    c = Cutter(g, tool)
    mv = moves_of((MoveKind.FEED, (20, 10, 12), (20, 10, 6)),   # flutes reach z 11: clear
                  (MoveKind.FEED, (20, 10, 12), (20, 10, 2)))   # shank from z 7: 3 mm in the stock
    shank = c.probe_moves(mv, body=tool.shank)
    assert shank[0] == 0.0
    assert shank[1] == pytest.approx(math.pi * 9 * 3, rel=0.03)


# --- invariants --------------------------------------------------------------------------

def test_repeating_a_move_changes_nothing():
    g = stock()
    c = Cutter(g, parse_tool_spec("ball:6"))
    mv = moves_of((MoveKind.FEED, (5, 5, 9), (35, 14, 5)), (MoveKind.ARC_CW, (30, 10, 6), (10, 10, 6), (20, 10, 6)))
    c.cut_moves(mv)
    snap = g.copy()
    res = c.cut_moves(mv)
    assert not res.removed.any() and res.changed_rays.size == 0
    assert same_model(g, snap)


def test_disjoint_moves_commute():
    a = (MoveKind.FEED, (5, 4, 7), (35, 6, 6))
    b = (MoveKind.FEED, (5, 15, 5), (35, 14, 8))
    g1, g2 = stock(), stock()
    t = parse_tool_spec("bull:6:1")
    Cutter(g1, t).cut_moves(moves_of(a, b), move_ids=[1, 2])
    Cutter(g2, t).cut_moves(moves_of(b, a), move_ids=[2, 1])
    assert same_model(g1, g2)


def test_changed_rays_are_exactly_the_rays_each_move_changed():
    g = stock(x1=80, y1=80, sp=0.2)  # > 65536 changed rays: the buffers grow mid-batch
    t = parse_tool_spec("flat:10")
    mv = moves_of(*[(MoveKind.FEED, (5, y, 8), (75, y, 8)) for y in np.arange(5, 76, 8.0)],
                  (MoveKind.FEED, (40, 5, 6), (40, 75, 6)))
    seq = g.copy()
    res = Cutter(g, t).cut_moves(mv)
    assert res.changed_ptr[-1] > 65536
    for k in range(len(mv)):
        before = seq.copy()
        Cutter(seq, t).cut_moves(mv[k:k + 1], move_ids=[k + 1])
        b, a = all_segments(before), all_segments(seq)
        changed = np.nonzero((b[4] != a[4]) | _per_ray_differs(before, seq))[0]
        np.testing.assert_array_equal(res.changed(k), changed)
    assert same_model(g, seq)


def _per_ray_differs(a: DexelGrid, b: DexelGrid) -> np.ndarray:
    ta, tb = a.top().reshape(-1), b.top().reshape(-1)
    return ~((ta == tb) | (np.isnan(ta) & np.isnan(tb)))


def _contained(old, new) -> bool:
    """Every segment of ``new`` lies inside a segment of ``old`` (both (k, 2))."""
    return all(any(o[0] <= n[0] + 1e-6 and n[1] <= o[1] + 1e-6 for o in old) for n in new)


tool_specs = st.sampled_from(["flat:4", "ball:6", "bull:6:1", "vbit:6:90"])
coords = st.tuples(st.floats(-2, 22), st.floats(-2, 12), st.floats(2, 14))


@settings(max_examples=25, deadline=None)
@given(tool_specs, st.lists(st.tuples(coords, coords), min_size=1, max_size=4))
def test_cutting_never_adds_material_and_is_idempotent(spec, segs):
    g = stock(x1=20, y1=10, sp=0.5, z0=2, z1=10)
    g.subtract(10, 10, 4, 5, move_id=99)  # one ray with two segments
    t = parse_tool_spec(spec)
    mv = moves_of(*[(MoveKind.FEED, a, b) for a, b in segs])
    before = g.copy()
    res = Cutter(g, t).cut_moves(mv)
    assert np.all(res.removed >= 0)
    assert res.removed.sum() == pytest.approx(before.volume() - g.volume(), abs=1e-6)
    for i, j in [(0, 0), (10, 10), (20, 5), (7, 13), (33, 20)]:
        if i < g.frame.nu and j < g.frame.nv:
            assert _contained(before.segments(i, j), g.segments(i, j))
    snap = g.copy()
    again = Cutter(g, t).cut_moves(mv)
    assert not again.removed.any() and same_model(g, snap)


def test_cutter_rejects_what_is_not_a_grid_or_a_tool():
    with pytest.raises(InputError):
        Cutter("grid", parse_tool_spec("flat:6"))
    with pytest.raises(InputError):
        Cutter(stock(), "flat:6")


@pytest.mark.parametrize("spec", ["ball:6", "flat:6", "flat:6:L=2", "ball:6:L=2", "bull:6:1"])
def test_chained_batch_equals_moves_cut_one_by_one(spec):
    # a batch lets a move skip the rays behind its start (the previous move cut them);
    # the result must be the same model as cutting the moves separately
    rng = np.random.default_rng(7)
    pts = np.cumsum(np.c_[rng.uniform(-0.8, 0.8, (120, 2)), rng.uniform(-0.3, 0.3, 120)], axis=0)
    pts += [20, 10, 7]
    rows = [(MoveKind.FEED, pts[k], pts[k + 1]) for k in range(len(pts) - 1)]
    mv = moves_of(*rows)
    t = parse_tool_spec(spec)
    g1, g2 = stock(), stock()
    Cutter(g1, t).cut_moves(mv)
    for k in range(len(mv)):
        Cutter(g2, t).cut_moves(mv[k:k + 1], move_ids=[k + 1])
    assert same_model(g1, g2)


@pytest.mark.parametrize("spec", ["flat:6", Tool.custom([[0, 3], [24, 3]])])
def test_moves_are_cut_in_program_order(spec):
    # an arc first, then a short line inside its swept region: the arc takes the
    # material and the line finds none; the faces carry the arc's id
    tool = parse_tool_spec(spec) if isinstance(spec, str) else spec
    g = stock()
    mv = moves_of((MoveKind.ARC_CCW, (25, 10, 7), (15, 10, 7), (20, 10, 7)),
                  (MoveKind.FEED, (20, 15, 7), (20.5, 15, 7)))
    res = Cutter(g, tool).cut_moves(mv)
    assert res.removed[0] > 0 and res.removed[1] < 0.01 * res.removed[0]
    assert g.face_ids(81, 60)[0, 1] == 1  # x 20.25, y 15: on the line, cut by the arc


def test_rays_along_y_are_cut_by_instances_of_motion():
    # a frame whose rays run along +Y (u = +X, v = d x u = -Z): no closed form applies,
    # the move is swept by instances; the slot volume agrees with the continuous one
    from sim.solids import box_grid

    frame = Frame(np.array([0.0, 0.0, 10.0]), np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0]),
                  SP, 161, 41)
    g = box_grid(frame, (0, 0, 0), (40, 20, 10))
    c = Cutter(g, parse_tool_spec("flat:6"))
    v0 = g.volume()
    res = c.cut_moves(moves_of((MoveKind.FEED, (10, 10, 7), (30, 10, 7))))
    assert res.removed[0] == pytest.approx(v0 - g.volume(), rel=1e-9)
    # per ray column: rays with 7 <= z <= 10 (13 of them) times the slot's chord along y
    x = np.arange(frame.nu) * SP
    dx = np.clip(np.maximum(10 - x, x - 30), 0, None)
    chord = np.where(dx < 3, 2 * np.sqrt(np.maximum(9 - dx * dx, 0)), 0.0)
    assert res.removed[0] == pytest.approx(13 * SP**2 * chord.sum(), rel=1e-3)
    # the ray at x = 20, z = 8 (j = 8) crosses the slot from y = 7 to 13: two segments remain
    np.testing.assert_allclose(g.segments(80, 8), [[0, 7], [13, 20]], atol=0.01)
    probed = c.probe_moves(moves_of((MoveKind.FEED, (10, 10, 5), (30, 10, 5))))
    assert probed[0] == pytest.approx(8 * SP**2 * chord.sum(), rel=1e-3)  # z 5 .. 6.75 left


def test_short_flutes_below_the_top_split_rays_and_the_pool_grows_mid_batch():
    # flutes 2 mm long fed 5 mm below the top: the exact kernel splits every ray it
    # reaches, more rays than the initial pool holds (the kernel stops, the pool grows, it
    # resumes where it stopped)
    g = stock()
    cap0 = g.store["pool_near"].size
    t = parse_tool_spec("flat:6:L=2")
    res = Cutter(g, t).cut_moves(moves_of((MoveKind.FEED, (2, 10.1, 5), (38, 10.1, 5))),
                                 move_ids=[3])
    assert g.store["pool_near"].size > cap0
    split = g.counts == 2
    assert split.sum() > cap0
    pts = g.frame.ray_points().reshape(-1, 3)
    inside = dist_to_segment_2d(pts, (2, 10.1), (38, 10.1)) < 3
    np.testing.assert_array_equal(split.reshape(-1), inside)
    np.testing.assert_allclose(g.segments(80, 40), [[0, 5], [7, 10]])
    np.testing.assert_array_equal(g.face_ids(80, 40), [[0, 3], [3, 0]])
    assert res.removed[0] == pytest.approx(inside.sum() * 2 * SP**2, rel=1e-9)
    assert res.changed_ptr[-1] == inside.sum()
