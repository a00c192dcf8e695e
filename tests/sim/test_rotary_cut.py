"""Rotary cuts on the +Z dexel grid: a Cutter with a kinematics turns the part (or the
tool) and cuts by instances of motion. Analytic oracles: a groove wrapped round a bar on a
4th axis (depth constant all round), a full A turn facing a bar down to a smaller
cylinder, a flat end mill tilted 30 degrees (5-axis head) cutting a slot; and the 3-axis
default untouched."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.cut import Cutter
from sim.frame import Frame
from sim.gcode.moves import MoveKind, empty_moves
from sim.kinematics import FourthAxis, HeadHead, Trivial, instance_poses
from sim.solids import box_grid, cylinder_grid
from sim.tolerance import DEFAULT
from sim.tools import parse_tool_spec

SPACING = 0.25
R = 10.0  # bar radius, mm, on the A axis (the machine X axis through the origin)


def bar(x0=0.0, x1=30.0, radius=R):
    frame = Frame.top(x0 - 5, -radius - 2, x1 + 5, radius + 2, SPACING)
    return cylinder_grid(frame, (x0, 0, 0), (1, 0, 0), radius, x1 - x0)


def rows(*poses, kind=MoveKind.FEED, tool_length=0.0):
    """Move rows from consecutive machine poses (X Y Z A B C)."""
    m = empty_moves(len(poses) - 1)
    m["kind"] = kind
    m["start"] = poses[:-1]
    m["end"] = poses[1:]
    m["tool_length"] = tool_length
    m["feed"] = 500.0
    return m


def radii(grid, x, ys):
    """(top, bottom) of the material on the rays at ``x`` and each ``ys`` (mm): the one
    segment each ray must hold."""
    f = grid.frame
    i = int(round((x - f.origin[0]) / f.spacing))
    out = []
    for y in ys:
        j = int(round((y - f.origin[1]) / f.spacing))
        seg = grid.segments(i, j)
        assert len(seg) == 1, (x, y, seg)
        out.append((float(seg[0][1]), float(seg[0][0])))
    return np.array(out)


def ray_ys(limit):
    """Ray ordinates (on the grid) with |y| <= limit."""
    n = int(limit / SPACING)
    return np.arange(-n, n + 1) * SPACING


def planned(cutter, moves):
    """Steps between the instances the cutter plans for the one row of ``moves``."""
    tips, _ = cutter._rotary.poses(moves[0], moves["start"][0, :3], moves["end"][0, :3], cutter.tool)
    return len(tips) - 1


def polygon_slack(radius, count):
    """How far outside the circle ``radius`` a polygon of ``count`` sides around a full
    turn reaches, plus float32 storage."""
    half = math.pi / count
    return radius * (1 / math.cos(half) - 1) + 4e-6


@pytest.mark.parametrize("spec", ["flat:6:L=20", "ball:6:L=20"])
def test_groove_round_a_bar_is_equally_deep_all_round(spec):
    """The tool at a fixed Z over the A axis, A turning 360: the groove's floor is the
    circle the tool's lowest point leaves at every angle, in every slice across it."""
    tool = parse_tool_spec(spec)
    grid = bar()
    kin = FourthAxis("A")
    depth = 3.0
    tip_z = R - depth
    moves = rows([15, 0, tip_z, 0, 0, 0], [15, 0, tip_z, 360, 0, 0])
    cutter = Cutter(grid, tool, kinematics=kin)
    cutter.cut_moves(moves)
    count = planned(cutter, moves)
    for dx in (-2.5, -1.0, 0.0, 1.0, 2.5):
        if spec.startswith("flat"):
            rho, slack = tip_z, polygon_slack(tip_z, count)
        else:  # the ball's lowest point in this slice; cusps between balls a chord
            # apart, and the ball's profile polygonised within tol.chord (its normal
            # leans from the radial direction in a slice off the centre)
            across = math.sqrt(9.0 - dx * dx)
            rho = tip_z + 3.0 - across
            chord = (tip_z + 3.0) * 2 * math.pi / count
            slack = (chord * chord / 8 / across + DEFAULT.chord) * 3.0 / across + 4e-6
        ys = ray_ys(0.7 * rho)
        got = radii(grid, 15 + dx, ys)
        want = np.sqrt(rho * rho - ys * ys)
        # the cut never leaves more than the slack, and never goes below the floor
        assert np.all(got[:, 0] <= want + slack / 0.7) and np.all(got[:, 0] >= want - 4e-6)
        assert np.all(-got[:, 1] <= want + slack / 0.7) and np.all(-got[:, 1] >= want - 4e-6)
    # beside the groove the bar is whole
    ys = ray_ys(0.7 * R)
    got = radii(grid, 15 + 4.0, ys)
    assert np.allclose(got[:, 0], np.sqrt(R * R - ys * ys), atol=4e-6)


