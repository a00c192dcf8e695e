"""pyvista views rendered offscreen (the bundled job's 3-D pictures are checked in
test_run_pictures.py against a reference image)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.sim.trace_helpers import ball_cut, box

pv = pytest.importorskip("pyvista")


@pytest.fixture(scope="module")
def cut_grid():
    g = box(81, 61, 0.5, 0.0, 10.0)
    for k in range(8):
        ball_cut(g, (6 + 4 * k, 10 + 3 * k, 7.0), 3.0, k + 1)
    return g


def test_heightfield_follows_the_tops(cut_grid):
    from monitor.render.view3d import heightfield

    sg = heightfield(cut_grid.frame, cut_grid.top())
    assert sg.n_points == cut_grid.frame.n_rays
    z = np.asarray(sg.points)[:, 2]
    assert z.min() == pytest.approx(np.nanmin(cut_grid.top())) and z.max() == pytest.approx(10.0)
    # point (i, j) sits at X = i*spacing, Y = j*spacing with the ray's top
    pts = np.asarray(sg.points)
    k = np.nonzero((np.abs(pts[:, 0] - 6.0) < 1e-9) & (np.abs(pts[:, 1] - 10.0) < 1e-9))[0][0]
    assert pts[k, 2] == pytest.approx(cut_grid.top()[20, 12])


def test_interactive_needs_a_display(monkeypatch):
    from monitor.render import view3d
    from sim.errors import InputError

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(InputError, match="display"):
        view3d.interactive(None)


def test_3d_view_without_design_is_depth_of_cut_and_vtk_is_quiet(tmp_path, capfd):
    """Without a design the 3-D view colours the depth of cut from 0 to the deepest cut,
    its colour bar titled in mm; VTK prints nothing offscreen (QA 10)."""
    from monitor.render import view3d
    from monitor.render.runpicture import RunPictures
    from monitor.trace_io import RunView
    from tests.monitor.run_helpers import record_run

    run = tmp_path / "r.dexrun"
    snaps, _ = record_run(run)
    capfd.readouterr()
    with RunView(run) as view:
        pics = RunPictures(view, size=200)
        assert pics.color_by == "depth"
        pl = view3d.stage_plotter(pics, view.last_stage, window_size=(200, 200))
        try:
            assert "depth of cut (mm)\n" in pl.scalar_bars
            lo, hi = pl.scalar_bars["depth of cut (mm)\n"].GetLookupTable().GetRange()
            deepest = np.nanmax(snaps[0].top() - snaps[view.last_stage].top())
            assert lo == 0.0 and hi == pytest.approx(deepest, rel=1e-3)
        finally:
            pl.close()
        img = view3d.stage_png(pics, view.last_stage, window_size=(200, 200))
    assert img.shape == (200, 200, 3) and img.std() > 10
    assert capfd.readouterr().err == ""


def _hue_bin(rgb) -> int:
    """The 10-degree hue bin of one colour, as imagecheck.hue_shares bins pixels."""
    r, g, b = (float(c) for c in rgb)
    mx, mn = max(r, g, b), min(r, g, b)
    h = ((g - b) / (mx - mn)) % 6 if mx == r else ((b - r) / (mx - mn) + 2 if mx == g else (r - g) / (mx - mn) + 4)
    return int(h * 6) % 36


def test_tridexel_part_is_drawn_by_move(tmp_path):
    """A tri-dexel part (a box with a side hole along X, id 3, and a slot cut by a
    tilted tool, id 7) drawn offscreen from its closed surface: the slot's colour
    covers most of the coloured pixels and the hole, on a side face that no top view
    shows, is there in its own colour; the PNG is written."""
    from monitor.render import view3d
    from monitor.render.shaded import id_palette
    from sim.boolean import difference
    from sim.solids import box_grid, cylinder_grid
    from sim.tools import Tool
    from sim.tridexel import TriCutter, TriDexel
    from tests.monitor.render.imagecheck import hue_shares

    lo, hi = np.zeros(3), np.array([12.0, 10.0, 8.0])
    model = TriDexel.build(lo, hi, 0.5, lambda f: difference(
        box_grid(f, lo, hi), cylinder_grid(f, (-1, 5, 3), (1, 0, 0), 2.0, 14, face_id=3)))
    tilt = np.radians(30)
    tips = np.stack([np.linspace(2, 10, 40), np.full(40, 5.0), np.full(40, 6.5)], axis=1)
    TriCutter(model, Tool("flat", diameter=4, flute_length=15)).cut_poses(
        tips, (np.sin(tilt), 0.0, np.cos(tilt)), 7)
    img = view3d.part_png(model, window_size=(300, 300), path_out=tmp_path / "part.png")
    assert img.shape == (300, 300, 3) and img.std() > 10
    assert (tmp_path / "part.png").stat().st_size > 0
    shares = hue_shares(img)
    pal = id_palette()

    def near(move):
        b = _hue_bin(pal[move])
        return shares[[(b - 1) % 36, b, (b + 1) % 36]].sum()

    assert near(7) > 0.5
    assert near(3) > 0.01
    from sim.errors import InputError

    with pytest.raises(InputError, match="no material"):
        view3d.part_plotter(_empty(model))


def _empty(model):
    from sim.grid import DexelGrid

    out = model.copy()
    for a in out.grids:
        out.grids[a] = DexelGrid(out.grids[a].frame)
    return out
