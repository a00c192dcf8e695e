"""Machine kinematics: analytic poses, LinuxCNC's formulas, forward and inverse both ways,
the closest solution, and clear errors on bad configurations."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.kinematics import (KINEMATICS, ROTARY_COLUMN, FourthAxis, HeadHead, HeadTable, KinematicsError,
                            TableTable, Trivial, instance_poses, make_kinematics)

TOL = 1e-9


def pose(x=0.0, y=0.0, z=0.0, a=0.0, b=0.0, c=0.0):
    return np.array([[x, y, z, a, b, c]], np.float64)


def close(got, want, tol=TOL):
    np.testing.assert_allclose(np.asarray(got, np.float64), np.asarray(want, np.float64), rtol=0, atol=tol)


# --- analytic poses ---------------------------------------------------------------------

def test_three_axis_tip_is_gauge_point_less_tool_length_whatever_abc():
    tip, axis = Trivial().forward(pose(1, 2, 3, 40, 50, 60), tool_length=20)
    close(tip, [[1, 2, -17]])
    close(axis, [[0, 0, 1]])


def test_fourth_axis_a90_turns_the_parts_plus_y_to_face_the_tool():
    # LinuxCNC's table direction (the default): A = +90 turns the part's +Y up to +Z, so
    # a tool standing 30 mm above the A axis line touches the part's +Y side, its axis
    # along the part's +Y
    kin = FourthAxis("A", rot_point=(0, 5, 7))
    tip, axis = kin.forward(pose(12, 5, 7 + 30 + 20, a=90), tool_length=20)
    close(tip, [[12, 5 + 30, 7]])
    close(axis, [[0, 1, 0]])
    # conventional direction: the tool turns +90 about X around the part -> the part's -Y
    tip, axis = FourthAxis("A", rot_point=(0, 5, 7), conventional_directions=True).forward(
        pose(12, 5, 57, a=90), tool_length=20)
    close(tip, [[12, 5 - 30, 7]])
    close(axis, [[0, -1, 0]])


def test_fourth_axis_full_turn_keeps_the_tip_on_one_cylinder():
    # a groove wrapped round the stock: the tip stays at the same radius all round
    kin = FourthAxis("A", rot_point=(0, 0, 10))
    a = np.linspace(-720, 720, 97)
    axes = np.zeros((len(a), 6))
    axes[:, 0] = np.linspace(0, 50, len(a))
    axes[:, 2] = 10 + 25 + 6
    axes[:, 3] = a
    tip, axis = kin.forward(axes, tool_length=6)
    radius = np.hypot(tip[:, 1], tip[:, 2] - 10)
    close(radius, np.full(len(a), 25.0))
    close(tip[:, 0], axes[:, 0])
    # the axis points out of the cylinder, from the A line through the tip
    close(axis[:, 1:], (tip[:, 1:] - [0, 10]) / 25.0)


def test_fourth_axis_b_turns_about_y():
    tip, axis = FourthAxis("B").forward(pose(0, 3, 40, b=90), tool_length=10)
    # B = +90 (table direction) turns the part about +Y: its -X comes up to the tool
    close(tip, [[-30, 3, 0]])
    close(axis, [[-1, 0, 0]])


def test_trunnion_ac_with_offsets_hand_computed():
    # C axis through (10, 20, *); the A axis 5 mm further in Y and 8 mm lower (LinuxCNC's
    # y-offset, z-offset): through y = 25, z = 22. Tool tip 30 mm above the A axis on
    # the C axis' plane x = 10 ... then 5 mm to +X.
    kin = make_kinematics("xyzac-trt", rot_point=[10, 20, 30], rot_offset=[0, 5, -8])
    L = 20.0
    # A = 90: the part's point under the tip was 30 mm from the A axis toward +Y
    tip, axis = kin.forward(pose(10, 25, 72, a=90), L)
    close(tip, [[10, 55, 22]])
    close(axis, [[0, 1, 0]])
    # C = 90 (table turns counterclockwise seen from above): the point 5 mm to +X of the
    # C axis came from the part's -Y side of it
    tip, axis = kin.forward(pose(15, 20, 72, c=90), L)
    close(tip, [[10, 15, 52]])
    close(axis, [[0, 0, 1]])
    # both: A first takes the tip to (15, 55, 22), then C turns that about (10, 20)
    tip, axis = kin.forward(pose(15, 25, 72, a=90, c=90), L)
    close(tip, [[45, 15, 22]])
    close(axis, [[1, 0, 0]])


def test_trunnion_bc_hand_computed():
    # B axis through (x = 10 - 4, z = 0 + 6); the tip 24 mm above it, B = 90: the part's
    # -X side (24 mm from the B axis) faces the tool
    kin = make_kinematics("xyzbc-trt", rot_point=[10, 0, 0], rot_offset=[-4, 0, 6])
    tip, axis = kin.forward(pose(6, 7, 30 + 10, b=90), tool_length=10)
    close(tip, [[6 - 24, 7, 6]])
    close(axis, [[-1, 0, 0]])


def test_head_head_b_swings_the_tip_toward_plus_x_as_5axiskins():
    kin = HeadHead("B", pivot_length=100)
    tip, axis = kin.forward(pose(0, 0, 0, b=90), tool_length=20)
    close(tip, [[120, 0, 100]])
    close(axis, [[-1, 0, 0]])
    tip, axis = kin.forward(pose(1, 2, 3, b=90, c=90), tool_length=20)
    close(tip, [[1, 122, 103]])
    close(axis, [[0, -1, 0]])
    # at zero the tip hangs tool_length below the gauge point, whatever the pivot
    tip, axis = kin.forward(pose(1, 2, 3), tool_length=20)
    close(tip, [[1, 2, -17]])


def test_head_table_tilts_the_tool_and_turns_the_part():
    kin = HeadTable("B", pivot_length=50, rot_point=(100, 0, 0))
    # B = -90 swings the tip toward -X by pivot + L (5axiskins' direction), so the
    # tool lies along +X from the tip
    tip_m = np.array([100 - 70.0, 0, 50])
    tip, axis = kin.forward(pose(100, 0, 0, b=-90), tool_length=20)
    close(tip, [tip_m])
    close(axis, [[1, 0, 0]])
    # C = 90 turns the table counterclockwise seen from above (LinuxCNC's table
    # direction): the point 70 mm to -X of the C axis is the part's +Y side of it, and
    # the tool, lying along machine +X, lies along the part's -Y
    tip, axis = kin.forward(pose(100, 0, 0, b=-90, c=90), tool_length=20)
    close(tip, [[100, 70, 50]])
    close(axis, [[0, -1, 0]])


def test_a_head_tilts_as_a_b_head_turned_a_quarter():
    # an A head by analogy with 5axiskins' B (the LinuxCNC direction): A = +90 swings the
    # tip toward -Y, the tool lying along +Y; C = +90 then turns that toward +X
    kin = HeadHead("A", pivot_length=100)
    tip, axis = kin.forward(pose(a=90), tool_length=20)
    close(tip, [[0, -120, 100]])
    close(axis, [[0, 1, 0]])
    tip, axis = kin.forward(pose(a=90, c=90), tool_length=20)
    close(tip, [[120, 0, 100]])
    close(axis, [[-1, 0, 0]])
    # the RS274 direction: the tool turns +90 about X, its tip toward +Y
    tip, axis = HeadHead("A", pivot_length=100, conventional_directions=True).forward(pose(a=90), 20)
    close(tip, [[0, 120, 100]])
    close(axis, [[0, -1, 0]])


def test_a_head_over_a_c_table():
    kin = HeadTable("A", pivot_length=50, rot_point=(100, 0, 0))
    # the tip swings 70 mm toward -Y of the C axis; C = +90 (table counterclockwise)
    # brings that point of the part from its -X side
    tip, axis = kin.forward(pose(100, 0, 0, a=90, c=90), tool_length=20)
    close(tip, [[30, 0, 50]])
    close(axis, [[1, 0, 0]])


# --- LinuxCNC's formulas, transcribed from its 5-axis chapter and modules ----------------

def linuxcnc_trt_world(kind, j, xr, yr, zr, dx, dy, dz, tool, con):
    """LinuxCNC's trt forward kinematics (world from joints), scalar, written out term by term."""
    x, y, z, a, b, c = j
    dz = dz + tool
    ca, sa = math.cos(math.radians(a)), math.sin(math.radians(a))
    cb, sb = math.cos(math.radians(b)), math.sin(math.radians(b))
    cc, sc = math.cos(math.radians(c)), math.sin(math.radians(c))
    if kind == "ac":
        vx, vy, vz = x - xr, y - dy - yr, z - dz - zr
        return (cc * vx - con * sc * ca * vy + sc * sa * vz - con * sc * dy + xr,
                con * sc * vx + cc * ca * vy - con * cc * sa * vz + cc * dy + yr,
                con * sa * vy + ca * vz + dz + zr)
    vx, vy, vz = x - dx - xr, y - yr, z - dz - zr
    return (cc * cb * vx - con * sc * vy + con * cc * sb * vz + cc * dx + xr,
            con * sc * cb * vx + cc * vy + sc * sb * vz + con * sc * dx + yr,
            -con * sb * vx + cb * vz + dz + zr)


