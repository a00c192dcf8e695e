"""Van Hook's image-space shaded view: analytic shading, orientation, inverse-shaded tool."""

from __future__ import annotations

import numpy as np
import pytest

from monitor.render import shaded
from sim.frame import Frame
from tests.monitor.render.imagecheck import check_image
from tests.sim.trace_helpers import ball_cut, box


def test_flat_and_tilted_planes_have_lambert_intensity():
    f = Frame.top(0, 0, 10, 10, 0.5)
    x = np.arange(f.nu) * 0.5
    L = np.array([0.3, -0.2, 0.9]); L /= np.linalg.norm(L)
    amb = 0.2
    flat = np.full(f.shape, 5.0, np.float32)
    img = shaded.shade(flat, f.spacing, light=L, ambient=amb, color=(200, 100, 50))
    k = amb + (1 - amb) * L[2]
    assert np.all(np.abs(img[..., 0].astype(float) - 200 * k) <= 0.5 + 1e-9)
    assert np.all(np.abs(img[..., 1].astype(float) - 100 * k) <= 0.5 + 1e-9)
    a = 0.4  # z = a x: normal (-a, 0, 1)
    tilt = np.broadcast_to(a * x[None, :], f.shape).astype(np.float32)
    img = shaded.shade(tilt, f.spacing, light=L, ambient=amb, color=(200, 200, 200))
    n = np.array([-a, 0, 1]) / np.hypot(a, 1)
    k = amb + (1 - amb) * max(0.0, n @ L)
    assert np.abs(img[..., 0].astype(float) - 200 * k).max() <= 1.0


def test_background_and_orientation():
    f = Frame.top(0, 0, 9, 4, 1.0)   # 10 x 5 rays
    h = np.full(f.shape, 3.0, np.float32)
    h[0, 0] = np.nan                  # ray at X0 Y0: bottom-left of the picture
    img = shaded.shade(h, 1.0, background=(1, 2, 3))
    assert img.shape == (5, 10, 3)
    assert img[-1, 0].tolist() == [1, 2, 3]
    assert img[0, 0].tolist() != [1, 2, 3]
    px = shaded.to_pixels(f, np.array([[0.0, 0.0, 0.0], [9.0, 4.0, 0.0]]))
    assert px.tolist() == [[0.0, 4.0], [9.0, 0.0]]


def test_faces_coloured_by_move_id():
    f = Frame.top(0, 0, 9, 9, 1.0)
    h = np.full(f.shape, 1.0, np.float32)
    ids = np.zeros(f.shape, np.int32)
    ids[:, 5:] = 3
    pal = shaded.id_palette()
    img = shaded.shade(h, 1.0, ids=ids, light=(0, 0, 1), ambient=0.0)
    assert img[0, 0].tolist() == pal[0].tolist()
    assert img[0, 9].tolist() == pal[3].tolist()


def test_tool_is_inverse_shaded_like_the_surface_it_leaves():
    # the dent a ball leaves and the ball drawn at that pose must shade alike (Van Hook)
    g = box(81, 81, 0.25, 0.0, 10.0)
    tip = np.array([10.0, 10.0, 8.0])
    ball_cut(g, tip + [0, 0, 3.0], 3.0, 1)
    h = g.top()
    L = (0.5, -0.3, 0.8)
    white = (200, 200, 200)
    surface = shaded.shade(h, 0.25, light=L, color=white).astype(float)
    tool = pytest.importorskip("sim.tools").parse_tool_spec("ball:6")
    drawn = shaded.draw_tool(surface.astype(np.uint8).copy(), g.frame, h + 1.0, tip, tool, light=L,
                             color=white).astype(float)
    px = shaded.to_pixels(g.frame, tip[None])[0]
    c, r = int(px[0]), int(px[1])
    win = (slice(r - 8, r + 9), slice(c - 8, c + 9))   # well inside the rim
    assert np.abs(drawn[win] - surface[win]).mean() < 4.0
    # and not like the ball's outward (upper) face, as a plain renderer would draw it
    x = np.arange(81) * 0.25 - tip[0]
    d2 = x[None, :] ** 2 + x[:, None] ** 2
    dome = np.where(d2 < 9, tip[2] + 3 + np.sqrt(np.maximum(9 - d2, 0)), np.nan).astype(np.float32)
    outward = shaded.shade(dome, 0.25, light=L, color=white).astype(float)
    assert np.abs(drawn[win] - outward[win]).mean() > 10.0


def test_overlays_mark_path_tool_and_findings():
    f = Frame.top(0, 0, 50, 50, 0.5)
    h = np.full(f.shape, 10.0, np.float32)
    img = shaded.picture(h, f, tool=3.0, tip=(25, 25, 9.0), path_ahead=np.array([[25, 25, 9], [45, 25, 9]]),
                         findings=np.array([[10.0, 40.0, 10.0]]))
    row = int(shaded.to_pixels(f, np.array([[0, 25, 0]]))[0, 1])
    assert img[row, 80].tolist() == list(shaded.PATH_COLOR)  # X = 40 on the path
    assert (img == np.array(shaded.FINDING_COLOR, np.uint8)).all(axis=2).any()
    tool_px = img[row, 50].astype(int)  # under the tool: tool colour dominates (yellow)
    assert tool_px[0] > tool_px[2] + 60 and tool_px[1] > tool_px[2] + 40


def test_reference_picture(data):
    g = box(121, 81, 0.25, 0.0, 10.0)
    for k in range(12):
        ball_cut(g, (3 + 2.2 * k, 6 + 0.9 * k, 9.0 - 0.25 * k), 3.0, k + 1)
    img = shaded.picture(g.top(), g.frame, ids=g.store["far_id"].reshape(g.shape), tool=3.0,
                         tip=(29.4, 15.9, 6.0), path_ahead=np.array([[29.4, 15.9, 6.0], [29.4, 2.0, 6.0]]),
                         findings=np.array([[10.0, 10.0, 8.0]]))
    check_image(img, "shaded_ref.png", threshold=1.0)
