"""The browser view's 3-D scene rendered offscreen (no browser): the path it draws is the
path near the stage (the moves the pictures draw, :func:`monitor.render.runpicture.path_near`),
and findings under the stock's surface stay visible as labelled marks."""

from __future__ import annotations

import numpy as np
import pytest

from sim.gcode.moves import MoveKind, empty_moves
from tests.sim.trace_helpers import box

pytest.importorskip("pyvista")


def raster(n_rows: int) -> np.ndarray:
    """A zig-zag of ``n_rows`` feeds along X at Z 5 (Y steps of 0.1 mm), a rapid every 10th."""
    m = empty_moves(n_rows)
    y = np.arange(n_rows) * 0.1
    m["line"] = np.arange(n_rows) + 1
    m["kind"] = np.where(np.arange(n_rows) % 10 == 0, MoveKind.RAPID, MoveKind.FEED)
    x0 = np.where(np.arange(n_rows) % 2 == 0, 2.0, 18.0)
    m["start"][:, 0], m["start"][:, 1], m["start"][:, 2] = x0, y, 5.0
    m["end"][:, 0], m["end"][:, 1], m["end"][:, 2] = 20.0 - x0, y, 5.0
    m["feed"] = 600.0
    return m


def path_points(scene) -> np.ndarray:
    """Every point of the path the scene draws (feeds and rapids), (k, 3) mm."""
    return np.concatenate([np.asarray(p.points).reshape(-1, 3) for p in scene.path_meshes()])


def test_the_path_drawn_is_the_path_near_the_stage():
    from monitor.render.runpicture import PATH_AFTER, PATH_BEFORE
    from monitor.web.scene import Scene

    g = box(41, 41, 0.5, 0.0, 10.0)
    moves = raster(600)
    scene = Scene(g.frame, g.top(), moves=moves, window_size=(300, 200))
    try:
        scene.show(g.top(), None, row=300)
        y = path_points(scene)[:, 1]
        # only the rows 300-PATH_BEFORE .. 300+PATH_AFTER: not the whole program over the part
        assert y.min() == pytest.approx((300 - PATH_BEFORE) * 0.1)
        assert y.max() == pytest.approx((300 + PATH_AFTER) * 0.1)
        scene.show(g.top(), None, row=550)
        y = path_points(scene)[:, 1]
        assert y.min() == pytest.approx((550 - PATH_BEFORE) * 0.1) and y.max() == pytest.approx(599 * 0.1)
    finally:
        scene.close()


def red_pixels(img: np.ndarray) -> int:
    r, gr, b = (img[..., k].astype(int) for k in range(3))
    return int(((r > 180) & (gr < 70) & (b < 70)).sum())


def test_a_finding_under_the_stock_surface_stays_visible():
    from monitor.web.scene import Scene

    g = box(41, 41, 0.5, 0.0, 10.0)
    scene = Scene(g.frame, g.top(), window_size=(400, 300))
    try:
        scene.plotter.render()
        bare = red_pixels(np.asarray(scene.plotter.screenshot(return_img=True)))
        # 4 mm under the top of the untouched stock, in its middle
        scene.set_findings(np.array([[10.0, 10.0, 6.0]]), ["GOUGE L22"])
        scene.plotter.render()
        marked = red_pixels(np.asarray(scene.plotter.screenshot(return_img=True)))
        assert marked > bare + 20
        scene.set_findings(None)
        scene.plotter.render()
        assert red_pixels(np.asarray(scene.plotter.screenshot(return_img=True))) <= bare + 5
    finally:
        scene.close()