def linuxcnc_5axis_world(j, pivot):
    """5axiskins: the joint point plus pivot length along (theta = C, phi = 180 - B), up pivot."""
    x, y, z, a, b, c = j
    t, p = math.radians(c), math.radians(180.0 - b)
    return (x + pivot * math.sin(p) * math.cos(t), y + pivot * math.sin(p) * math.sin(t),
            z + pivot * math.cos(p) + pivot)


def random_axes(rng, n, span=200.0):
    axes = rng.uniform(-span, span, (n, 6))
    axes[:, 3:] = rng.uniform(-400, 400, (n, 3))
    return axes


@pytest.mark.parametrize("tilt", ["A", "B"])
@pytest.mark.parametrize("conventional", [False, True])
def test_trunnions_match_linuxcnc_trtfuncs(tilt, conventional):
    rng = np.random.default_rng(7)
    rot_point, offset = (11.0, -23.0, 37.0), (3.0, -6.0, 14.0)
    kin = TableTable(tilt, rot_point=rot_point, rot_offset=offset, conventional_directions=conventional)
    for j in random_axes(rng, 40):
        L = float(rng.uniform(0, 80))
        tip, _ = kin.forward(j, L)
        want = linuxcnc_trt_world(tilt.lower() + "c", j, *rot_point,
                                  *(offset if tilt == "B" else (0.0,) + offset[1:]), L,
                                  1.0 if conventional else -1.0)
        close(tip[0] + [0, 0, L], want, 1e-9)


