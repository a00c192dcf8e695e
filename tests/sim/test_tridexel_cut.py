"""Cutting a tri-dexel model (sim.tridexel.TriCutter): analytic oracles read on all three
grids (a flat end mill tilted 30 degrees slotting, a groove wrapped round a bar on the A
axis, a full A turn facing the bar down, a ball on a 5-axis swarf-like pass against the
union of its instances), and the model's invariants (the grids agree on every node away
from the surface, a repeated move changes nothing, a cut never adds material, the three
volumes agree, each grid is bit for bit what a lone Cutter makes of it)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.cut import Cutter
from sim.errors import InputError
from sim.kinematics import FourthAxis, HeadHead
from sim.tools import parse_tool_spec
from sim.tridexel import AXES, TriCutter, TriDexel
from tests.sim.test_rotary_cut import planned, polygon_slack, rows

SPACING = 0.25
R = 8.0  # bar radius, mm, on the A axis


# --- reading the model ------------------------------------------------------------------

def ray_segments(model: TriDexel, axis: str, point) -> np.ndarray:
    """Segments (k, 2) (mm along the ray) of grid ``axis``'s ray through the lattice node
    nearest ``point`` (world mm; the coordinate along the ray is ignored)."""
    g = model.grids[axis]
    local = g.frame.to_local(np.asarray(point, np.float64))
    i, j = (int(round(c / model.spacing)) for c in local[:2])
    return g.segments(i, j)


def node(model: TriDexel, value: float, axis: int) -> float:
    """The lattice coordinate nearest ``value`` along world ``axis`` (0 1 2), mm."""
    return model.lo[axis] + round((value - model.lo[axis]) / model.spacing) * model.spacing


def occupancy(model: TriDexel) -> dict[str, np.ndarray]:
    """``{axis: bool (nx, ny, nz)}``: each node inside the material as that grid's ray
    through it reads it (closed segments)."""
    nx, ny, nz = model.shape
    along = {"x": (0, nx), "y": (1, ny), "z": (2, nz)}
    out = {}
    for a, g in model.grids.items():
        d, n = along[a]
        near, far, _, _, counts = g.segments_of(np.arange(g.frame.n_rays))
        k0 = np.ceil((near.astype(np.float64) - model.lo[d]) / model.spacing - 1e-9).clip(0, n)
        k1 = np.floor((far.astype(np.float64) - model.lo[d]) / model.spacing + 1e-9).clip(-1, n - 1) + 1
        ray = np.repeat(np.arange(g.frame.n_rays), counts)
        marks = np.zeros((g.frame.n_rays, n + 1), np.int32)
        ok = k1 > k0
        np.add.at(marks, (ray[ok], k0[ok].astype(np.int64)), 1)
        np.add.at(marks, (ray[ok], k1[ok].astype(np.int64)), -1)
        inside = np.cumsum(marks, axis=1)[:, :n] > 0  # (rays, along)
        inside = inside.reshape(g.frame.nv, g.frame.nu, n)  # [iv, iu, along]
        if a == "z":    # iu = i, iv = j
            out[a] = inside.transpose(1, 0, 2)
        elif a == "x":  # iu = j, iv = k
            out[a] = inside.transpose(2, 1, 0)
        else:           # iu = k, iv = i
            out[a] = inside.transpose(0, 2, 1)
    return out


def nodes(model: TriDexel) -> np.ndarray:
    """World coordinates of every node, float64 (nx, ny, nz, 3)."""
    axes = [model.lo[d] + model.spacing * np.arange(model.shape[d]) for d in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)


def boundary(occ: np.ndarray, reach: int = 1) -> np.ndarray:
    """Nodes within ``reach`` lattice steps (each way) of a node whose occupancy differs."""
    edge = np.zeros_like(occ)
    for d in range(3):
        diff = np.diff(occ, axis=d)
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[d] = slice(0, -1)
        hi[d] = slice(1, None)
        edge[tuple(lo)] |= diff
        edge[tuple(hi)] |= diff
    for _ in range(reach):
        grown = edge.copy()
        for d in range(3):
            grown[tuple(slice(1, None) if e == d else slice(None) for e in range(3))] |= \
                edge[tuple(slice(0, -1) if e == d else slice(None) for e in range(3))]
            grown[tuple(slice(0, -1) if e == d else slice(None) for e in range(3))] |= \
                edge[tuple(slice(1, None) if e == d else slice(None) for e in range(3))]
        edge = grown
    return edge


def assert_grids_agree(model: TriDexel) -> dict[str, np.ndarray]:
    """The invariant: a node's inside/outside reads the same from its x-, y- and z-ray
    except within one lattice step of a face (where one ray holds the face the others
    pass beside). Returns the occupancies."""
    occ = occupancy(model)
    agree = (occ["x"] == occ["y"]) & (occ["y"] == occ["z"])
    near_face = boundary(occ["x"]) | boundary(occ["y"]) | boundary(occ["z"])
    assert not np.any(~agree & ~near_face), np.argwhere(~agree & ~near_face)[:5]
    return occ


def assert_same_grid(a, b) -> None:
    rays = np.arange(a.frame.n_rays)
    for x, y in zip(a.segments_of(rays), b.segments_of(rays)):
        assert np.array_equal(x, y)


def assert_only_removed(before: TriDexel, after: TriDexel) -> None:
    """A cut never adds material: every segment after lies within one before, on every ray."""
    for a in AXES:
        g0, g1 = before.grids[a], after.grids[a]
        rays = np.arange(g0.frame.n_rays)
        n0, f0, _, _, c0 = g0.segments_of(rays)
        n1, f1, _, _, c1 = g1.segments_of(rays)
        owner0 = np.repeat(rays, c0)
        for r, lo, hi in zip(np.repeat(rays, c1), n1, f1):
            first = np.searchsorted(owner0, r)
            last = np.searchsorted(owner0, r, side="right")
            assert np.any((n0[first:last] <= lo) & (f0[first:last] >= hi)), (a, r, lo, hi)


# --- stock ------------------------------------------------------------------------------

def test_stock_constructors_hold_the_solid_on_all_three_grids():
    """Box, cylinder on the A axis and closed mesh: nodes half a spacing inside the faces,
    an empty margin round the solid, the three volumes of one solid."""
    box = TriDexel.box((0, 0, 0), (10, 20, 5), 0.5)
    assert np.allclose(box.lo, [-0.75, -0.75, -0.75]) and np.allclose(box.hi, [10.75, 20.75, 5.75])
    assert all(v == pytest.approx(1000.0, abs=1e-6) for v in box.volumes().values())
    assert_grids_agree(box)
    bar = TriDexel.cylinder(0.0, 30.0, R, SPACING, center=(1.0, -2.0))
    assert np.allclose(bar.lo[1:] + SPACING * np.round((np.array([1.0, -2.0]) - bar.lo[1:]) / SPACING),
                       [1.0, -2.0])  # a row of nodes on the axis
    want = math.pi * R * R * 30.0
    # a disc sampled at the nodes: the area error is about the rim's length x spacing / 4
    assert all(abs(v - want) < 2 * math.pi * R * 30.0 * SPACING / 4 for v in bar.volumes().values())
    seg = ray_segments(bar, "z", (15.125, 1.0, 0.0))
    assert np.allclose(seg, [[-2.0 - R, -2.0 + R]], atol=4e-6)
    trimesh = pytest.importorskip("trimesh")
    mesh = trimesh.creation.box(extents=(10, 20, 5))
    solid = TriDexel.mesh(mesh, 0.5)
    assert all(v == pytest.approx(1000.0, abs=1e-3) for v in solid.volumes().values())
    with pytest.raises(InputError, match="margin"):
        TriDexel.box((0, 0, 0), (1, 1, 1), 0.5, margin=-1.0)


# --- analytic oracles -------------------------------------------------------------------

def test_tilted_flat_mill_slot_section_is_the_projected_cylinder():
    """A flat end mill (r 3, L 20) leaning 30 degrees toward its feed (an xyzbc-head at
    B = 30) slots along X at a constant tip height. The slot's section square to the feed
    is the cylinder projected along X: its end disc projects to a half-ellipse of
    semi-axes r (across, Y) and r sin 30 = r cos 60 (Z; 60 degrees between the axis and
    the feed), under straight walls at y = +-r. The X grid (rays along the feed) reads
    the whole section: a ray is emptied exactly when it lies inside it; the Z grid reads
    the floor (the half-ellipse, never below it, above it by at most the instance step);
    the Y grid the walls."""
    r, fl, tz = 3.0, 20.0, -2.0
    tool = parse_tool_spec(f"flat:{2 * r}:L={fl}")
    model = TriDexel.box((0, -6, -6), (12, 6, 0), SPACING)
    kin = HeadHead("B")
    poses = np.zeros((2, 6))
    poses[:, 4] = 30.0
    poses[:, :3] = kin.machine_xyz(np.array([[-5.0, 0, tz], [17.0, 0, tz]]), poses[:, 3:], 0.0)
    before = model.copy()
    TriCutter(model, tool, kinematics=kin).cut_moves(rows(poses[0], poses[1]))
    _, k = kin.forward(poses[:1], 0.0)
    assert abs(k[0, 1]) < 1e-12 and abs(abs(k[0, 0]) - 0.5) < 1e-12  # leaning along the feed
    b = r * abs(k[0, 0])  # the end disc's projected semi-axis along Z
    step = 0.5 * SPACING

    def floor(y):  # lowest point of the section at y (|y| <= r)
        return tz - b * np.sqrt(np.clip(1 - (y / r) ** 2, 0, None))

    # X grid: inside the section (more than a spacing from its edge) empty, outside whole
    checked = 0
    for y in np.arange(-5.875, 5.9, SPACING):
        for z in np.arange(-5.875, 0, SPACING):
            seg = ray_segments(model, "x", (0, y, z))
            inside = abs(y) < r and z > floor(y)
            margin = min(r - abs(y), z - floor(y)) if inside else max(abs(y) - r, floor(y) - z)
            if margin < SPACING:
                continue
            assert (len(seg) == 0) if inside else np.allclose(seg, [[0, 12]], atol=4e-6), (y, z, seg)
            checked += inside
    assert checked > 100
    # Z grid: the floor; Y grid: the walls, at stations along the slot
    for x in (3.125, 6.125, 8.875):
        for y in np.arange(-2.875, 2.9, SPACING):
            seg = ray_segments(model, "z", (x, y, 0))
            assert len(seg) == 1 and seg[0, 0] == pytest.approx(-6, abs=4e-6), (x, y, seg)
            assert floor(y) - 4e-6 <= seg[0, 1] <= floor(y) + step, (x, y, seg, floor(y))
        for z in np.arange(-1.375, 0, SPACING):
            seg = ray_segments(model, "y", (x, 0, z))
            assert len(seg) == 2 and np.allclose([seg[0, 0], seg[1, 1]], [-6, 6], atol=4e-6), (x, z, seg)
            # between instances the wall stands in by (dx cos 30)^2 / 2r at most
            slack = (step * math.sqrt(3) / 4) ** 2 / (2 * r) + 4e-6
            assert -r - 4e-6 <= seg[0, 1] <= -r + slack and r - slack <= seg[1, 0] <= r + 4e-6, (x, z, seg)
    assert_grids_agree(model)
    assert_only_removed(before, model)


def test_groove_round_a_bar_is_equally_deep_all_round_on_every_grid():
    """A flat mill at a fixed Z over the A axis, A turning 360: the groove's floor is the
    circle of the tip's height at every angle, read on the Y grid (angles near 0 and
    180 degrees) and the Z grid (near 90 and 270); on the X grid the rays between the
    floor and the bar's skin are cut between the tool's flat sides x = 15 -+ r."""
    tool = parse_tool_spec("flat:6:L=20")
    model = TriDexel.cylinder(0.0, 30.0, R, SPACING)
    kin = FourthAxis("A")
    depth = 2.5
    rho = R - depth
    moves = rows([15, 0, rho, 0, 0, 0], [15, 0, rho, 360, 0, 0])
    tri = TriCutter(model, tool, kinematics=kin)
    tri.cut_moves(moves)
    slack = polygon_slack(rho, planned(tri.cutters["z"], moves))
    x = 15.125  # a node in the groove, 0.125 from its middle: the flat bottom is all there
    radii = []
    for c in np.arange(-0.7 * rho, 0.7 * rho + 1e-9, SPACING):
        across = node(model, c, 1)
        z_seg = ray_segments(model, "z", (x, across, 0))
        y_seg = ray_segments(model, "y", (x, 0, across))
        for seg in (z_seg, y_seg):
            assert len(seg) == 1, (c, seg)
            radii += [math.hypot(across, seg[0, 0]), math.hypot(across, seg[0, 1])]
    radii = np.array(radii)
    assert len(radii) > 100
    assert np.all(radii >= rho - 4e-6) and np.all(radii <= rho + slack / 0.7), (radii.min(), radii.max())
    # the X grid: the groove's walls; between two instances the ray passes the tool off
    # its middle by up to d sin(pi / count), where the flat's side stands in
    count = planned(tri.cutters["x"], moves)
    for d in (rho + 0.5, rho + 1.25, R - 0.5):
        off = d * math.sin(math.pi / count)
        wall = 3.0 - math.sqrt(9.0 - off * off) + 4e-6
        for ang in np.radians([0, 37, 90, 150, 222, 300]):
            y, z = node(model, d * math.cos(ang), 1), node(model, d * math.sin(ang), 2)
            if not (rho + 0.1 < math.hypot(y, z) < R - 0.1):
                continue
            seg = ray_segments(model, "x", (0, y, z))
            assert len(seg) == 2, (d, ang, seg)
            assert seg[0, 0] == pytest.approx(0, abs=4e-6) and seg[1, 1] == pytest.approx(30, abs=4e-6)
            assert 12 - 4e-6 <= seg[0, 1] <= 12 + wall and 18 - wall <= seg[1, 0] <= 18 + 4e-6, (d, ang, seg)
    # beside the groove the bar is whole
    for c in np.arange(-0.7 * R, 0.7 * R, 1.0):
        assert np.allclose(ray_segments(model, "z", (22.125, node(model, c, 1), 0)),
                           [[-math.sqrt(R * R - node(model, c, 1) ** 2), math.sqrt(R * R - node(model, c, 1) ** 2)]],
                           atol=4e-6)
    assert_grids_agree(model)


def test_full_a_turn_faces_the_bar_down_to_a_smaller_cylinder():
    """A helical facing pass (X feeding 4 mm per A turn under a 6 mm flat mill, 3 turns)
    turns the bar to the radius h of the tip's height along x 9..19: the X grid's rays
    (along the axis) inside h keep the whole bar, those between h and R are empty there;
    the Y and Z grids give the radius h at every station."""
    tool = parse_tool_spec("flat:6:L=20")
    model = TriDexel.cylinder(0.0, 28.0, R, SPACING)
    before = model.copy()
    h = 5.5
    moves = rows([8, 0, h, 0, 0, 0], [20, 0, h, 3 * 360, 0, 0])
    tri = TriCutter(model, tool, kinematics=FourthAxis("A"))
    tri.cut_moves(moves)
    slack = polygon_slack(h, planned(tri.cutters["z"], moves) / 3)
    for y in np.arange(-R, R + 1e-9, 0.5):  # nodes: whole spacings from the axis
        for z in np.arange(-R, R + 1e-9, 0.5):
            d = math.hypot(y, z)
            seg = ray_segments(model, "x", (0, y, z))
            if d < h - slack - 1e-3:
                assert np.allclose(seg, [[0, 28]], atol=4e-6), (y, z, seg)
            elif h + slack < d < R:
                assert not np.any((seg[:, 0] < 19) & (seg[:, 1] > 9)), (y, z, seg)
                assert seg[0, 0] == pytest.approx(0, abs=4e-6) and seg[-1, 1] == pytest.approx(28, abs=4e-6)
    for x in (9.125, 12.375, 15.125, 18.875):
        for c in np.arange(-0.7 * h, 0.7 * h, SPACING):
            across = node(model, c, 1)
            for a, point in (("z", (x, across, 0)), ("y", (x, 0, across))):
                seg = ray_segments(model, a, point)
                assert len(seg) == 1, (x, c, a, seg)
                got = np.hypot(across, seg[0])
                assert np.all(np.abs(got - h) <= slack / 0.7 + 4e-6), (x, c, a, got)
    assert_grids_agree(model)
    assert_only_removed(before, model)
    vols = model.volumes()
    assert max(vols.values()) - min(vols.values()) < 0.01 * min(vols.values()), vols


def test_ball_swarf_pass_against_the_union_of_its_instances():
    """A 6 mm ball on an xyzbc-head leaning 15..25 degrees across its feed (its flank
    cutting a ruled wall, swarf-like) while the tip dips: every node of every grid is in
    the material exactly when it is in the stock and outside every instance the cutter
    placed (the ball end mill below its top is the capsule of radius r round the axis
    from tip + r k to tip + L k: distance from each node to those segments), except
    within the profile's chordal tolerance of an instance's surface."""
    r, fl = 3.0, 20.0
    tool = parse_tool_spec(f"ball:{2 * r}:L={fl}")
    model = TriDexel.box((0, 0, -6), (10, 12, 0), SPACING)
    before = model.copy()
    kin = HeadHead("B")
    rot = np.array([[0.0, 15.0, 0.0], [0.0, 25.0, 0.0]])
    tips = np.array([[3.0, -4.0, -2.0], [5.0, 16.0, -3.5]])
    poses = np.hstack([kin.machine_xyz(tips, rot, 0.0), rot])
    moves = rows(poses[0], poses[1])
    tri = TriCutter(model, tool, kinematics=kin)
    res = tri.cut_moves(moves)
    t, k = tri.cutters["x"]._rotary.poses(moves[0], moves["start"][0, :3], moves["end"][0, :3], tool)
    assert len(t) > 100 and np.all(k[:, 2] > 0.9)
    # the instances' top ends stay far above the stock: only the capsule part can cut
    assert np.all(t[:, 2] + fl * k[:, 2] - r > 1.0)
    p = nodes(model).reshape(-1, 3)
    gap = np.full(len(p), np.inf)
    for c0, ax in zip(t + r * k, k):  # distance to each instance's capsule axis
        w = p - c0
        h = np.clip(w @ ax, 0.0, fl - r)
        gap = np.minimum(gap, np.linalg.norm(w - h[:, None] * ax, axis=1) - r)
    gap = gap.reshape(model.shape)
    xyz = nodes(model)
    in_stock = np.all((xyz >= [0, 0, -6]) & (xyz <= [10, 12, 0]), axis=-1)
    want = in_stock & (gap > 0)
    sure = np.abs(gap) > 2 * 1e-3  # the ball's polygon lies within tol.chord of the sphere
    occ = occupancy(model)
    for a in AXES:
        bad = (occ[a] != want) & sure
        assert not bad.any(), (a, int(bad.sum()), np.argwhere(bad)[:3])
    assert (in_stock & ~want).sum() > 1000  # the pass cut a good deal
    assert all(rr.removed.sum() > 0 for rr in res.values())
    assert_only_removed(before, model)


# --- invariants -------------------------------------------------------------------------

def test_tri_cut_is_each_grid_cut_alone_and_repeating_it_changes_nothing():
    """3-axis moves (the Z grid's exact sweep, the X and Y grids' instances): each grid
    cut by the TriCutter (on bands, or the grids at once) is bit for bit the grid a lone
    one-thread Cutter cuts; the
    same moves again remove nothing and change no ray; the volumes agree within the
    stated tolerance (a dexel volume is off by about the surface area x spacing / 4 at
    most, each way)."""
    tool = parse_tool_spec("ball:4:L=15")
    stock = TriDexel.box((0, 0, 0), (16, 12, 6), SPACING)
    pts = [[-3, 2, 8], [-3, 2, 4.5]]
    for j, y in enumerate(np.arange(2, 11, 1.5)):
        xs = (-3, 19) if j % 2 == 0 else (19, -3)
        pts += [[xs[0], y, 4.5 - 0.2 * j], [xs[1], y, 4.5 - 0.2 * j]]
    pts = np.array(pts, float)
    moves = rows(*np.hstack([pts, np.zeros((len(pts), 3))]))
    for at_once in (False, True):
        model = stock.copy()
        got = TriCutter(model, tool, threads=2, grids_at_once=at_once).cut_moves(moves, record_changes=True)
        for a in AXES:
            alone = stock.grids[a].copy()
            want = Cutter(alone, tool, threads=1).cut_moves(moves, record_changes=True)
            assert_same_grid(model.grids[a], alone)
            assert np.array_equal(got[a].removed, want.removed)
            assert np.array_equal(got[a].changed_rays, want.changed_rays)
    assert_grids_agree(model)
    assert_only_removed(stock, model)
    again = model.copy()
    res = TriCutter(again, tool, threads=1).cut_moves(moves, record_changes=True)
    for a in AXES:
        assert res[a].removed.sum() == 0.0 and res[a].changed_rays.size == 0
        assert_same_grid(again.grids[a], model.grids[a])
    vols = model.volumes()
    area = 2 * (16 * 12 + 16 * 6 + 12 * 6) + 2 * 16 * 10  # the box and a generous allowance for the cut's walls
    assert max(vols.values()) - min(vols.values()) <= area * SPACING / 2, vols
    # the removed volume of each grid is the stock's less what is left
    for a in AXES:
        assert got[a].removed.sum() == pytest.approx(stock.volumes()[a] - vols[a], rel=1e-6)


def test_tri_cut_poses_and_probe_moves_touch_every_grid():
    """cut_poses cuts each grid (three estimates of one volume); probe_moves leaves the
    model as it was and gives one column per grid."""
    tool = parse_tool_spec("flat:4:L=10")
    model = TriDexel.box((0, 0, 0), (10, 10, 5), SPACING)
    moves = rows([-3, 5, 3, 0, 0, 0], [13, 5, 3, 0, 0, 0])
    before = model.copy()
    probe = TriCutter(model, tool).probe_moves(moves)
    assert probe.shape == (1, 3)
    for a in AXES:
        assert_same_grid(before.grids[a], model.grids[a])
    want = 10 * 4 * 2  # the slot: 10 long, 4 wide, 2 deep
    assert np.allclose(probe[0], want, rtol=0.05), probe
    got = TriCutter(model, tool).cut_poses([[5.0, 5.0, 1.0]], [[0.0, 0.0, 1.0]], 7)
    disc = math.pi * 4 * 4  # the tool standing 4 mm deep
    assert all(abs(v - disc) < 0.1 * disc for v in got.values()), got


# --- the side grids' shortcuts ----------------------------------------------------------

def test_ray_square_to_the_axis_crosses_the_disc_every_piece_gives():
    """sweep_kernels.pose_intervals for a ray square to the tool's axis (a vertical tool on
    the X and Y grids) takes the one disc at the ray's height: the same interval as the
    union of every profile piece's, for every tool shape, also at vertex heights."""
    from sim import sweep, sweep_kernels as K

    rng = np.random.default_rng(3)
    for spec in ("ball:6:L=20", "flat:6:L=20", "bull:6:1:L=20", "vbit:6:90:L=20", "drill:6:118:L=20"):
        prof = sweep.body_profile(parse_tool_spec(spec))
        out, buf = np.empty((prof.shape[0], 2)), np.empty(2)
        for n in range(2000):
            tip = rng.uniform(-5, 5, 3)
            ax = np.array([0.0, 1.0, 0.0]) if n % 2 else np.array([1.0, 0.0, 0.0])
            if n % 5 == 0:  # a ray at a vertex's height
                h, off = prof[rng.integers(len(prof)), 0], rng.uniform(-4, 4)
                px, py = tip[0] + h * ax[0] + off * ax[1], tip[1] + h * ax[1] + off * ax[0]
            else:
                px, py = rng.uniform(-10, 10, 2)
            got = out[:K.pose_intervals(prof, tip, ax, px, py, out, buf)].copy()
            wx, wy = px - tip[0], py - tip[1]
            h0 = wx * ax[0] + wy * ax[1]
            pieces = [(buf[0] + tip[2], buf[1] + tip[2]) for k in range(len(prof) - 1)
                      if K._piece_interval(prof, k, h0, 0.0, wx * wx + wy * wy, buf)]
            want = [[min(p[0] for p in pieces), max(p[1] for p in pieces)]] if pieces else np.zeros((0, 2))
            assert np.array_equal(got, np.asarray(want).reshape(-1, 2)), (spec, got, want)


