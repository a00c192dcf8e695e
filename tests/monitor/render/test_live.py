"""LiveView writes frames when there is no display; frames show tool, path and findings."""

from __future__ import annotations

import numpy as np
import pytest

from monitor.render import shaded
from monitor.render.live import LiveView
from sim.errors import InputError
from tests.sim.trace_helpers import ball_cut, box


def test_frames_written_to_a_folder(tmp_path):
    import imageio.v3 as iio

    g = box(81, 61, 0.5)
    view = LiveView(g.frame, tool=3.0, out_dir=tmp_path / "frames")
    for k in range(3):
        tip = (5 + 8 * k, 15, 8.0)
        ball_cut(g, (tip[0], tip[1], 11.0), 3.0, k + 1)
        assert view.update(g, tool_pose=tip, path_ahead=np.array([tip, (35, 25, 8.0)]),
                           findings=[{"position": [30.0, 20.0, 9.0]}])
    files = sorted((tmp_path / "frames").glob("frame_*.png"))
    assert [p.name for p in files] == ["frame_000001.png", "frame_000002.png", "frame_000003.png"]
    img = iio.imread(files[-1])
    assert img.shape == (61, 81, 3)
    assert (img == np.array(shaded.FINDING_COLOR, np.uint8)).all(axis=2).any()
    assert (img == np.array(shaded.PATH_COLOR, np.uint8)).all(axis=2).any()
    assert not np.array_equal(iio.imread(files[0]), img)


def test_large_grids_are_strided_to_max_size(tmp_path):
    g = box(1001, 401, 0.1)
    view = LiveView(g.frame, out_dir=tmp_path, max_size=250)
    img = view.render(g.top())
    assert max(img.shape[:2]) <= 250 and view.k == 5


def test_max_fps_skips_updates(tmp_path):
    g = box(21, 21, 1.0)
    view = LiveView(g.frame, out_dir=tmp_path, max_fps=1e-3)
    assert view.update(g.top()) and not view.update(g.top())
    assert view.frames_drawn == 1


def test_window_needs_display(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(InputError, match="--frames"):
        LiveView(box(5, 5).frame)


def test_wrong_shape_is_a_clear_error(tmp_path):
    view = LiveView(box(10, 10).frame, out_dir=tmp_path)
    with pytest.raises(InputError, match="shape"):
        view.update(np.zeros((3, 3)))
