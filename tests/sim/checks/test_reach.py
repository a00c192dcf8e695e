"""Material a tool cannot reach (sim.checks.reach), and how an undercut finding says so.

Before, every undercut read "material left on the part": the fillet a ball must leave
in an inside corner (the corpus's gouge-free ``sphere_on_plate`` path reports one where
the dome meets the block) read the same as material the path missed. Now the whole-model
assessment measures how much of an undercut region its finishing tool cannot reach
without cutting into the design, and ``simulate`` says "the ball:6 cannot reach" when
that is nearly all of it.

Oracle: a design with a vertical step (a floor at z = 5 below x = 20, a plateau at
z = 15 beyond) finished by a 6 mm ball whose tips follow the exact drop-cutter height. The
lowest a ball of radius R reaches over the floor next to the wall is the fillet
``z = 5 + R - sqrt(R^2 - (x - (20 - R))^2)`` for ``20 - R < x < 20``.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from monitor.cli import main
from sim.checks import reach
from sim.checks.design_kernels import tool_reach_floor
from sim.tools import parse_tool_spec

R = 3.0
WALL_X, FLOOR_Z, PLATEAU_Z = 20.0, 5.0, 15.0


def step_height(x):
    return np.where(np.asarray(x) < WALL_X, FLOOR_Z, PLATEAU_Z)


def fillet(x):
    """The lowest the ball reaches over the floor at ``x`` (the design where it reaches it)."""
    x = np.asarray(x, np.float64)
    c = WALL_X - R
    out = np.where(x < WALL_X, FLOOR_Z, PLATEAU_Z).astype(np.float64)
    corner = (x > c) & (x < WALL_X)
    out[corner] = FLOOR_Z + R - np.sqrt(R * R - (x[corner] - c) ** 2)
    return out


SP = 0.1


def step_field():
    """The step on rays SP apart: x (nu,), the design (41, nu) and the rays of a row at
    least two ball radii from the field's ends (they see the whole field around them)."""
    x = np.arange(0.0, 40.0 + 1e-9, SP)
    return x, np.tile(step_height(x), (41, 1)).astype(np.float64), (x > 2 * R) & (x < 40 - 2 * R)


def floor_of_row(z, tool, sp, row: int = 20):
    """The tool's reach over every ray of a middle row (the field runs on along y)."""
    mi = np.arange(z.shape[1], dtype=np.int64)
    floor, measured = tool_reach_floor(z, *reach.footprint(tool, sp), mi, np.full_like(mi, row), 10**12)
    assert measured
    return floor


def test_the_ball_reaches_down_to_the_fillet_of_an_inside_corner():
    x, z, inner = step_field()
    sp = SP
    floor = floor_of_row(z, parse_tool_spec("ball:6"), sp)
    # the fillet, to the grid's resolution: the ray on the wall's foot holds the plateau,
    # so the grid's wall stands anywhere from one spacing before x = 20 to x = 20
    assert np.all(floor[inner] >= fillet(x[inner]) - 1e-9)
    assert np.all(floor[inner] <= fillet(x[inner] + sp) + 1e-9)
    corner = inner & (x > WALL_X - R) & (x < WALL_X - sp)
    assert np.all(floor[corner] > FLOOR_Z)   # out of the ball's reach over the whole fillet
    # never below the design (no gouge), and the flat floor and plateau are reached exactly
    assert np.all(floor[inner] >= step_height(x[inner]) - 1e-12)
    flat = inner & ((x < WALL_X - R - sp) | (x >= WALL_X))
    assert np.array_equal(floor[flat], step_height(x[flat]).astype(np.float64))


def test_a_flat_end_mill_reaches_into_the_corner():
    x, z, inner = step_field()
    floor = floor_of_row(z, parse_tool_spec("flat:6"), SP)
    assert np.array_equal(floor[inner], step_height(x[inner]).astype(np.float64))


def test_unreachable_share_of_a_fillet_and_of_a_missed_strip():
    x, design, _ = step_field()
    sp = SP
    ball = parse_tool_spec("ball:6")
    # the fillet left in the corner: all out of reach
    model = np.tile(fillet(x), (41, 1))
    # rows 10-30: the field runs on along y past them (its ends are open: tips may stand there)
    rows = np.zeros((41, 1), bool)
    rows[10:31] = True
    corner = np.nonzero((((x > WALL_X - R) & (x < WALL_X))[None, :] & rows).reshape(-1))[0]
    assert reach.unreachable_share(design, model, corner, ball, sp, 0.05) == pytest.approx(1.0)
    # a strip 1 mm high the path left on the open floor: all within reach
    model = design.copy()
    model[:, (x > 8) & (x < 10)] += 1.0
    strip = np.nonzero((((x > 8) & (x < 10))[None, :] & rows).reshape(-1))[0]
    assert reach.unreachable_share(design, model, strip, ball, sp, 0.05) == 0.0


