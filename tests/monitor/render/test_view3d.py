"""pyvista views rendered offscreen, compared with reference images (tolerant metric)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.monitor.render.imagecheck import check_image
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


def test_height_view_png_matches_reference(cut_grid, tmp_path):
    from monitor.render.view3d import render_png
    from sim.tools import parse_tool_spec

    out = tmp_path / "v.png"
    img = render_png(cut_grid, out, window_size=(320, 320), tool=parse_tool_spec("ball:6:L=12"),
                     tip=(34, 31, 7.0), path=np.array([[6, 10, 7.0], [34, 31, 7.0]]),
                     findings=np.array([[20.0, 20.0, 7.0]]), contours=6)
    assert out.exists() and img.shape == (320, 320, 3)
    check_image(img, "view3d_height_ref.png", threshold=12.0)


def test_error_map_view_has_colour_bar_colours(cut_grid):
    from monitor.render.view3d import render_png
    from sim.checks.error_map import error_colors

    err = np.zeros(cut_grid.shape)
    err[:, :40] = -0.5   # a gouge on the left half: reds
    err[:, 40:] = 0.0    # in tolerance: green
    img = render_png(cut_grid, None, errors=err, window_size=(320, 320))
    red = error_colors(np.array([-0.5]))[0].astype(int)
    green = error_colors(np.array([0.0]))[0].astype(int)
    flat = img.reshape(-1, 3).astype(int)
    near = lambda c: (np.abs(flat - c).sum(axis=1) < 90).mean()  # noqa: E731 (shading varies)
    assert near(red) > 0.02 and near(green) > 0.02
    check_image(img, "view3d_error_ref.png", threshold=12.0)


def test_interactive_needs_a_display(monkeypatch):
    from monitor.render import view3d
    from sim.errors import InputError

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(InputError, match="display"):
        view3d.interactive(None)


def test_replay_3d_is_a_solid_with_its_real_height_range_and_quiet_vtk(tmp_path, capfd):
    """QA 10: the stock is a closed solid (walls down to its bottom) coloured over the real
    height range, and VTK prints nothing offscreen."""
    pytest.importorskip("pyvista")
    from monitor.render import view3d
    from tests.sim.trace_helpers import ball_cut, box

    grid = box(41, 31, 0.5, 0.0, 10.0)  # a 20 x 15 x 10 mm block
    ball_cut(grid, np.array([10.0, 7.5, 7.0]), 3.0, 1)
    solid = view3d.solid_surface(grid)
    lo, hi = np.asarray(solid.bounds).reshape(3, 2).T
    assert hi[2] == pytest.approx(10.0) and lo[2] == pytest.approx(0.0)  # sides down to the bottom
    assert solid.point_data["height"].min() == pytest.approx(0.0)
    pl = view3d.build_plotter(grid=grid, off_screen=True, window_size=(200, 200))
    try:
        rng = pl.mapper.scalar_range
    finally:
        pl.close()
    assert rng[0] == pytest.approx(0.0) and rng[1] == pytest.approx(10.0)
    capfd.readouterr()
    img = view3d.render_png(grid, str(tmp_path / "s.png"), window_size=(200, 200))
    assert img.shape == (200, 200, 3) and img.std() > 10
    assert capfd.readouterr().err == ""
