"""Per-ray intervals of tool poses and swept moves against analytic / brute-force oracles."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim import sweep
from sim.frame import Frame
from sim.tools import Body, Tool, parse_tool_spec


def brute_lower(tool: Tool, p0, p1, x, y, n=20001):
    """min over densely sampled tip positions of tip_z + lowest_height(d); NaN if never under."""
    t = np.linspace(0, 1, n)
    pts = p0 + t[:, None] * (np.asarray(p1) - p0)
    d = np.hypot(pts[:, 0] - x, pts[:, 1] - y) + 1e-9  # rays grazing the rim are ambiguous
    h = tool.lowest_height(d)
    z = pts[:, 2] + h
    return np.nanmin(z) if np.isfinite(z).any() else np.nan


@pytest.mark.parametrize("spec", ["flat:6", "ball:6", "bull:6:1.5", "vbit:6:90", "drill:4", "ball:6:L=2"])
@pytest.mark.parametrize("p1", [(14.0, 11.0, 6.0), (10.5, 10.0, 9.0), (10.0, 10.0, 4.0), (16.0, 13.0, 8.0)])
def test_linear_sweep_lower_envelope_matches_brute_force(spec, p1):
    tool = parse_tool_spec(spec)
    frame = Frame.top(4, 4, 22, 20, 0.5)
    p0 = np.array([10.0, 10.0, 8.0])
    lo, hi = sweep.linear_sweep_on_rays(tool, p0, p1, frame)
    pts = frame.ray_points()
    worst = 0.0
    for j in range(0, frame.nv, 3):
        for i in range(0, frame.nu, 3):
            want = brute_lower(tool, p0, np.array(p1), pts[j, i, 0], pts[j, i, 1])
            if np.isnan(want):
                continue
            assert not np.isnan(lo[j, i])
            # exact is never above the sampled minimum, and close to it
            assert lo[j, i] <= want + 1e-9
            worst = max(worst, want - lo[j, i])
            # the top of the swept flutes: the higher end of the part of the move over the ray
            assert hi[j, i] <= max(p0[2], p1[2]) + tool.flute_length + 1e-9
    assert worst < 2e-3


def test_ball_groove_cross_section_is_the_circle():
    tool = parse_tool_spec("ball:6")
    frame = Frame.top(0, 0, 20, 10, 0.25)
    lo, hi = sweep.linear_sweep_on_rays(tool, [2, 5, 1], [18, 5, 1], frame)
    e = np.arange(frame.nv) * 0.25 - 5.0
    col = lo[:, 40]  # x = 10, mid-groove
    inside = np.abs(e) <= 3
    np.testing.assert_allclose(col[inside], 1 + 3 - np.sqrt(9 - e[inside] ** 2), atol=1e-12)
    assert np.isnan(col[~inside]).all()
    np.testing.assert_allclose(hi[inside, 40], 1 + 24)


def test_bull_nose_groove_profile():
    tool = parse_tool_spec("bull:8:1.5")
    frame = Frame.top(0, 0, 20, 10, 0.1)
    lo, _ = sweep.linear_sweep_on_rays(tool, [2, 5, 3], [18, 5, 3], frame)
    e = np.abs(np.arange(frame.nv) * 0.1 - 5.0)
    a = 4 - 1.5
    want = np.where(e <= a, 3.0, 3 + 1.5 - np.sqrt(np.maximum(1.5**2 - (e - a) ** 2, 0)))
    want[e > 4 + 1e-12] = np.nan
    np.testing.assert_allclose(lo[:, 100], want, atol=1e-9)


def test_ramp_with_a_ball_is_the_capsule():
    # a descending ramp: the lowest point under the line of travel is the ball at the end,
    # and at a ray on the path midway the capsule surface lies R / cos(slope) above the axis
    tool = parse_tool_spec("ball:6")
    frame = Frame.top(0, 0, 40, 10, 0.5)
    lo, _ = sweep.linear_sweep_on_rays(tool, [5, 5, 10], [35, 5, 4], frame)
    slope = math.atan2(6, 30)
    x = 20.0
    z_axis = 10 - 6 * (x - 5) / 30 + 3  # ball centre line
    assert lo[10, 40] == pytest.approx(z_axis - 3 / math.cos(slope), abs=1e-9)


def test_pose_on_rays_vertical_flat_is_the_cylinder():
    tool = parse_tool_spec("flat:4:L=10")
    frame = Frame.top(0, 0, 10, 10, 0.5)
    rays, lo, hi = sweep.pose_on_rays(tool, [5, 5, 2], [0, 0, 1], frame)
    pts = frame.ray_points().reshape(-1, 3)
    d = np.hypot(pts[:, 0] - 5, pts[:, 1] - 5)
    inside = np.nonzero(d < 2 - 1e-9)[0]
    assert set(inside) <= set(rays)
    sel = np.isin(rays, inside)
    np.testing.assert_allclose(lo[sel], 2.0, atol=1e-12)
    np.testing.assert_allclose(hi[sel], 12.0, atol=1e-12)


@pytest.mark.parametrize("tilt_deg", [10.0, 30.0, 60.0])
def test_tilted_flat_end_mill_against_its_analytic_section(tilt_deg):
    # axis tilted about Y; on a vertical ray whose foot on the bottom plane lies inside the
    # bottom disk, the ray enters the tool through that plane: z = tz - ((x-tx) ax) / az
    th = math.radians(tilt_deg)
    axis = np.array([math.sin(th), 0.0, math.cos(th)])
    tip = np.array([10.0, 10.0, 5.0])
    tool = parse_tool_spec("flat:6:L=15")
    frame = Frame.top(0, 0, 20, 20, 0.25)
    rays, lo, hi = sweep.pose_on_rays(tool, tip, axis, frame)
    pts = frame.ray_points().reshape(-1, 3)[rays]
    zp = tip[2] - (pts[:, 0] - tip[0]) * axis[0] / axis[2]
    foot = np.stack([pts[:, 0], pts[:, 1], zp], axis=1) - tip
    rho = np.linalg.norm(foot - (foot @ axis)[:, None] * axis, axis=1)
    on_disk = rho < 3 - 1e-6
    assert on_disk.sum() > 50
    np.testing.assert_allclose(lo[on_disk], zp[on_disk], atol=1e-9)
    # the top face: the plane through tip + L*axis
    zt = tip[2] + 15 / axis[2] - (pts[:, 0] - tip[0]) * axis[0] / axis[2]
    top = np.stack([pts[:, 0], pts[:, 1], zt], axis=1) - (tip + 15 * axis)
    rho_t = np.linalg.norm(top - (top @ axis)[:, None] * axis, axis=1)
    on_top = rho_t < 3 - 1e-6
    np.testing.assert_allclose(hi[on_top], zt[on_top], atol=1e-9)
    # never lower than the lowest point of the rim
    assert lo.min() >= tip[2] - 3 * math.sin(th) - 1e-9


def test_pose_on_rays_ball_along_a_side_frame():
    # rays along +X (a side view): a vertical ball tool is a sphere + cylinder seen sideways
    frame = Frame(np.array([0.0, 0.0, 0.0]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), 0.5, 41, 41)
    tool = parse_tool_spec("ball:6:L=10")
    tip = np.array([10.0, 10.0, 2.0])
    rays, lo, hi = sweep.pose_on_rays(tool, tip, [0, 0, 1], frame)
    # frame: u = +Y, v = direction x u = X x Y = +Z; ray (i, j) at y = i*0.5, z = j*0.5
    i = rays % frame.nu
    j = rays // frame.nu
    y, z = i * 0.5, j * 0.5
    # both ends of each interval lie on the tool surface: the sphere (within the chord
    # tolerance of its polygonised profile) below the centre, the cylinder above
    for s in (lo, hi):
        sphere = z < 5.0 - 1e-9
        r = np.sqrt((s[sphere] - 10) ** 2 + (y[sphere] - 10) ** 2 + (z[sphere] - 5) ** 2)
        assert np.all(r <= 3 + 1e-9) and np.all(r >= 3 - 0.001 - 1e-9)
        cyl = (z > 5.0 + 1e-9) & (z < 12.0 - 1e-9)
        np.testing.assert_allclose(np.hypot(s[cyl] - 10, y[cyl] - 10), 3.0, atol=1e-9)
    assert sphere.sum() > 20 and cyl.sum() > 20


def test_undercut_tool_gives_two_intervals_on_a_ray_parallel_to_nothing():
    # a T-slot cutter seen from the side: its head and neck are one interval; a ray
    # through the head only is the head's chord. Vertical rays under the head see the
    # head [0, 2] and, within the neck radius, the neck too - merged into one.
    tslot = Tool.custom([[0, 5], [2, 5], [2, 1], [20, 1]])
    frame = Frame.top(0, 0, 20, 20, 0.5)
    rays, lo, hi = sweep.pose_on_rays(tslot, [10, 10, 0], [0, 0, 1], frame)
    pts = frame.ray_points().reshape(-1, 3)[rays]
    d = np.hypot(pts[:, 0] - 10, pts[:, 1] - 10)
    head_only = (d > 1 + 1e-9) & (d < 5 - 1e-9)
    np.testing.assert_allclose(lo[head_only], 0.0, atol=1e-12)
    np.testing.assert_allclose(hi[head_only], 2.0, atol=1e-12)
    neck = d < 1 - 1e-9
    np.testing.assert_allclose(hi[neck], 20.0, atol=1e-12)
    assert np.bincount(rays).max() == 1


def test_body_params_of_a_shank_is_a_raised_cylinder():
    tool = parse_tool_spec("flat:6:L=20:S=8:SL=30")
    tp = sweep.body_params(tool.shank)
    assert tp[4] == 20.0 and tp[5] == 50.0 and tp[6] == 4.0
    frame = Frame.top(0, 0, 20, 20, 0.5)
    lo, hi = sweep.linear_sweep_on_rays(tool.shank, [5, 10, 0], [15, 10, 0], frame)
    assert np.nanmin(lo) == 20.0 and np.nanmax(hi) == 50.0
    assert sweep.has_exact_sweep(tool.shank)
    assert not sweep.has_exact_sweep(Body("taper", [[0, 1], [5, 3]]))


@pytest.mark.parametrize("cw", [False, True])
def test_arc_points_direction_and_radius(cw):
    pts = sweep.arc_points([10, 0, 0], [0, 10, 0], [0, 0, 0], 0, 1, cw, max_step_angle=0.01)
    r = np.hypot(pts[:, 0], pts[:, 1])
    np.testing.assert_allclose(r, 10, atol=1e-9)
    ang = np.unwrap(np.arctan2(pts[:, 1], pts[:, 0]))
    sweep_angle = ang[-1] - ang[0]
    assert sweep_angle == pytest.approx(-1.5 * math.pi if cw else 0.5 * math.pi)
    assert np.all(np.abs(np.diff(ang)) <= 0.01 + 1e-12)


def test_full_circle_helix_and_extra_turns():
    pts = sweep.arc_points([12, 10, 5], [12, 10, 1], [10, 10, 0], 0, 2, True, max_step_angle=0.1)
    ang = np.unwrap(np.arctan2(pts[:, 1] - 10, pts[:, 0] - 10))
    assert ang[-1] - ang[0] == pytest.approx(-4 * math.pi)
    np.testing.assert_allclose(pts[[0, -1], 2], [5, 1])
    assert np.all(np.diff(pts[:, 2]) < 0)  # descends steadily


def test_arc_planes_g18_g19():
    # G18: first axis Z, second X; CCW turns Z toward X
    pts = sweep.arc_points([0, 0, 5], [5, 0, 0], [0, 0, 0], 1, 1, False, max_step_angle=0.1)
    assert np.all(pts[:, 1] == 0) and np.all(pts[1:-1, 0] > 0) and np.all(pts[1:-1, 2] > 0)
    # G19: first axis Y, second Z
    pts = sweep.arc_points([0, 5, 0], [0, 0, 5], [0, 0, 0], 2, 1, False, max_step_angle=0.1)
    assert np.all(pts[:, 0] == 0) and np.all(pts[1:-1, 1] > 0) and np.all(pts[1:-1, 2] > 0)


def test_chord_step_angle_keeps_the_sagitta():
    for r in (0.5, 5.0, 100.0):
        th = sweep.chord_step_angle(r, 0.001)
        assert r * (1 - math.cos(th / 2)) == pytest.approx(0.001)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-20, 20), min_size=3, max_size=3),
       st.lists(st.floats(-20, 20), min_size=3, max_size=3),
       st.floats(0.05, 1.0))
def test_instances_are_spaced_below_the_step(p0, p1, step):
    tips, axes = sweep.instances(p0, p1, [0, 0, 1], [0.3, 0, 1], 10.0, step)
    np.testing.assert_allclose(tips[[0, -1]], [p0, p1])
    tops = tips + 10.0 * axes
    assert np.abs(np.diff(tips, axis=0)).max() <= step + 1e-9
    assert np.abs(np.diff(tops, axis=0)).max() <= step * (1 + 1e-6)
    np.testing.assert_allclose(np.linalg.norm(axes, axis=1), 1.0)