def write_step(tmp_path, skip_from: float | None = None):
    """The step design (a height-field sheet), its stock and a ball raster along Y whose
    tips follow the exact drop-cutter height, passes 0.25 mm apart across X; passes from
    ``skip_from`` to 4 mm past it are left out (material the ball could have cut)."""
    import trimesh

    xs = np.array([-10.0, WALL_X - 1e-3, WALL_X, 50.0])
    ys = np.array([-10.0, 30.0])
    X, Y = np.meshgrid(xs, ys)
    Z = step_height(X)
    verts = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    nv, nu = X.shape
    idx = np.arange(nv * nu).reshape(nv, nu)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    trimesh.Trimesh(verts, faces, process=False).export(str(tmp_path / "step.stl"))
    lines = ["G21 G90 G17 G94", "T1 M6", "S12000 M3", "G0 Z30", "G0 X0 Y-5", "G1 Z10 F600", "F2000"]
    k = 0
    for px in np.arange(0.0, 40.0 + 1e-9, 0.25):
        if skip_from is not None and skip_from <= px <= skip_from + 4.0:
            continue
        # the drop-cutter tip over the step: the floor, or riding the wall's top edge
        if px <= WALL_X - R:
            tip = FLOOR_Z
        elif px < WALL_X:
            tip = PLATEAU_Z - R + math.sqrt(R * R - (WALL_X - px) ** 2)
        else:
            tip = PLATEAU_Z
        tip += 0.001
        y0, y1 = (-5.0, 25.0) if k % 2 == 0 else (25.0, -5.0)
        lines += [f"G1 X{px:.4f} Y{y0:.4f} Z{tip:.4f}", f"G1 Y{y1:.4f}"]
        k += 1
    lines += ["G0 Z30", "M5", "M30"]
    (tmp_path / "step.nc").write_text("\n".join(lines) + "\n")
    return tmp_path / "step.nc", tmp_path / "step.stl"


def simulate(tmp_path, capsys, prog, stl, *flags):
    rc = main(["simulate", str(prog), "--stock", "box:0,0,0,40,20,20", "--tool", "ball:6:L=20",
               "--design", str(stl), "--resolution", "0.2", *flags])
    return rc, capsys.readouterr().out


def test_simulate_says_the_corner_fillet_is_out_of_the_balls_reach(tmp_path, capsys):
    prog, stl = write_step(tmp_path)
    rc, out = simulate(tmp_path, capsys, prog, stl, "--json")
    under = [f for f in json.loads(out)["findings"] if f["kind"] == "undercut"]
    assert rc == 1 and len(under) == 1, under
    f = under[0]
    assert f["detail"]["unreachable_share"] >= reach.UNREACHABLE_SHARE
    assert f["detail"]["finishing_tool"].startswith("ball:6")
    assert WALL_X - R <= f["position"][0] <= WALL_X
    rc, out = simulate(tmp_path, capsys, prog, stl)
    assert "material left where the ball:6:L=20 cannot reach (a smaller tool would)" in out, out


def test_material_the_path_missed_is_not_blamed_on_the_tool(tmp_path, capsys):
    prog, stl = write_step(tmp_path, skip_from=6.0)
    rc, out = simulate(tmp_path, capsys, prog, stl, "--json")
    under = sorted((f for f in json.loads(out)["findings"] if f["kind"] == "undercut"),
                   key=lambda f: f["position"][0])
    assert rc == 1 and len(under) == 2, under
    missed, corner = under
    assert 6.0 <= missed["position"][0] <= 10.0 and missed["detail"]["unreachable_share"] == 0.0
    assert corner["detail"]["unreachable_share"] >= reach.UNREACHABLE_SHARE
    rc, out = simulate(tmp_path, capsys, prog, stl)
    rows = [ln for ln in out.splitlines() if ln.startswith("undercut")]
    assert len(rows) == 2 and sum("cannot reach" in ln for ln in rows) == 1, out


def test_a_region_too_large_to_measure_is_not_measured(monkeypatch):
    design = np.zeros((50, 50))
    model = design + 0.5
    members = np.arange(2500, dtype=np.int64)
    ball = parse_tool_spec("ball:6")
    assert reach.unreachable_share(design, model, members, ball, 0.5, 0.05) == 0.0
    monkeypatch.setattr(reach, "MAX_STEPS", 1000)
    assert reach.unreachable_share(design, model, members, ball, 0.5, 0.05) is None


def test_past_the_grids_edge_the_tool_may_stand():
    """The grid covers the stock: past its edge lies no design, and the tool may stand
    there, as on rays of the grid with no design. A 0.8 mm trough along the edge, a wall
    5 mm high beside it: measured on the grid, and on the same grid with 3 mm of empty rays
    added around it, the trough's share out of the ball's reach is the same (before, tips
    past the edge were not tried and all of it was out of reach: the carpet path's strips
    along the stock's ends, which its passes stop short of, read "a smaller tool would")."""
    sp, pad = 0.2, 15
    design = np.full((60, 40), 5.0)
    design[:5, :] = 0.0
    model = design.copy()
    model[:5, :] += 1.0
    trough = np.arange(5 * 40, dtype=np.int64)
    ball = parse_tool_spec("ball:6")
    share = reach.unreachable_share(design, model, trough, ball, sp, 0.05)
    big_design = np.full((60 + 2 * pad, 40 + 2 * pad), np.nan)
    big_design[pad:-pad, pad:-pad] = design
    big_model = big_design.copy()
    big_model[pad:-pad, pad:-pad] = model
    j, i = trough // 40 + pad, trough % 40 + pad
    assert share == reach.unreachable_share(big_design, big_model, j * (40 + 2 * pad) + i, ball, sp, 0.05)
    # part of it is out of reach all the same (the wall's fillet), part is not
    assert 0.0 < share < 1.0