def test_full_a_turn_faces_a_smaller_cylinder():
    """A helical facing pass (X feeding 4 mm per turn of A under a 6 mm flat mill) turns
    the bar down to a cylinder of the tip's height, all along the pass."""
    tool = parse_tool_spec("flat:6:L=20")
    grid = bar()
    kin = FourthAxis("A")
    h = 7.0
    moves = rows([5, 0, h, 0, 0, 0], [25, 0, h, 5 * 360, 0, 0])
    cutter = Cutter(grid, tool, kinematics=kin)
    cutter.cut_moves(moves)
    count = planned(cutter, moves)
    slack = polygon_slack(h, count / 5)
    ys = ray_ys(0.7 * h)
    for x in (9.0, 12.5, 15.0, 20.0):
        got = radii(grid, x, ys)
        want = np.sqrt(h * h - ys * ys)
        assert np.all(np.abs(got[:, 0] - want) <= slack / 0.7)
        assert np.all(np.abs(-got[:, 1] - want) <= slack / 0.7)
    assert np.allclose(radii(grid, 29.0, ys)[:, 0], np.sqrt(R * R - ys * ys), atol=4e-6)


def test_constant_a_moves_cut_on_the_turned_part():
    """A = 90 held while X feeds: the tool cuts the side of the part that A turned up
    (the xyza convention: A = +90 brings the part's +Y up to +Z)."""
    tool = parse_tool_spec("flat:4:L=10")
    frame = Frame.top(-2, -15, 22, 15, SPACING)
    grid = box_grid(frame, (0, -10, -5), (20, 10, 5))  # 20 wide in Y, 10 high in Z
    kin = FourthAxis("A")
    # the tip at machine Z 8 with A = 90: on the part that is Y = 8 (a 2 mm cut into the +Y side)
    Cutter(grid, tool, kinematics=kin).cut_moves(rows([5, 0, 8, 90, 0, 0], [15, 0, 8, 90, 0, 0]))
    # on the part the tool lies along +Y from y = 8 and spans z -2..2: the ray at y = 9 is cut through
    f = grid.frame
    seg = grid.segments(int(round((10 - f.origin[0]) / SPACING)), int(round((9 - f.origin[1]) / SPACING)))
    assert np.allclose(seg, [[-5, -2], [2, 5]], atol=4e-6)
    seg = grid.segments(int(round((10 - f.origin[0]) / SPACING)), int(round((7 - f.origin[1]) / SPACING)))
    assert np.allclose(seg, [[-5, 5]], atol=4e-6)


