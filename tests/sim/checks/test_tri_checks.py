"""The checks on a tri-dexel model and with tilted tools (issue 16): the same findings as
on one Z grid where that grid sees the fault, and the faults only the X and Y grids see
(a thin rib the Z rays step over, a gouge into a wall parallel to Z between two Z rays).

The reproducing case of the issue: a 5-axis head tilts the tool 30 degrees toward a
standing rib; the tip and the flutes stay clear of it, the holder passes through it."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from sim.boolean import union
from sim.checks import Checker, Fixture
from sim.frame import Frame
from sim.gcode.moves import MoveKind, empty_moves
from sim.kinematics import HeadHead
from sim.solids import box_grid
from sim.tools import parse_tool_spec
from sim.tridexel import TriDexel
from tests.sim.checks.helpers import table
from tests.sim.checks.test_collisions import LIMITS, SPACING, pocket, stock

F, R = MoveKind.FEED, MoveKind.RAPID


def tri_stock():
    """test_collisions' stock (60 x 40 x 20 box) as a tri-dexel model."""
    return TriDexel.build((0, 0, 0), (60, 40, 20), SPACING, lambda f: box_grid(f, (0, 0, 0), (60, 40, 20)))


def found_on(model, moves, spec="flat:6:L=20:S=6:H=30", **kw):
    kw.setdefault("limits", LIMITS)
    kw.setdefault("fixtures", [Fixture.box((62, 0, 0), (70, 40, 35), SPACING, name="jaw")])
    ch = Checker(model, parse_tool_spec(spec), **kw)
    _, found = ch.cut_and_check(moves)
    return found


def summary(found):
    """What a finding says, NaN sizes as None (so two summaries compare equal)."""
    def size(v):
        return None if np.isnan(v) else round(v, 6)

    return [(f.kind, f.line, f.lines, f.stage, size(f.volume), size(f.depth)) for f in found]


@pytest.mark.parametrize("case", ["clean", "rapid", "holder", "shank", "above_flutes", "fixture", "plunge",
                                  "depth_of_cut", "spindle"])
def test_same_findings_as_the_z_grid_where_it_sees_them(case):
    """3-axis faults test_collisions plants, on a box: the tri-dexel model finds the same
    kinds at the same lines, with the Z grid's volumes (it sees all of them)."""
    stopped = pocket()
    stopped["spindle_dir"][3:] = 0  # M5 before line 40
    kw = {"depth_of_cut": {"max_depth_of_cut": 4.0}}.get(case, {})
    moves, spec = {
        "plunge": (pocket(), "flat:6:L=20:nocenter"),
        "depth_of_cut": (pocket(z=15.0), "flat:6:L=20:S=6:H=30"),
        "spindle": (stopped, "flat:6:L=20:S=6:H=30"),
        "clean": (pocket(), "flat:6:L=20:S=6:H=30"),
        "rapid": (pocket(extra=[(R, (10, 10, 30), (30, 20, 15))]), "flat:6:L=20:S=6:H=30"),
        "holder": (table([(R, (30, 20, 40), (30, 20, 25)), (F, (30, 20, 25), (30, 20, 3)),
                          (R, (30, 20, 3), (30, 20, 40))]), "flat:6:L=10:S=6:SL=5:H=30:HL=10"),
        "shank": (table([(R, (30, 20, 40), (30, 20, 25)), (F, (30, 20, 25), (30, 20, 4)),
                         (R, (30, 20, 4), (30, 20, 40))]), "flat:6:L=10:S=10"),
        "above_flutes": (table([(R, (10, 20, 40), (10, 20, 25)), (F, (10, 20, 25), (10, 20, 10)),
                                (F, (10, 20, 10), (40, 20, 10)), (F, (40, 20, 10), (40, 20, 40))]), "flat:6:L=5"),
        "fixture": (pocket(extra=[(R, (10, 10, 30), (65, 20, 30)), (R, (65, 20, 30), (10, 10, 30))]),
                    "flat:6:L=20:S=6:H=30"),
    }[case]
    on_z = found_on(stock(), moves, spec, **kw)
    on_tri = found_on(tri_stock(), moves, spec, **kw)
    assert summary(on_tri) == summary(on_z)
    assert bool(on_z) == (case != "clean")


def test_predict_on_a_tri_dexel_model_leaves_it_as_it_was():
    kin = HeadHead("B")
    moves, _ = tilted_pass(kin)
    _, tri_model = rib_models()
    ch = Checker(tri_model, parse_tool_spec(TILTED_TOOL), kinematics=kin)
    before = tri_model.volumes()
    predicted = ch.predict(moves)
    assert tri_model.volumes() == before
    assert [(f.kind, f.line) for f in predicted] == [("holder_contact", 20)]
    _, found = ch.cut_and_check(moves)
    assert summary(found) == summary(predicted)


