"""The error map's exact near-point search and per-ray reduction against brute force."""

import numpy as np
import pytest
import trimesh

from sim.checks.arrays import distinct
from sim.checks.error_map import DesignModel, ErrorMap
from sim.frame import Frame
from sim.grid import DexelGrid
from sim.tolerance import Tolerance


def brute_distance(tri_local, pts):
    """Closest distance from each point to any triangle, by trimesh over all triangles."""
    mesh = trimesh.Trimesh(vertices=tri_local.reshape(-1, 3), faces=np.arange(tri_local.shape[0] * 3).reshape(-1, 3),
                           process=False)
    _, dist, _ = trimesh.proximity.closest_point(mesh, pts)
    return dist


def bumpy_mesh():
    """A closed block 0..40 x 0..30 x 0..10 (12 big triangles) and a ball above it."""
    block = trimesh.creation.box(bounds=[(0, 0, 0), (40, 30, 10)])
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=6.0)
    sphere.apply_translation((20, 15, 17))  # clear of the block: two solids, parity = inside
    return trimesh.util.concatenate([block, sphere])


@pytest.fixture(scope="module")
def design():
    frame = Frame.top(0, 0, 40, 30, 0.5)
    return DesignModel(frame, bumpy_mesh())


def test_near_distance_equals_brute_force_inside_the_search_radius(design):
    rng = np.random.default_rng(5)
    pts = np.column_stack([rng.uniform(-3, 43, 400), rng.uniform(-3, 33, 400), rng.uniform(-2, 20, 400)])
    exact = brute_distance(design.tri, pts)
    got = design.distance(pts, 2.5)
    near = exact <= 2.5
    assert near.sum() > 100 and (~near).sum() > 20
    assert np.allclose(got[near], exact[near], atol=1e-9)
    assert np.all(np.isinf(got[~near]))
    # a seed triangle does not change the answer, only the work
    seeded = design.distance(pts, 2.5, seed=np.zeros(len(pts), np.int32))
    assert np.array_equal(seeded, got)


def test_large_triangles_across_the_frame_are_found_from_every_bin():
    # two triangles spanning a 100 mm frame diagonally, one far outside it, and 400 small
    # ones deep below so that the bins come out about 5 mm
    big = np.array([[[-5, -5, 1], [105, -5, 1], [105, 105, 3]],
                    [[-5, -5, 1], [105, 105, 3], [-5, 105, 1]],
                    [[300, 300, 0], [301, 300, 0], [300, 301, 0]]], float)
    x, y = np.meshgrid(np.arange(20) * 5.0, np.arange(20) * 5.0)
    small = np.stack([np.column_stack([x.ravel(), y.ravel(), np.full(400, -60.0)]),
                      np.column_stack([x.ravel() + 1, y.ravel(), np.full(400, -60.0)]),
                      np.column_stack([x.ravel(), y.ravel() + 1, np.full(400, -60.0)])], axis=1)
    tri = np.concatenate([big, small])
    mesh = trimesh.Trimesh(vertices=tri.reshape(-1, 3), faces=np.arange(tri.shape[0] * 3).reshape(-1, 3),
                           process=False)
    d = DesignModel(Frame.top(0, 0, 100, 100, 1.0), mesh, require_height_field=False)  # binning only
    bin_size, nbu, nbv, ptr, items = d._binned()
    assert nbu * nbv >= 100
    # each diagonal triangle lands in the bins it covers (about half and the diagonal), not
    # in all of them; the far one in the corner bin only
    per_tri = np.bincount(items, minlength=tri.shape[0])
    assert 0.45 * nbu * nbv < per_tri[0] < 0.75 * nbu * nbv and per_tri[2] == 1
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(0, 100, 300), rng.uniform(0, 100, 300), rng.uniform(-4, 8, 300)])
    exact = brute_distance(d.tri, pts)
    assert np.allclose(d.distance(pts, 50.0), exact, atol=1e-9)
    assert np.allclose(d.distance(pts, 4.0), np.where(exact <= 4.0, exact, np.inf), atol=1e-9)