def test_trunnion_offset_along_the_tilt_axis_changes_nothing():
    a = TableTable("A", rot_point=(1, 2, 3), rot_offset=(0, 4, 5))
    b = TableTable("A", rot_point=(1, 2, 3), rot_offset=(99, 4, 5))
    axes = random_axes(np.random.default_rng(3), 20)
    close(a.forward(axes, 5)[0], b.forward(axes, 5)[0])


def test_head_head_matches_linuxcnc_5axiskins():
    rng = np.random.default_rng(11)
    kin = HeadHead("B", pivot_length=150)
    for j in random_axes(rng, 40):
        L = float(rng.uniform(0, 80))
        tip, axis = kin.forward(j, L)
        close(tip[0] + [0, 0, L], linuxcnc_5axis_world(j, 150 + L), 1e-9)
        # the axis points from the tip back to the pivot
        pivot = j[:3] + [0, 0, 150]
        close(axis[0], (pivot - tip[0]) / (150 + L))


# --- forward and inverse both ways ------------------------------------------------------

ALL = {
    "xyz": {},
    "xyza": {"rot_point": [0, 4, -30]},
    "xyzb": {"rot_point": [5, 0, -30], "conventional_directions": True},
    "xyzac-trt": {"rot_point": [10, 20, 30], "rot_offset": [0, 5, -8]},
    "xyzbc-trt": {"rot_point": [-10, 2, 0], "rot_offset": [7, 0, 12], "conventional_directions": True},
    "xyzbc-head-table": {"pivot_length": 120, "rot_point": [50, 60, 0]},
    "xyzac-head-table": {"pivot_length": 90, "rot_point": [-5, 6, 1], "conventional_directions": True},
    "xyzbc-head": {"pivot_length": 150},
    "xyzac-head": {"pivot_length": 80},
}