# --- a gouge into a wall parallel to Z, between two Z rays ---------------------------------------

WALL_X = 10.45  # the design's wall; the Z rays stand at X 10.0 and 10.5
CUT_X = 10.1    # where the flat end mill's side cuts it: 0.35 mm into the part


def wall_case():
    """A 30 x 20 x 20 block; the design keeps X <= 10.45; a 4 mm end mill runs along Y
    with its side at X 10.1 (line 20), 15 mm deep."""
    lo, hi = (0, 0, 0), (30, 20, 20)
    design = trimesh.creation.box(bounds=[(0, 0, 0), (WALL_X, 20, 20)])
    moves = table([(R, (CUT_X + 2, -5, 30), (CUT_X + 2, -5, 5)), (F, (CUT_X + 2, -5, 5), (CUT_X + 2, 25, 5)),
                   (R, (CUT_X + 2, 25, 5), (CUT_X + 2, 25, 30))])
    z_model = box_grid(Frame.top(0, 0, 30, 20, SPACING), lo, hi)
    tri_model = TriDexel.build(lo, hi, SPACING, lambda f: box_grid(f, lo, hi))
    return z_model, tri_model, design, moves


def test_gouge_into_a_wall_the_z_rays_step_over():
    z_model, tri_model, design, moves = wall_case()
    tool = parse_tool_spec("flat:4:L=20")
    on_z = Checker(z_model, tool, design=design)
    on_z.cut_and_check(moves)
    # the Z rays at X 10.0 (inside the part, untouched) and 10.5 (outside it) see nothing
    assert on_z.all_findings() == []
    assert on_z.assess_model(undercut=False) == []
    on_tri = Checker(tri_model, tool, design=design)
    _, found = on_tri.cut_and_check(moves)
    assert [(f.kind, f.line) for f in found] == [("gouge", 20)]
    whole = on_tri.assess_model(undercut=False)
    assert [(f.kind, f.line, f.lines) for f in whole] == [("gouge", 20, (20,))]
    g = whole[0]
    # the X rays hold the cut face at X 10.1: 0.35 mm inside the design, measured along them
    assert g.depth == pytest.approx(WALL_X - CUT_X, abs=1e-3)
    assert g.detail["grid"] == "x"
    x, y, z = g.position
    assert abs(x - CUT_X) <= SPACING / 2 and 0 <= y <= 20 and 5 - 1e-6 <= z <= 20 + 1e-6
    # the face cut into the part: 20 x 15 mm, 0.35 deep (the X rays' estimate)
    assert g.volume == pytest.approx(20 * 15 * (WALL_X - CUT_X), rel=0.15)
    assert set(g.to_json()) >= {"kind", "line", "worst_line", "lines", "stage", "position", "depth", "area",
                                "volume", "message"}


# --- the holder of a tilted tool through a standing rib (the case) ---------------------

RIB = (10.2, 10.8)     # a 0.6 mm rib: the Z rays (every 1 mm) step over it
RIB_SPACING = 1.0
TILT_B = -30.0         # the head tilts the tool 30 degrees: its axis leans toward +X
TIP_X, TIP_Z = 1.5, 8.0
TILTED_TOOL = "flat:4:L=8:S=4:SL=4:H=30:HL=20"  # holder 30 mm wide from 12 mm above the tip


def rib_models(spacing=RIB_SPACING, rib=RIB, rib_top=25.0):
    """A 30 x 20 x 5 base plate with a rib standing on it along Y (X ``rib``, up to
    ``rib_top``): as one Z grid and as a tri-dexel model."""
    base = ((0, 0, 0), (30, 20, 5))
    wall = ((rib[0], 0, 5), (rib[1], 20, rib_top))

    def solid(f):
        return union(box_grid(f, *base), box_grid(f, *wall))

    lo, hi = (0, 0, 0), (30, 20, 30)
    return solid(Frame.top(0, 0, 30, 20, spacing)), TriDexel.build(lo, hi, spacing, solid)