def test_tilted_flat_mill_slot_section_is_the_tilted_rectangle():
    """A flat end mill tilted 30 degrees (an xyzbc-head at B = 30, C = 0) slotting along
    Y: the slot's section (the XZ plane, square to the feed) is the projection of the
    tilted cylinder along Y, the rectangle 2r x L leaning 30 degrees on the tip; every
    ray of the section keeps the stock less that rectangle's span."""
    r, fl = 3.0, 20.0
    tool = parse_tool_spec(f"flat:{2 * r}:L={fl}")
    frame = Frame.top(-15, -5, 15, 25, SPACING)
    grid = box_grid(frame, (-12, 0, -10), (12, 20, 0))
    kin = HeadHead("B")
    tip0, tip1 = np.array([0.0, -4, -2]), np.array([0.0, 24, -2])
    poses = np.zeros((2, 6))
    poses[:, 4] = 30.0
    poses[:, :3] = kin.machine_xyz(np.stack([tip0, tip1]), poses[:, 3:], 0.0)
    Cutter(grid, tool, kinematics=kin).cut_moves(rows(poses[0], poses[1]))
    _, k = kin.forward(poses[:1], 0.0)
    k = k[0]
    assert abs(k[1]) < 1e-12 and abs(math.degrees(math.acos(k[2])) - 30) < 1e-9
    u = np.array([k[2], 0.0, -k[0]])  # in XZ, square to the axis
    corners = [tip0 + r * u, tip0 + r * u + fl * k, tip0 - r * u + fl * k, tip0 - r * u]
    # instances 0.125 mm apart along Y slice the tool up to 0.0625 mm off its axis plane:
    # the section narrows by up to dy^2 / 2r across, sin(30) of that on the steep sides
    dy = 0.5 * 0.5 * SPACING
    slack = dy * dy / (2 * r) / math.sin(math.radians(30)) + 4e-6
    f = grid.frame
    j = int(round((10 - f.origin[1]) / SPACING))
    checked = 0
    for x in np.arange(-11, 11.001, SPACING):
        if min(abs(x - c[0]) for c in corners) < 0.1:
            continue  # a corner's ray: the span's ends turn there
        zs = []
        for p, q in zip(corners, corners[1:] + corners[:1]):
            if (p[0] - x) * (q[0] - x) < 0:
                zs.append(p[2] + (x - p[0]) / (q[0] - p[0]) * (q[2] - p[2]))
        seg = grid.segments(int(round((x - f.origin[0]) / SPACING)), j)
        if not zs:
            assert np.allclose(seg, [[-10, 0]], atol=4e-6), (x, seg)
            continue
        lo, hi = min(zs), max(zs)
        want = [w for w in ([-10, min(lo, 0.0)], [max(hi, -10.0), 0]) if w[1] > w[0]]
        assert len(seg) == len(want), (x, seg, want)
        assert np.all(np.abs(np.asarray(seg) - want) <= slack), (x, seg, want)
        checked += 1
    assert checked > 20


def test_three_axis_default_is_unchanged():
    """Without a kinematics, or with the plain 3-axis one, A words turn nothing and the
    exact 3-axis sweep cuts bit for bit the same."""
    tool = parse_tool_spec("ball:6:L=20")
    frame = Frame.top(-10, -10, 40, 10, SPACING)
    moves = rows([0, 0, 2, 0, 0, 0], [30, 0, -1, 90, 0, 0], [30, 5, -1, 90, 0, 0])
    ref = box_grid(frame, (-5, -5, -5), (35, 5, 0))
    a, b = ref.copy(), ref.copy()
    Cutter(ref, tool).cut_moves(moves)
    Cutter(a, tool, kinematics=Trivial()).cut_moves(moves)
    Cutter(b, tool, kinematics=FourthAxis("A")).cut_moves(moves[:0])
    for name in ("pool_near", "pool_far", "count"):
        assert np.array_equal(ref.store[name], a.store[name])


@pytest.mark.parametrize("case", ["4axis", "5axis"])
def test_body_cut_to_its_reach_cuts_the_same(case):
    """Rotary batches cut with the tool's profile stopped where no instance can reach the
    material's box (sim.rotary_plan.RotaryPlan.reaching_profile): the model is bit for bit the whole body's."""
    if case == "4axis":
        tool = parse_tool_spec("ball:3:L=10")
        stock = bar(radius=8.0)
        kin = FourthAxis("A")
        poses = [[10 + 0.5 * k, 0, 7.0, 15.0 * k, 0, 0] for k in range(30)]
    else:
        tool = parse_tool_spec("ball:6:L=20")
        frame = Frame.top(-8, -8, 28, 18, SPACING)
        stock = box_grid(frame, (-5, -5, -10), (25, 15, 0))
        kin = HeadHead("B", pivot_length=50.0)
        rot = np.array([[0.0, 25 * math.sin(x / 4), 0.0] for x in range(20)])
        tips = np.array([[x, 5.0, -0.7] for x in range(20)])
        poses = np.hstack([kin.machine_xyz(tips, rot, 0.0), rot])
    moves = rows(*np.asarray(poses, float))
    trimmed, whole = stock.copy(), stock.copy()
    a = Cutter(trimmed, tool, kinematics=kin)
    b = Cutter(whole, tool, kinematics=kin)
    b.trim_body = False
    ra = a.cut_moves(moves)
    rb = b.cut_moves(moves)
    assert np.array_equal(ra.removed, rb.removed)
    rays = np.arange(stock.frame.n_rays)
    for x, y in zip(trimmed.segments_of(rays), whole.segments_of(rays)):
        assert np.array_equal(x, y)
    # and the trim did cut the body short
    f = stock.frame
    t, ax = kin.forward(np.asarray(poses, float), 0.0)
    axes_l = np.stack([ax @ f.u, ax @ f.v, ax @ f.direction], axis=1)
    prof = a._rotary.reaching_profile(tool.profile, f.to_local(t), axes_l)
    assert prof[-1, 0] < tool.profile[-1, 0]