def test_every_kinematics_is_tested():
    assert set(ALL) == set(KINEMATICS)


@pytest.mark.parametrize("name", sorted(ALL))
def test_inverse_of_forward_gives_the_machine_axes_back(name):
    kin = make_kinematics(name, **ALL[name])
    rng = np.random.default_rng(5)
    axes = random_axes(rng, 200)
    L = rng.uniform(0, 60, len(axes))
    tip, axis = kin.forward(axes, L)
    # the pose itself as previous: the inverse must find exactly it (whole turns included)
    back = kin.inverse(tip, axis, L, previous=axes)
    close(back, axes, 1e-8)


@pytest.mark.parametrize("name", sorted(ALL))
def test_forward_of_inverse_gives_the_tip_and_axis_back(name):
    kin = make_kinematics(name, **ALL[name])
    rng = np.random.default_rng(9)
    # reachable tips and axes: from random poses; the inverse starts from elsewhere
    tip, axis = kin.forward(random_axes(rng, 200), 25.0)
    previous = random_axes(rng, 200)
    got = kin.inverse(tip, axis, 25.0, previous=previous)
    tip2, axis2 = kin.forward(got, 25.0)
    close(tip2, tip, 1e-8)
    close(axis2, axis, 1e-12)
    # unused rotary columns come from previous
    unused = [ROTARY_COLUMN[r] for r in "ABC" if r not in kin.rotaries]
    close(got[:, unused], previous[:, unused])


def test_machine_xyz_places_the_tip_with_the_rotaries_given():
    kin = make_kinematics("xyzac-trt", **ALL["xyzac-trt"])
    axes = random_axes(np.random.default_rng(2), 30)
    tip, _ = kin.forward(axes, 12.0)
    close(kin.machine_xyz(tip, axes[:, 3:], 12.0), axes[:, :3], 1e-9)
    close(kin.machine_xyz(tip, axes, 12.0), axes[:, :3], 1e-9)


# --- the closest solution ---------------------------------------------------------------

def _axis(tilt_deg, azimuth_deg):
    t, g = math.radians(tilt_deg), math.radians(azimuth_deg)
    return np.array([[math.sin(t) * math.cos(g), math.sin(t) * math.sin(g), math.cos(t)]])


def test_inverse_takes_the_branch_nearest_previous():
    kin = make_kinematics("xyzbc-head")
    k = _axis(30, 0)  # tool leaning toward +X at the top: 5axiskins B = +30 with C = 180 ...
    near0 = kin.inverse([[0, 0, 0]], k, previous=np.zeros(6))
    tip, axis = kin.forward(near0)
    close(axis, k)
    # ... or B = -30 with C = 0 (nearest C = 0)
    close(near0[0, 4:], [-30, 0])
    near180 = kin.inverse([[0, 0, 0]], k, previous=[0, 0, 0, 0, 0, 170])
    close(near180[0, 4:], [30, 180])


def test_inverse_adds_whole_turns_toward_previous():
    kin = make_kinematics("xyzac-trt")
    k = kin.forward(pose(c=10, a=20))[1]
    got = kin.inverse([[1, 2, 3]], k, previous=[0, 0, 0, 25, 0, 725])
    close(got[0, [3, 5]], [20, 730])
    got = kin.inverse([[1, 2, 3]], k, previous=[0, 0, 0, -340, 0, -355])
    close(got[0, [3, 5]], [-340, -350])


