"""Frame and DexelGrid basics: geometry of rays, window, copy, top, volume, limits."""

from __future__ import annotations

import numpy as np
import pytest

from sim.errors import InputError
from sim.frame import Frame
from sim.grid import DexelGrid
from sim.solids import box_grid


def test_top_frame_counts_and_ray_points():
    f = Frame.top(-1, 2, 3, 4, 0.5)
    assert (f.nu, f.nv) == (9, 5) and f.shape == (5, 9) and f.n_rays == 45
    assert f.is_top
    p = f.ray_points()
    assert p.shape == (5, 9, 3)
    np.testing.assert_allclose(p[3, 4], [1.0, 3.5, 0.0])
    np.testing.assert_allclose(f.v, [0, 1, 0])


def test_frame_local_world_round_trip_and_orthogonalised_u():
    f = Frame([1, 2, 3], [0, 1, 1], [1, 1, 0], 0.3, 4, 5)  # u not orthogonal to d: fixed
    assert abs(f.u @ f.direction) < 1e-12 and abs(np.linalg.norm(f.u) - 1) < 1e-12
    assert not f.is_top
    pts = np.random.default_rng(0).normal(size=(10, 3)) * 5
    np.testing.assert_allclose(f.to_world(f.to_local(pts)), pts, atol=1e-12)
    # ray (i, j) foot has local (i h, j h, 0)
    np.testing.assert_allclose(f.to_local(f.ray_points()[2, 3]), [0.9, 0.6, 0], atol=1e-12)


@pytest.mark.parametrize("kwargs, match", [
    (dict(direction=[0, 0, 0]), "direction"),
    (dict(u=[0, 0, 2]), "orientation"),
    (dict(spacing=0.0), "spacing"),
    (dict(spacing=float("nan")), "spacing"),
    (dict(nu=0), "at least one ray"),
])
def test_bad_frames_are_input_errors(kwargs, match):
    args = dict(origin=[0, 0, 0], direction=[0, 0, 1], u=[1, 0, 0], spacing=1.0, nu=2, nv=2)
    args.update(kwargs)
    with pytest.raises(InputError, match=match):
        Frame(**args)
    with pytest.raises(InputError, match="empty grid extent"):
        Frame.top(1, 0, 0, 1, 0.5)


def test_same_rays():
    a = Frame.top(0, 0, 4, 4, 0.5)
    assert a.same_rays(Frame.top(0, 0, 4, 4, 0.5))
    assert not a.same_rays(Frame.top(0, 0, 4, 4, 0.25))
    assert not a.same_rays(Frame.top(0.5, 0, 4.5, 4, 0.5))
    assert not a.same_rays(Frame(a.origin, [0, 0, -1], a.u, 0.5, a.nu, a.nv))


def test_from_intervals_skips_nan_and_empty():
    f = Frame.top(0, 0, 2, 0, 1.0)
    g = DexelGrid.from_intervals(f, [[0, np.nan, 1]], [[2, 5, 1]], face_id=4)
    assert g.counts.tolist() == [[1, 0, 0]]
    assert g.face_ids(0, 0).tolist() == [[4, 4]]
    with pytest.raises(InputError, match="expected"):
        DexelGrid.from_intervals(f, np.zeros(2), np.ones(2))


def test_top_and_volume_of_a_stepped_model():
    f = Frame.top(0, 0, 3, 2, 1.0)
    g = box_grid(f, (0, 0, -1), (3, 2, 2))
    g.subtract(1, 1, 0.5, 5, move_id=3)  # lower one ray to 0.5
    g.subtract(2, 0, 0.0, 1.0, move_id=4)  # split one ray in two
    top = g.top()
    assert top.dtype == np.float32 and top.shape == (3, 4)
    assert top[1, 1] == 0.5 and top[0, 2] == 2.0
    assert g.volume() == pytest.approx(12 * 3 - 1.5 - 1.0)
    np.testing.assert_allclose(g.segments(2, 0), [[-1, 0], [1, 2]])
    assert g.face_ids(2, 0).tolist() == [[0, 4], [4, 0]]
    assert g.max_top() == 2.0
    g.subtract(2, 0, 1.5, 5, move_id=5)  # the top of a two-segment ray is in the pool
    g.add(0, 0, 2.5, 3.25)
    assert g.max_top() == 3.25 == np.nanmax(g.top())
    empty = DexelGrid(f)
    assert np.all(np.isnan(empty.top())) and empty.volume() == 0.0 and empty.max_top() == -np.inf
    # top_of: the same tops for chosen rays (one in the pool, a lowered one, an emptied one)
    g.subtract(3, 1, -5, 5, move_id=6)
    rays = np.array([0, 2, 5, 7, 11])
    np.testing.assert_array_equal(g.top_of(rays), g.top().reshape(-1)[rays].astype(np.float64))
    assert np.isnan(g.top_of([7])[0]) and g.top_of([5])[0] == 0.5