def test_line_instances_are_each_rows_instances():
    """sweep.line_instances (every straight row at once) gives bit for bit the tips
    sweep.instances gives each row."""
    from sim import sweep

    rng = np.random.default_rng(1)
    p0 = rng.normal(size=(300, 3)) * 10
    p1 = p0 + rng.normal(size=(300, 3)) * rng.choice([0.0, 0.01, 1.0, 10.0], size=(300, 1))
    tips, steps = sweep.line_instances(p0, p1, 0.125)
    at = 0
    for k in range(300):
        want, _ = sweep.instances(p0[k], p1[k], [0, 0, 1], [0, 0, 1], 20.0, 0.125)
        assert np.array_equal(tips[at:at + steps[k] + 1], want)
        at += steps[k] + 1
    assert at == len(tips)


def test_subtract_on_rays_of_several_segments_is_the_boolean_difference():
    """dexel_store.subtract_interval on rays of several segments (its shortcuts: a ray
    the interval misses, one segment shortened in place) against Van Hook's difference
    written out: the same segments, face ids and removed length."""
    from sim import dexel_store as ds
    from sim.frame import Frame
    from sim.grid import DexelGrid

    eps = 1e-6
    f32 = np.float32
    rng = np.random.default_rng(5)
    frame = Frame.top(0, 0, 1, 0, 1.0)
    for _ in range(100):
        grid = DexelGrid.from_intervals(frame, np.zeros(frame.shape), np.full(frame.shape, 10.0))
        ref = [[(f32(0), f32(10), 0, 0)] for _ in range(2)]
        for step in range(40):
            a = float(rng.uniform(-1, 11))
            b = a + float(rng.choice([1e-7, 0.01, 0.3, 2.0])) * float(rng.random())
            r, mid = int(rng.integers(2)), step + 1
            got = ds.subtract_interval(grid.S, r, a, b, mid, eps)
            if got == ds.POOL_FULL:
                ds.grow_pool(grid.store, 1024)
                got = ds.subtract_interval(grid.S, r, a, b, mid, eps)
            keep, removed = [], 0.0
            for n, f, ni, fi in ref[r]:
                if b <= n or a >= f:
                    keep.append((n, f, ni, fi))
                    continue
                removed += min(b, float(f)) - max(a, float(n))
                if a - n > eps:
                    keep.append((n, f32(a), ni, mid))
                if f - b > eps:
                    keep.append((f32(b), f, mid, fi))
            ref[r] = keep
            assert got == removed
            assert grid.segments(r, 0).tolist() == [[float(n), float(f)] for n, f, _, _ in keep]
            assert grid.face_ids(r, 0).tolist() == [[ni, fi] for _, _, ni, fi in keep]