def test_singularity_axis_along_c_keeps_c_where_it_was():
    for name in ("xyzac-trt", "xyzbc-head", "xyzbc-head-table"):
        kin = make_kinematics(name)
        got = kin.inverse([[5, 6, 7]], [0, 0, 1], previous=[0, 0, 0, 0, 0, 123.0])
        assert got[0, 5] == 123.0
        tilt = got[0, 3] if "ac" in name else got[0, 4]
        assert tilt == 0.0
        close(kin.forward(got)[0], [[5, 6, 7]])


def test_fourth_axis_inverse_is_unique_up_to_whole_turns():
    kin = FourthAxis("A", rot_point=(0, 0, 0))
    got = kin.inverse([[0, 0, 25]], [0, 0, 1], previous=[0, 0, 0, 350, 0, 0])
    close(got, [[0, 0, 25, 360, 0, 0]])
    got = kin.inverse([[0, 25, 0]], [0, 1, 0], tool_length=5)
    close(got, [[0, 0, 30, 90, 0, 0]])


# --- bad configurations and unreachable poses -------------------------------------------

@pytest.mark.parametrize("name, params, message", [
    ("xyzq", {}, "unknown kinematics 'xyzq'; expected one of xyz, xyza"),
    ("xyz", {"rot_point": [0, 0, 0]}, "xyz does not take rot_point; it takes no parameters"),
    ("xyzac-trt", {"pivot_length": 10}, "xyzac-trt does not take pivot_length; it takes rot_point"),
    ("xyza", {"rot_point": [0, 0]}, "xyza: rot_point must be 3 finite numbers (mm)"),
    ("xyza", {"rot_point": "abc"}, "xyza: rot_point must be 3 numbers (mm)"),
    ("xyzac-trt", {"rot_offset": [0, float("nan"), 0]}, "xyzac-trt: rot_offset must be 3 finite numbers"),
    ("xyzbc-head", {"pivot_length": -1}, "xyzbc-head: pivot length must be a finite number >= 0 (mm)"),
])
def test_bad_configurations_say_what_was_expected(name, params, message):
    with pytest.raises(KinematicsError) as err:
        make_kinematics(name, **params)
    assert message in str(err.value)


def test_linuxcnc_names_are_accepted():
    assert make_kinematics("trivkins").name == "xyz"
    assert make_kinematics("5axiskins", pivot_length=5).name == "xyzbc-head"
    assert make_kinematics("XYZAC-TRT-KINS").name == "xyzac-trt"


@pytest.mark.parametrize("name, axis, reach", [
    ("xyz", [0, 0.5, 1], "this machine reaches only +Z"),
    ("xyza", [0.2, 0, 1], "only axes square to X (A turns about X)"),
    ("xyzb", [0, 0.2, 1], "only axes square to Y (B turns about Y)"),
])
def test_unreachable_axis_names_the_row(name, axis, reach):
    kin = make_kinematics(name)
    with pytest.raises(KinematicsError) as err:
        kin.inverse([[0, 0, 0], [1, 1, 1]], [[0, 0, 1], axis])
    assert "row 1: tool axis" in str(err.value) and reach in str(err.value)


def test_a_zero_axis_is_no_direction():
    with pytest.raises(KinematicsError, match="row 0: tool axis .* is not a direction"):
        make_kinematics("xyzbc-head").inverse([0, 0, 0], [0, 0, 0])


def test_shapes_are_checked():
    kin = make_kinematics("xyza")
    with pytest.raises(ValueError, match=r"axes: expected shape \(n, 6\)"):
        kin.forward(np.zeros((3, 5)))
    with pytest.raises(ValueError, match=r"previous: expected shape \(2, 6\)"):
        kin.inverse(np.zeros((2, 3)), [0, 0, 1], previous=np.zeros((3, 6)))


# --- tool points and instances of motion ------------------------------------------------