def test_instance_counts_of_many_moves_are_each_moves_own():
    """instance_counts over (n, 6) rows on a table kinematics (it raised for n > 1: a
    Python max over the ends' distance arrays)."""
    kin = FourthAxis("A", rot_point=(0, 1, -2))
    start = np.array([[0, 0, 10, 0, 0, 0], [5, 3, 12, 90, 0, 0], [1, 1, 1, 0, 0, 0]], float)
    end = np.array([[0, 0, 10, 360, 0, 0], [6, -3, 14, 45, 0, 0], [2, 1, 1, 0, 0, 0]], float)
    got = kin.instance_counts(start, end, 5.0, 20.0, 3.0, 0.1)
    one = [int(kin.instance_counts(s, e, 5.0, 20.0, 3.0, 0.1)[0]) for s, e in zip(start, end)]
    assert got.tolist() == one


def test_fewest_instances_keep_every_tool_point_within_the_step():
    """A 5-axis move that tilts the tool about its tip (the linear axes following the
    head, as a TCP post does): the sum-of-motions bound counts the pivot's swing; the
    instances actually planned are far fewer, and no point of the tool (360 points on
    each rim, checked here independently) moves more than the step between two."""
    kin = HeadHead("B", pivot_length=100.0)
    tool = parse_tool_spec("ball:6:L=20")
    grid = box_grid(Frame.top(-10, -10, 10, 10, SPACING), (-5, -5, -5), (5, 5, 0))
    cutter = Cutter(grid, tool, kinematics=kin)
    rot = np.array([[0.0, -15.0, 0.0], [0.0, 15.0, 0.0]])
    tips = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, -1.0]])
    a, b = np.hstack([kin.machine_xyz(tips, rot, 0.0), rot])
    move = rows(a, b)
    tips_got, _ = cutter._rotary.poses(move[0], a[:3], b[:3], tool)
    bound = int(kin.instance_counts(a, b, 0.0, 20.0, 3.0, cutter._step())[0])
    count = len(tips_got) - 1
    assert count < bound / 3
    ang = np.radians(np.arange(360))
    rim = np.stack([3 * np.cos(ang), 3 * np.sin(ang), np.zeros(360)], axis=1)
    pts = kin.tool_points(instance_poses(a, b, count), 0.0, np.concatenate([rim, rim + [0, 0, 20]]))
    assert np.linalg.norm(np.diff(pts, axis=0), axis=2).max() <= cutter._step()


def test_a_table_of_tips_cuts_on_a_head_by_the_tool_lengths_given():
    """A tilting head swings the tip on pivot + tool length. The same moves as the
    interpreter gives them (machine X Y Z, tool_length 40) and as a table of tips (Z less
    the length, tool_length 0, as the monitor cuts them) with ``tool_lengths`` {tool: 40}
    cut bit for bit the same; the table of tips without it puts the tip elsewhere."""
    tool = parse_tool_spec("ball:6:L=20")
    frame = Frame.top(-8, -8, 28, 18, SPACING)
    stock = box_grid(frame, (-5, -5, -10), (25, 15, 0))
    kin = HeadHead("B", pivot_length=50.0)
    L = 40.0
    rot = np.array([[0.0, 25 * math.sin(x / 4), 0.0] for x in range(12)])
    tips = np.array([[x, 5.0, -0.7] for x in range(12)])
    machine = rows(*np.hstack([kin.machine_xyz(tips, rot, L), rot]), tool_length=L)
    machine["tool"] = 3
    as_tips = machine.copy()
    as_tips["start"][:, 2] -= L
    as_tips["end"][:, 2] -= L
    as_tips["tool_length"] = 0.0
    ref, got, bare = stock.copy(), stock.copy(), stock.copy()
    Cutter(ref, tool, kinematics=kin).cut_moves(machine)
    Cutter(got, tool, kinematics=kin, tool_lengths={3: L}).cut_moves(as_tips)
    Cutter(bare, tool, kinematics=kin).cut_moves(as_tips)
    for name in ("pool_near", "pool_far", "count"):
        assert np.array_equal(ref.store[name], got.store[name])
    # without it each tip lands L (k - Z) from where it is: elsewhere, a different cut
    assert abs(ref.volume() - bare.volume()) > 1.0