def test_errors_refine_exactly_the_points_past_their_side_tolerance(design):
    f = design.frame
    rng = np.random.default_rng(7)
    rays = rng.integers(0, f.n_rays, 3000)
    s = rng.uniform(5, 18, rays.size)
    tol = Tolerance(gouge=0.01, undercut=0.3, interest=2.0)
    err, dv = design.errors(rays, s, tol, with_dv=True)
    hit = np.isfinite(dv)
    pts = np.column_stack([(rays % f.nu) * f.spacing, (rays // f.nu) * f.spacing, s])
    exact = brute_distance(design.tri, pts)
    inside = err < 0
    limit = np.where(inside, tol.gouge, tol.undercut)
    past = hit & (dv > limit)
    assert past.sum() > 500 and (hit & ~past).sum() > 50
    # refined points: the exact distance (when within the search radius of 3 mm)
    close = past & (exact <= 1.5 * tol.interest)
    assert np.allclose(np.abs(err[close]), exact[close], atol=1e-9)
    # points kept on the estimate are within their tolerance, and so is their true distance
    kept = hit & ~past
    assert np.all(np.abs(err[kept]) <= limit[kept] + 1e-12) and np.all(exact[kept] <= limit[kept] + 1e-9)
    # the verdict never differs from the exact distance's
    assert np.array_equal((np.abs(err) > limit)[hit], (exact > limit)[hit])
    # the sign is the side of the solid (points on the block's walls are on both)
    off = hit & (exact > 1e-6)
    assert np.array_equal(inside[off], bumpy_mesh().contains(pts[off]))


def reference_worst(pr, err, pid, ps, dv, is_far, n_rays):
    """The per-ray reduction as first written: near faces before far faces, lexsort."""
    order = np.concatenate([np.nonzero(is_far == 0)[0], np.nonzero(is_far == 1)[0]])
    pr, err, pid, ps, dv = pr[order], err[order], pid[order], ps[order], dv[order]
    out = {}
    for sign, key in ((1, "gouge"), (-1, "excess")):
        o = np.lexsort((sign * err, pr))
        first = np.ones(o.size, bool)
        first[1:] = pr[o][1:] != pr[o][:-1]
        sel = o[first]
        val = np.full(n_rays, np.nan)
        val[pr[sel]] = np.minimum(err[sel], 0) if sign == 1 else np.maximum(err[sel], 0)
        ids = np.zeros(n_rays, np.int32)
        ids[pr[sel]] = pid[sel]
        s = np.zeros(n_rays)
        s[pr[sel]] = ps[sel]
        ln = np.zeros(n_rays)
        ln[pr[sel]] = np.where(sign * err[sel] < 0, dv[sel], 0.0)
        out[key] = (val, ids, s, ln)
    return out


def test_update_keeps_the_worst_point_of_every_ray(design):
    f = design.frame
    rng = np.random.default_rng(3)
    # up to three disjoint segments per ray with face ids, ties in the error (rounded s)
    counts = rng.integers(0, 4, f.n_rays)
    seg_ray = np.repeat(np.arange(f.n_rays), counts)
    k = np.arange(seg_ray.size) - np.repeat(np.cumsum(counts) - counts, counts)  # index on its ray
    near = 4.0 + 5.0 * k + np.round(rng.uniform(0, 2, seg_ray.size), 1)
    far = near + np.round(rng.uniform(0.5, 2.5, seg_ray.size), 1)
    ids = rng.integers(0, 50, (seg_ray.size, 2)).astype(np.int32)
    grid = DexelGrid(f)
    grid._write_rays(np.arange(f.n_rays), counts, near.astype(np.float32), far.astype(np.float32), ids[:, 0], ids[:, 1])
    em = ErrorMap(f)
    tol = Tolerance(gouge=0.01, undercut=0.05)
    got = em.update(grid, design, np.arange(f.n_rays), tol, faces="all")
    nr, fr, ni, fi, c = grid.segments_of(np.arange(f.n_rays))
    pr = np.repeat(np.repeat(np.arange(f.n_rays), c), 2)
    ps = np.stack([nr, fr], 1).reshape(-1).astype(float)
    pid = np.stack([ni, fi], 1).reshape(-1)
    is_far = np.tile([0, 1], pr.size // 2)
    err, dv = design.errors(pr, ps, tol, with_dv=True)
    ref = reference_worst(pr, err, pid, ps, dv, is_far, f.n_rays)
    assert np.array_equal(got, distinct(pr))
    for key in ("gouge", "excess"):
        val, ids, s, ln = ref[key]
        assert np.array_equal(getattr(em, key), val, equal_nan=True)
        has = ~np.isnan(val)
        assert np.array_equal(getattr(em, key + "_id")[has], ids[has])
        assert np.array_equal(getattr(em, key + "_s")[has], s[has])
        assert np.array_equal(getattr(em, key + "_len")[has], ln[has])


@pytest.mark.parametrize("exact_excess", [True, False])
def test_update_of_cut_faces_on_a_window_is_the_reference_reduction_of_those_faces(design, exact_excess):
    """Faces a move made (id != 0) only, on a window of the design's frame mapped back to
    its rays (as look-ahead windows are), over a subset of rays given unsorted: the
    reference reduction of exactly those points."""
    f = design.frame
    i0, j0, i1, j1 = 10, 6, 70, 50
    wf = f.window(i0, i1, j0, j1)
    rng = np.random.default_rng(8)
    counts = rng.integers(0, 3, wf.n_rays)
    seg_ray = np.repeat(np.arange(wf.n_rays), counts)
    k = np.arange(seg_ray.size) - np.repeat(np.cumsum(counts) - counts, counts)
    near = 4.0 + 6.0 * k + np.round(rng.uniform(0, 3, seg_ray.size), 1)
    far = near + np.round(rng.uniform(0.5, 3.0, seg_ray.size), 1)
    ids = rng.integers(0, 4, (seg_ray.size, 2)).astype(np.int32)  # a quarter are stock faces (0)
    grid = DexelGrid(wf)
    grid._write_rays(np.arange(wf.n_rays), counts, near.astype(np.float32), far.astype(np.float32),
                     ids[:, 0], ids[:, 1])

    def to_full(r):
        return (r // wf.nu + j0) * f.nu + (r % wf.nu + i0)

    asked = rng.permutation(rng.integers(0, wf.n_rays, wf.n_rays // 2))
    tol = Tolerance(gouge=0.01, undercut=0.05)
    em = ErrorMap(wf)
    got = em.update(grid, design, asked, tol, design_rays=to_full, exact_excess=exact_excess)
    rays = distinct(asked)
    nr, fr, ni, fi, c = grid.segments_of(rays)
    pr = np.repeat(np.repeat(rays, c), 2)
    ps = np.stack([nr, fr], 1).reshape(-1).astype(float)
    pid = np.stack([ni, fi], 1).reshape(-1)
    is_far = np.tile([0, 1], pr.size // 2)
    keep = pid != 0
    pr, ps, pid, is_far = pr[keep], ps[keep], pid[keep], is_far[keep]
    err, dv = design.errors(to_full(pr), ps, tol, with_dv=True, exact_outside=exact_excess)
    ref = reference_worst(pr, err, pid, ps, dv, is_far, wf.n_rays)
    assert np.array_equal(got, distinct(pr)) and got.size < rays.size  # rays of stock faces only: none
    for key in ("gouge", "excess"):
        val, ids_, s_, ln = ref[key]
        assert np.array_equal(getattr(em, key), val, equal_nan=True)
        has = ~np.isnan(val)
        assert has.sum() > 500
        assert np.array_equal(getattr(em, key + "_id")[has], ids_[has])
        assert np.array_equal(getattr(em, key + "_s")[has], s_[has])
        assert np.array_equal(getattr(em, key + "_len")[has], ln[has])


@pytest.mark.parametrize("a", [[], [3], [5, 1, 5, 2, 2, 9, 1], np.random.default_rng(0).integers(0, 50, 500)])
def test_distinct_is_numpy_unique(a):
    a = np.asarray(a, np.int64)
    assert np.array_equal(distinct(a), np.unique(a))


# --- undercut regions (QA 5): range of interest, separate regions, worst point --------------

def _two_block_design():
    """Two closed blocks on a 60 x 50 stock with a margin: A 0..25 x 0..40, top z 15;
    B 35..60 x 0..40, top sloping from z 14.9 at X35 to z 14.5 at X60."""
    a = trimesh.creation.box(bounds=[(0, 0, 0), (25, 40, 15)])
    pts = [(x, y, 0) for x in (35, 60) for y in (0, 40)] + [(35, y, 14.9) for y in (0, 40)] \
        + [(60, y, 14.5) for y in (0, 40)]
    b = trimesh.convex.convex_hull(np.array(pts, float))
    return trimesh.util.concatenate([a, b])


def test_undercut_regions_are_separate_in_range_and_placed_at_their_worst_point():
    from sim.checks.checker import Checker
    from sim.checks.report import final_findings
    from sim.solids import box_grid
    from sim.tools import parse_tool_spec
    from tests.sim.checks.helpers import polyline

    frame = Frame.top(-5, -5, 65, 45, 0.5)
    stock = box_grid(frame, (-5, -5, 0), (65, 45, 20))
    ch = Checker(stock, parse_tool_spec("flat:6"), design=_two_block_design(), tol=Tolerance(gouge=0.01))
    assert ch.tol.undercut == 0.05  # the default t_h, not tied to t_l
    pts = [(-8, -8, 30), (-8, -8, 15.3)]
    for k, y in enumerate(np.arange(-8, 49, 4.0)):  # one raster pass faces everything at z 15.3
        xs = (-8, 68) if k % 2 == 0 else (68, -8)
        pts += [(xs[0], y, 15.3), (xs[1], y, 15.3)]
    ch.check_program(polyline(pts))
    und = [f for f in final_findings(ch) if f.kind == "undercut"]
    # the margin and the gap between the blocks are > 1 mm from the part: not assessed;
    # A (0.3 mm left) and B (0.4 .. 0.8 mm left) are two regions though one pass made both
    assert len(und) == 2, [str(f) for f in und]
    a, b = sorted(und, key=lambda f: f.position[0])
    assert a.depth == pytest.approx(0.3, abs=1e-3) and -0.01 <= a.position[0] <= 25.01
    assert a.area == pytest.approx(25.5 * 40.5, rel=0.05)
    assert b.depth == pytest.approx(0.8, abs=0.01)
    assert b.position[0] == pytest.approx(60, abs=0.6) and b.position[2] == pytest.approx(15.3, abs=1e-3)
    assert 0 <= b.position[1] <= 40


# --- gouges only: the material-left side on Huang's estimate (the live loop's fast path) ----

def test_errors_without_exact_outside_are_the_same_inside_and_the_estimate_outside(design):
    f = design.frame
    rng = np.random.default_rng(11)
    rays = rng.integers(0, f.n_rays, 3000)
    s = rng.uniform(5, 18, rays.size)
    tol = Tolerance(gouge=0.01, undercut=0.05, interest=2.0)
    exact, dv = design.errors(rays, s, tol, with_dv=True)
    fast, dv_fast = design.errors(rays, s, tol, with_dv=True, exact_outside=False)
    assert np.array_equal(dv_fast, dv)
    _, nz, inside, _ = design.vertical(rays, s)
    hit = np.isfinite(dv)
    assert (hit & inside).sum() > 300 and (hit & ~inside).sum() > 300
    # inside the design (gouges): bit for bit the exact path
    assert np.array_equal(fast[inside], exact[inside])
    # outside: the estimate dv |n.d|, on the same side; the exact path refined some of them
    out = hit & ~inside
    assert np.array_equal(fast[out], dv[out] * nz[out]) and np.all(fast[out] >= 0)
    assert not np.array_equal(fast[out], exact[out])
    assert np.array_equal(fast[~hit], exact[~hit])


def test_update_without_exact_excess_keeps_every_gouge_and_its_findings(design):
    f = design.frame
    rng = np.random.default_rng(4)
    counts = rng.integers(0, 4, f.n_rays)
    seg_ray = np.repeat(np.arange(f.n_rays), counts)
    k = np.arange(seg_ray.size) - np.repeat(np.cumsum(counts) - counts, counts)
    near = 4.0 + 5.0 * k + np.round(rng.uniform(0, 2, seg_ray.size), 1)
    far = near + np.round(rng.uniform(0.5, 2.5, seg_ray.size), 1)
    ids = rng.integers(0, 50, (seg_ray.size, 2)).astype(np.int32)
    grid = DexelGrid(f)
    grid._write_rays(np.arange(f.n_rays), counts, near.astype(np.float32), far.astype(np.float32), ids[:, 0], ids[:, 1])
    tol = Tolerance(gouge=0.01, undercut=0.05, interest=2.0)
    exact, fast = ErrorMap(f), ErrorMap(f)
    rays = np.arange(f.n_rays)
    assert np.array_equal(exact.update(grid, design, rays, tol, faces="all"),
                          fast.update(grid, design, rays, tol, faces="all", exact_excess=False))
    assert np.array_equal(fast.gouge, exact.gouge, equal_nan=True)
    g = np.nan_to_num(exact.gouge) < 0
    assert g.sum() > 100
    for key in ("gouge_id", "gouge_s", "gouge_len"):
        assert np.array_equal(getattr(fast, key)[g], getattr(exact, key)[g])
    lines = np.arange(60) * 10
    want = [x.to_json() for x in exact.findings(tol, lines, undercut=False, join=3.0)]
    assert want and [x.to_json() for x in fast.findings(tol, lines, undercut=False, join=3.0)] == want
    assert not np.array_equal(fast.excess, exact.excess, equal_nan=True)  # the estimate there


def test_checker_finds_the_same_while_cutting_without_the_exact_excess():
    """A ball raster polled in small batches over a part with a sloping top, partly too
    deep: the gouges found while cutting, the gouge map and the final assessment are the
    same whether the error map kept while cutting holds the exact material left or not."""
    from sim.checks.checker import Checker
    from sim.checks.report import final_findings
    from sim.solids import box_grid
    from sim.tools import parse_tool_spec
    from tests.sim.checks.helpers import polyline

    frame = Frame.top(-5, -5, 65, 45, 0.5)
    pts = [(-8, -8, 30), (-8, -8, 14.7)]
    for k, y in enumerate(np.arange(-8, 49, 2.0)):
        xs = (-8, 68) if k % 2 == 0 else (68, -8)
        pts += [(xs[0], y, 14.7), (xs[1], y, 14.7)]
    moves = polyline(pts)
    # pieces as the live loop cuts them: each row split in three
    pieces = np.repeat(moves, 3)
    a, b = np.repeat(moves["start"][:, :3], 3, axis=0), np.repeat(moves["end"][:, :3], 3, axis=0)
    third = np.tile([0.0, 1.0, 2.0], len(moves))[:, None] / 3
    pieces["start"][:, :3] = a + third * (b - a)
    pieces["end"][:, :3] = a + (third + 1 / 3) * (b - a)
    ids = np.repeat(np.arange(1, len(moves) + 1), 3)
    found, checkers = [], []
    for exact in (True, False):
        ch = Checker(box_grid(frame, (-5, -5, 0), (65, 45, 20)), parse_tool_spec("ball:6"),
                     design=_two_block_design(), tol=Tolerance(gouge=0.01), exact_excess_while_cutting=exact)
        during = []
        for a in range(len(pieces)):
            _, got = ch.cut_and_check(pieces[a:a + 1], move_ids=ids[a:a + 1])
            during += [x.to_json() for x in got]
        found.append(during)
        checkers.append(ch)
    assert sum(x["kind"] == "gouge" for x in found[0]) > 0
    assert found[1] == found[0]
    exact, fast = checkers
    assert np.array_equal(fast.error_map.gouge, exact.error_map.gouge, equal_nan=True)
    assert not np.array_equal(fast.error_map.excess, exact.error_map.excess, equal_nan=True)
    after = [[x.to_json() for x in final_findings(ch)] for ch in checkers]
    assert any(x["kind"] == "undercut" for x in after[0]) and after[1] == after[0]