def test_tool_points_are_the_tip_and_axis_for_points_on_the_axis():
    kin = make_kinematics("xyzac-trt", **ALL["xyzac-trt"])
    axes = random_axes(np.random.default_rng(4), 25)
    tip, axis = kin.forward(axes, 15.0)
    pts = kin.tool_points(axes, 15.0, [[0, 0, 0], [0, 0, 10], [3, 0, 0], [0, 3, 0]])
    close(pts[:, 0], tip)
    close(pts[:, 1], tip + 10 * axis)
    # points off the axis stay square to it and at their radius
    for j in (2, 3):
        r = pts[:, j] - tip
        close(np.linalg.norm(r, axis=1), np.full(len(axes), 3.0))
        close(np.einsum("ij,ij->i", r, axis), np.zeros(len(axes)))


def test_instances_of_a_straight_three_axis_move_are_its_length_over_the_step():
    kin = Trivial()
    counts = kin.instance_counts([[0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 0]],
                                 [[3, 4, 0, 90, 0, 0], [0, 0, 0, 0, 0, 0]], 20, height=30, radius=3, step=0.5)
    assert counts.tolist() == [10, 1]  # A turns nothing on a 3-axis machine; no motion is one instance


def test_instances_of_a_fourth_axis_turn_follow_the_farthest_point():
    # the tool's cylinder (r 3, 20 high, standing on the tip 25 above the A axis): its
    # centre 35 above the axis, every point within hypot(10, 3) of it
    kin = FourthAxis("A")
    count = int(kin.instance_counts([0, 0, 45, 0, 0, 0], [0, 0, 45, 90, 0, 0], 20, height=20, radius=3,
                                    step=0.1)[0])
    assert count == math.ceil(math.pi / 2 * (35 + math.hypot(10, 3)) / 0.1)
    # and no fewer than the farthest point's arc needs (top rim, hypot(45, 3) from the axis)
    assert count >= math.pi / 2 * math.hypot(45, 3) / 0.1
    # along the A axis the distance does not grow: 100 mm further in X, the same count
    assert kin.instance_counts([100, 0, 45, 0, 0, 0], [100, 0, 45, 90, 0, 0], 20, height=20, radius=3,
                               step=0.1)[0] == count


def _surface(height, radius):
    """Points of the tool cylinder's surface (tool frame): rims, sides, axis ends."""
    phi = np.radians(np.arange(0, 360, 30))
    pts = [[0, 0, 0], [0, 0, height]]
    for h in (0.0, height / 2, height):
        pts += [[radius * math.cos(f), radius * math.sin(f), h] for f in phi]
    return np.array(pts)


@pytest.mark.parametrize("name", sorted(ALL))
def test_no_tool_point_moves_more_than_the_step_between_instances(name):
    kin = make_kinematics(name, **ALL[name])
    rng = np.random.default_rng(13)
    height, radius, step, L = 40.0, 4.0, 1.0, 30.0
    surface = _surface(height, radius)
    worst = []
    for _ in range(12):
        q0 = random_axes(rng, 1, span=80)[0]
        q1 = q0 + np.concatenate([rng.uniform(-40, 40, 3), rng.uniform(-60, 60, 3)])
        count = int(kin.instance_counts(q0, q1, L, height, radius, step)[0])
        # the instances, and 4 poses between each two (the bound holds along the way too)
        fine = instance_poses(q0, q1, 4 * count)
        pts = kin.tool_points(fine, L, surface)
        moved = np.linalg.norm(pts[4::4] - pts[:-4:4], axis=2)
        assert moved.max() <= step * (1 + 1e-9)
        sub = np.linalg.norm(np.diff(pts, axis=0), axis=2).sum(axis=0)  # path length of each point
        worst.append(sub.max() / count)
    # the bound is not wildly loose: the farthest-moving point uses a fair share of the step
    assert max(worst) > 0.3 * step


def test_instance_poses_include_both_ends_exactly():
    q0, q1 = np.array([0.1, 0.2, 0.3, 10, 20, 30]), np.array([1.7, -2.2, 3.3, -10, 200, 31])
    poses = instance_poses(q0, q1, 7)
    assert poses.shape == (8, 6) and (poses[0] == q0).all() and (poses[-1] == q1).all()
    close(np.diff(poses, axis=0), np.tile((q1 - q0) / 7, (7, 1)))