def test_window_is_an_independent_copy_in_its_own_frame():
    f = Frame.top(0, 0, 9, 9, 1.0)
    g = box_grid(f, (2, 2, 0), (7, 7, 3), face_id=1)
    g.subtract(4, 4, 1, 2, move_id=2)
    w = g.window(3, 6, 3, 6)
    assert w.shape == (3, 3)
    np.testing.assert_allclose(w.frame.origin, [3, 3, 0])
    np.testing.assert_allclose(w.segments(1, 1), g.segments(4, 4))
    w.subtract(1, 1, 0, 3, move_id=9)
    assert g.segments(4, 4).shape == (2, 2)  # the live model is untouched
    clipped = g.window(-5, 2, 8, 20)  # clipped to the grid
    assert clipped.shape == (2, 2)
    with pytest.raises(InputError, match="empty window"):
        g.window(5, 5, 0, 3)


def test_copy_does_not_share_storage():
    g = box_grid(Frame.top(0, 0, 3, 3, 1.0), (0, 0, 0), (3, 3, 1))
    c = g.copy()
    c.subtract(1, 1, 0.2, 0.4, move_id=5)
    assert g.segments(1, 1).shape == (1, 2) and c.segments(1, 1).shape == (2, 2)


def test_memory_limit_is_a_clear_error():
    f = Frame.top(0, 0, 999, 999, 1.0)
    with pytest.raises(InputError, match="coarser resolution"):
        DexelGrid(f, memory_limit=1024)
    assert DexelGrid.estimate_bytes(f.n_rays) == f.n_rays * 26


@pytest.mark.parametrize("spacing", [0.25, 0.4, 1.0])
def test_trapezoid_volume_of_a_box_is_exact(spacing):
    # 60 x 40 x 20 = 48000 mm^3; the edge-inclusive rays overstate it by the edge half-cells
    f = Frame.top(0, 0, 60, 40, spacing)
    g = box_grid(f, (0, 0, 0), (60, 40, 20))
    assert g.volume(weights="trapezoid") == pytest.approx(48000.0, rel=1e-9)
    assert g.volume() == pytest.approx(f.nu * f.nv * spacing**2 * 20)  # default unchanged
    # a pocket in the middle: interior rays count whole in both rules
    i, j = int(round(30 / spacing)), int(round(20 / spacing))
    removed = g.subtract(i, j, 10.0, 25.0, 1)
    assert removed == pytest.approx(10.0)
    assert g.volume(weights="trapezoid") == pytest.approx(48000.0 - 10.0 * spacing**2, rel=1e-9)
    with pytest.raises(ValueError):
        g.volume(weights="simpson")


def test_a_million_ray_box_with_one_cut_stays_under_32_mb():
    """The model is its store (per-ray arrays and the pool) and nothing else per ray."""
    from sim.cut import Cutter
    from sim.tools import parse_tool_spec

    frame = Frame.top(0, 0, 100, 100, 0.1)
    assert frame.n_rays >= 1_000_000
    g = box_grid(frame, (0, 0, 0), (100, 100, 20))
    got = Cutter(g, parse_tool_spec("ball:6:L=20")).cut_segment((5, 10, 12), (95, 80, 8), 1)
    assert got > 0
    held = [v for v in vars(g).values() if isinstance(v, np.ndarray)]
    assert held == []  # no cached tops or ids beside the store
    assert g.nbytes() == sum(a.nbytes for a in g.store.values())
    assert g.nbytes() < 32_000_000