def tilted_pass(kin, b=TILT_B, tip_x=TIP_X, tip_z=TIP_Z):
    """Lines 10-30 on a 5-axis head: down beside the part, a feed along Y past the rib
    (line 20), up; the head tilted ``b`` degrees all the way."""
    tips = np.array([[tip_x, -25, 40], [tip_x, -25, tip_z], [tip_x, 45, tip_z], [tip_x, 45, 40]], float)
    _, axis = kin.forward(np.array([[0, 0, 0, 0, b, 0]], float))
    poses = np.zeros((4, 6))
    poses[:, :3] = kin.machine_xyz(tips, np.tile([0.0, b, 0.0], (4, 1)), 0.0)
    poses[:, 4] = b
    m = empty_moves(3)
    m["line"] = [10, 20, 30]
    m["kind"] = [int(R), int(F), int(R)]
    m["start"], m["end"] = poses[:-1], poses[1:]
    m["spindle"], m["spindle_dir"], m["feed"], m["tool"] = 12000.0, 1, 600.0, 1
    return m, axis[0]


def test_tilted_holder_through_a_rib_the_z_grid_cannot_hold():
    kin = HeadHead("B")
    moves, axis = tilted_pass(kin)
    assert axis[0] == pytest.approx(0.5) and axis[2] == pytest.approx(np.sqrt(3) / 2)  # leans toward +X
    z_model, tri_model = rib_models()
    tool = parse_tool_spec(TILTED_TOOL)
    on_tri = Checker(tri_model, tool, kinematics=kin)
    res, found = on_tri.cut_and_check(moves)
    # the flutes and the shank stay clear of everything: nothing is cut
    assert res.removed.sum() == 0.0
    assert [(f.kind, f.line) for f in found] == [("holder_contact", 20)]
    # the rib the holder meets is the X grid's: 0.6 mm thick, where the holder crosses it
    assert 0 < found[0].volume < 0.6 * 20 * 20
    # one Z grid at the same spacing holds no rib at all (its rays step over it): it says nothing
    on_z = Checker(z_model, tool, kinematics=kin)
    assert on_z.cut_and_check(moves)[1] == []
    assert np.all(z_model.top() == 5.0)


def test_tilted_holder_over_a_wall_the_z_grid_holds():
    """A thick wall the Z grid holds, whose top the tilted holder's lower rim dips into
    while the holder's bottom on the tool axis (tip + 12 mm up) stays above it: found on
    both models (the look for bodies that cannot reach the material must follow the tilt)."""
    kin = HeadHead("B")
    moves, _ = tilted_pass(kin)
    z_model, tri_model = rib_models(spacing=0.5, rib=(12.0, 20.0), rib_top=14.0)
    tool = parse_tool_spec(TILTED_TOOL)
    for model in (z_model, tri_model):
        ch = Checker(model, tool, kinematics=kin)
        res, found = ch.cut_and_check(moves)
        assert res.removed.sum() == 0.0
        assert [(f.kind, f.line) for f in found] == [("holder_contact", 20)], type(model).__name__


def test_tilted_holder_into_a_fixture():
    """A clamp where the thick wall stood: the tilted holder's rim dips into it (the
    fixture check follows the kinematics too), on either model."""
    kin = HeadHead("B")
    moves, _ = tilted_pass(kin)
    box = Fixture.box((12.0, 0.0, 5.0), (20.0, 20.0, 14.0), 0.5, name="clamp")
    clamp = Fixture(box.name, box.grid, kinematics=kin)   # on a head machine: the head's tilt
    z_model, tri_model = rib_models(spacing=0.5, rib=(25.0, 26.0), rib_top=6.0)
    tool = parse_tool_spec(TILTED_TOOL)
    for model in (z_model, tri_model):
        ch = Checker(model, tool, kinematics=kin, fixtures=[clamp])
        _, found = ch.cut_and_check(moves)
        assert [(f.kind, f.line, f.detail["group"]) for f in found] == [
            ("fixture_collision", 20, "holder in fixture clamp")], type(model).__name__


def test_a_design_placed_by_an_offset_is_placed_on_every_grid():
    """The job's design STL moved by its [design] offset: the X and Y grids' casts carry
    the offset too (the wall gouge is found where it is, not 5 mm off)."""
    from sim.checks.error_map import DesignModel

    _, tri_model, mesh, moves = wall_case()
    shifted = mesh.copy()
    shifted.apply_translation((-5.0, 0.0, 0.0))
    placed = DesignModel(tri_model.grids["z"].frame, shifted, offset=(5.0, 0.0, 0.0))
    ch = Checker(tri_model, parse_tool_spec("flat:4:L=20"), design=placed)
    ch.cut_and_check(moves)
    whole = ch.assess_model(undercut=False)
    assert [(f.kind, f.line) for f in whole] == [("gouge", 20)]
    assert whole[0].depth == pytest.approx(WALL_X - CUT_X, abs=1e-3)