def test_rotary_body_trim_cuts_the_same_on_the_side_grids():
    """RotaryPlan.reaching_profile reads the grid's own frame: on the X and Y grids too the
    tool cut off where no instance reaches the material cuts bit for bit what the whole
    tool cuts (a ball turning round the bar)."""
    tool = parse_tool_spec("ball:3:L=10")
    stock = TriDexel.cylinder(0.0, 20.0, 6.0, 0.5)
    moves = rows(*[[4 + 0.5 * k, 0, 5.0, 15.0 * k, 0, 0] for k in range(24)])
    trimmed, whole = stock.copy(), stock.copy()
    a = TriCutter(trimmed, tool, kinematics=FourthAxis("A"), threads=1)
    b = TriCutter(whole, tool, kinematics=FourthAxis("A"), threads=1)
    for c in b.cutters.values():
        c.trim_body = False
    ra, rb = a.cut_moves(moves), b.cut_moves(moves)
    for ax in AXES:
        assert np.array_equal(ra[ax].removed, rb[ax].removed) and ra[ax].removed.sum() > 0
        assert_same_grid(trimmed.grids[ax], whole.grids[ax])


@pytest.mark.parametrize("turning", [False, True])
def test_chained_rows_cut_their_shared_pose_once_and_the_same(turning):
    """Instances of motion of chained rows: a row's first pose is the last one's end, cut
    once in a batch (sim.cut.Cutter._plan); the grid, the removed volumes and the changed
    rays are those of cutting the rows one call each (where nothing is shared)."""
    tool = parse_tool_spec("ball:3:L=10")
    stock = TriDexel.cylinder(0.0, 20.0, 6.0, 0.5)
    kin = FourthAxis("A") if turning else None
    pts = [[4 + 0.7 * k, 0.3 * (k % 3), 5.0, 20.0 * k if turning else 0.0, 0, 0] for k in range(12)]
    pts.insert(5, pts[4])  # a row that does not move
    moves = rows(*pts)
    for a in ("x", "y"):
        batch, single = stock.grids[a].copy(), stock.grids[a].copy()
        cutter = Cutter(batch, tool, kinematics=kin, threads=1)
        work = cutter._plan(moves, np.arange(len(moves)), np.arange(1, len(moves) + 1, dtype=np.int32),
                            tool, np.zeros(len(moves), bool))
        poses = len(work.pose_arrays()[0])
        got = cutter.cut_moves(moves)
        one = Cutter(single, tool, kinematics=kin, threads=1)
        apart = [one.cut_moves(moves[k:k + 1], move_ids=[k + 1]) for k in range(len(moves))]
        assert np.array_equal(got.removed, [r.removed[0] for r in apart])
        for k in range(len(moves)):
            assert np.array_equal(got.changed(k), apart[k].changed(0))
        assert_same_grid(batch, single)
        planned_apart = sum(len(one._plan(moves[k:k + 1], np.arange(1), np.ones(1, np.int32), tool,
                                          np.zeros(1, bool)).pose_arrays()[0]) for k in range(len(moves)))
        assert poses == planned_apart - (len(moves) - 1)  # every row after the first shares one
