"""Gouge and undercut of the corpus finishing paths on their design parts
(../shared/corpus/parts/README.md): 6 mm ball paths are gouge-free at 0.002 mm and leave
material only where the ball cannot reach; an 8 mm ball on the carpet path gouges by
about 0.34 mm."""

import numpy as np
import pytest

from sim.checks import Checker
from sim.checks.motion import is_motion
from sim.frame import Frame
from sim.gcode import load_program
from sim.solids import box_grid
from sim.tolerance import Tolerance
from sim.tools import parse_tool_spec

BOXES = {"sphere_on_plate": (0, 0, -1, 76.4923, 76.4923, 30.8718),
         "carpet1": (0, -82, -10, 152, 66, 5.197857)}
SPACING = {"sphere_on_plate": 0.25, "carpet1": 0.4}
R = 3.0


@pytest.fixture(scope="module")
def programs(shared):
    cache = {}

    def get(part):
        if part not in cache:
            m = load_program(shared / "corpus" / "parts" / f"{part}_ball6_finish.ngc").moves.copy()
            # the interpreter starts at machine zero, inside these stock boxes; the machine
            # really starts wherever the first rapid finds it, so that move is a no-op here
            k = np.nonzero(is_motion(m))[0][0]
            m["start"][k] = m["end"][k]
            cache[part] = m
        return cache[part]
    return get


def simulate(shared, programs, part, spec, tol):
    b = BOXES[part]
    frame = Frame.top(b[0], b[1], b[3], b[4], SPACING[part])
    ch = Checker(box_grid(frame, b[:3], b[3:]), parse_tool_spec(spec),
                 design=shared / "corpus" / "parts" / f"{part}.stl", tol=tol)
    _, during = ch.cut_and_check(programs(part))
    after = ch.assess_model()
    return ch, during, after


@pytest.fixture(scope="module")
def sphere6(shared, programs):
    return simulate(shared, programs, "sphere_on_plate", "ball:6", Tolerance(gouge=0.002, undercut=0.05))


@pytest.fixture(scope="module")
def carpet6(shared, programs):
    return simulate(shared, programs, "carpet1", "ball:6", Tolerance(gouge=0.002, undercut=0.01))


def test_sphere_on_plate_ball6_has_no_gouge_and_no_collision(sphere6):
    ch, during, after = sphere6
    assert during == []
    assert [f for f in after if f.kind == "gouge"] == []
    assert np.nanmin(ch.error_map.gouge) > -0.002


def test_sphere_on_plate_ball6_leaves_material_only_on_the_dome_flanks_and_its_corner(sphere6):
    ch, _, after = sphere6
    f = ch.frame
    ex = ch.error_map.excess.reshape(f.shape)
    y, x = np.mgrid[0:f.nv, 0:f.nu] * f.spacing
    r = np.hypot(x - 38.2461, y - 38.2461)  # dome axis; it meets the block at r = 19.10
    edge = np.minimum.reduce([x, y, 76.4923 - x, 76.4923 - y])
    left = (ex > 0.05) & (edge > R + 0.5)
    assert left.any()
    # flat block top and dome cap are finished (scallops 0.04 mm < 0.05 mm) ...
    assert r[left].min() > 8.0 and r[left].max() < 19.10 + R + 0.5
    # ... and the most material is left in the concave corner the ball cannot enter
    worst = [u for u in after if u.kind == "undercut" and min(u.position[0], u.position[1],
                                                              76.4923 - u.position[0], 76.4923 - u.position[1]) > R + 0.5]
    w = max(worst, key=lambda u: u.depth)
    assert abs(np.hypot(w.position[0] - 38.2461, w.position[1] - 38.2461) - 19.10) < R
    assert 14.9359 < w.position[2] < 14.9359 + R


def test_carpet_ball6_has_no_gouge(carpet6):
    ch, during, after = carpet6
    assert during == []
    assert [f for f in after if f.kind == "gouge"] == []
    assert np.nanmin(ch.error_map.gouge) > -0.002


def test_carpet_ball6_leaves_material_only_in_the_creases_and_at_the_edges(carpet6, shared):
    import trimesh

    ch, _, _ = carpet6
    f = ch.frame
    # the profile (every X section is the same) and its concave creases
    v = trimesh.load(shared / "corpus" / "parts" / "carpet1.stl", force="mesh").vertices
    prof = np.unique(np.round(v[:, 1:], 4), axis=0)
    slope = np.diff(prof[:, 1]) / np.diff(prof[:, 0])
    creases = prof[1:-1, 0][np.diff(slope) > 0]
    assert len(creases) == 4
    ex = ch.error_map.excess.reshape(f.shape)
    y = f.origin[1] + np.arange(f.nv) * f.spacing
    # rows (constant Y) where most rays keep more than 0.01 mm: scallops (0.023 mm high,
    # 0.75 mm apart) never fill a row; material the ball cannot reach does
    rows = y[(ex > 0.01).mean(axis=1) > 0.5]
    near_crease = np.abs(rows[:, None] - creases[None, :]).min(axis=1) < 1.0
    near_edge = (rows < -82 + R) | (rows > 66 - R)  # the ball centre never leaves Y -82..66
    assert np.all(near_crease | near_edge), rows[~(near_crease | near_edge)]
    for c in creases:
        assert np.abs(rows - c).min() < 1.0


def test_carpet_with_an_8mm_ball_gouges_about_0_34(shared, programs):
    ch, during, after = simulate(shared, programs, "carpet1", "ball:8", Tolerance(gouge=0.002, undercut=0.05))
    gouges = [f for f in after if f.kind == "gouge"]
    assert gouges
    deepest = max(gouges, key=lambda f: f.depth)
    assert deepest.depth == pytest.approx(0.34, abs=0.02)
    assert deepest.line > 0 and deepest.volume > 0 and deepest.area > 0
    # found while cutting too, at the same depth
    assert max(f.depth for f in during if f.kind == "gouge") == pytest.approx(deepest.depth, abs=1e-6)