def test_instance_counts_refuse_a_step_that_is_not_positive():
    with pytest.raises(ValueError, match="step must be a positive number"):
        Trivial().instance_counts(np.zeros(6), np.ones(6), 0, 10, 3, 0.0)


def test_fourth_axis_turn_cut_by_instances_leaves_a_cylinder():
    """Machine poses -> instances of motion -> Cutter.cut_poses: a ball end mill standing
    still while A turns -15..15 deg cuts, in the part, a groove whose bottom is the cylinder
    of radius (ball centre's radius - ball radius) about the A axis."""
    from sim.cut import Cutter
    from sim.frame import Frame
    from sim.grid import DexelGrid
    from sim.tools import parse_tool_spec

    sp = 0.25
    frame = Frame.top(0.0, -15.0, 20.0, 15.0, sp)
    grid = DexelGrid.from_intervals(frame, np.zeros(frame.shape), np.full(frame.shape, 30.0))
    tool = parse_tool_spec("ball:6:L=20")
    kin = FourthAxis("A")
    L = 20.0
    q0, q1 = np.array([10.0, 0, 26 + L, -15, 0, 0]), np.array([10.0, 0, 26 + L, 15, 0, 0])
    step = 0.5 * sp
    count = int(kin.instance_counts(q0, q1, L, height=20.0, radius=3.0, step=step)[0])
    tips, axes = kin.forward(instance_poses(q0, q1, count), L)
    assert Cutter(grid, tool).cut_poses(tips, axes, 1) > 0
    y = -15.0 + np.arange(frame.nv) * sp
    inside = np.abs(y) <= 26 * math.sin(math.radians(15)) - 3 * sp
    bottom = grid.top()[inside, int(round(10.0 / sp))]
    want = np.sqrt(26.0**2 - y[inside] ** 2)
    # never deeper than the cylinder; shallower only by the cusps between instances
    assert (bottom >= want - 1e-5).all()
    np.testing.assert_allclose(bottom, want, atol=2e-3)


def test_inverse_path_keeps_the_rotaries_continuous():
    # a tool axis circling the vertical twice at 30 deg tilt: C winds on past 360
    # instead of jumping back, and the tilt keeps its sign
    kin = make_kinematics("xyzbc-head", pivot_length=100)
    az = np.linspace(0, 720, 145)
    k = np.stack([np.sin(np.radians(30)) * np.cos(np.radians(az)),
                  np.sin(np.radians(30)) * np.sin(np.radians(az)), np.full(len(az), np.cos(np.radians(30)))], 1)
    tips = np.stack([np.cos(np.radians(az)), np.sin(np.radians(az)), np.zeros(len(az))], 1) * 20
    axes = kin.inverse_path(tips, k, 10.0, start=[0, 0, 0, 0, -30, 0])
    assert np.abs(np.diff(axes[:, 5])).max() < 5.01 and axes[-1, 5] == pytest.approx(720.0)
    close(axes[:, 4], np.full(len(az), -30.0))
    tip2, k2 = kin.forward(axes, 10.0)
    close(tip2, tips, 1e-9)
    close(k2, k, 1e-12)


def test_move_instances_are_the_forward_of_the_instance_poses():
    from sim.kinematics import move_instances

    kin = FourthAxis("A")
    q0, q1 = np.array([0.0, 0, 45, 0, 0, 0]), np.array([5.0, 0, 45, 30, 0, 0])
    tips, axes = move_instances(kin, q0, q1, 20.0, 20.0, 3.0, 0.5)
    count = int(kin.instance_counts(q0, q1, 20.0, 20.0, 3.0, 0.5)[0])
    assert len(tips) == count + 1
    want_tips, want_axes = kin.forward(instance_poses(q0, q1, count), 20.0)
    close(tips, want_tips)
    close(axes, want_axes)
