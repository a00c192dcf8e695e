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
    # a small grid is enlarged (whole pixels per ray) to >= 600 px, with the text strip below
    assert view.scale == 8 and img.shape == (61 * 8 + view.strip_height, 81 * 8, 3)
    assert (img == np.array(shaded.FINDING_COLOR, np.uint8)).all(axis=2).any()
    assert (img == np.array(shaded.PATH_COLOR, np.uint8)).all(axis=2).any()
    assert not np.array_equal(iio.imread(files[0]), img)


def test_large_grids_are_strided_to_max_size(tmp_path):
    g = box(1001, 401, 0.1)
    view = LiveView(g.frame, out_dir=tmp_path, max_size=250, min_size=0)
    img = view.render(g.top())
    assert max(view.picture_shape) <= 250 and view.k == 5 and view.scale == 1
    assert img.shape == (view.picture_shape[0] + view.strip_height, view.picture_shape[1], 3)


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


def _mask(img, color):
    return (img == np.asarray(color, np.uint8)).all(axis=2)


def test_cut_areas_are_coloured_by_depth_and_uncut_stock_stays_grey(tmp_path):
    """A 2 mm pocket and a 4 mm pocket in a flat block: the uncut top is the stock colour,
    the pocket floors take the ramp's colours at 2/4 and 4/4 of the range (times the flat
    floor's Lambert factor), different from each other and from the stock."""
    g = box(81, 61, 0.5, 0.0, 10.0)
    top0 = g.top()
    h = top0.copy()
    h[10:30, 10:30] = 8.0
    h[10:30, 50:70] = 6.0
    view = LiveView(g.frame, out_dir=tmp_path, stock_top=top0, max_depth=4.0, min_size=0)
    img = view.render(h)
    L = np.asarray(shaded.LIGHT) / np.linalg.norm(shaded.LIGHT)
    k = 0.22 + 0.78 * L[2]
    ramp = shaded.depth_ramp()

    def px(x, y):
        c, r = view.pixel_of(np.array([[x, y, 0.0]]))[0]
        return img[int(round(r)), int(round(c))].astype(float)

    assert np.abs(px(35, 25) - np.asarray(shaded.STOCK_COLOR) * k).max() <= 1.0    # uncut
    assert np.abs(px(10, 10) - ramp[128] * k).max() <= 1.5                        # 2 mm deep
    assert np.abs(px(30, 10) - ramp[255] * k).max() <= 1.5                        # 4 mm deep
    assert np.abs(px(10, 10) - px(35, 25)).sum() > 60 and np.abs(px(10, 10) - px(30, 10)).sum() > 60
    # the pocket walls are shaded (lit or in shadow), unlike the flat floors next to them
    c, r = view.pixel_of(np.array([[4.75, 10.0, 0.0], [15.0, 10.0, 0.0]]))[:, :2].round().astype(int).T
    assert np.abs(img[r[0], c[0]].astype(int) - img[r[1], c[1]].astype(int)).sum() > 30


def test_deeper_cut_than_the_range_grows_it(tmp_path):
    g = box(41, 41, 0.5, 0.0, 10.0)
    view = LiveView(g.frame, out_dir=tmp_path, stock_top=g.top(), max_depth=1.0)
    h = g.top()
    h[5:15, 5:15] = 7.0
    view.render(h)
    assert view.max_depth >= 3.0


def test_findings_are_ringed_and_labelled_and_the_strip_tells_the_state(tmp_path):
    g = box(101, 61, 0.5, 0.0, 10.0)
    view = LiveView(g.frame, tool=3.0, out_dir=tmp_path)
    findings = [{"kind": "gouge", "line": 22, "position": [20.0, 20.0, 9.0]},
                {"kind": "rapid_into_stock", "line": 5, "lines": [5, 7], "position": [40.0, 10.0, 9.0]}]
    img = view.render(g.top(), (30.0, 15.0, 9.5), np.array([[30, 15, 9.5], [45, 25, 9.5]]), findings,
                      status={"line": 17, "time": 12.25, "feed": 600.0})
    rows, cols = view.picture_shape
    ts = view.text_scale
    red = _mask(img, shaded.FINDING_COLOR)
    for f, text in zip(findings, ["GOUGE L22", "RAPID INTO STOCK L5-7"]):
        c, r = view.pixel_of(np.array([f["position"]]))[0].round().astype(int)
        size = max(6, max(img.shape[:2]) // 90)
        assert red[r - size - 1:r + size + 2, c - size - 1:c + size + 2].sum() >= 2 * size
        # the label's pixels are somewhere in the picture, in the finding colour
        m = shaded.text_mask(text, ts)
        assert _find(red[:rows], m), text
    # the text strip: state line with line number, time, position, feed and findings count
    white = _mask(img[rows:], (235, 235, 235))
    assert _find_text(white, "LINE 17")
    assert _find_text(white, "X 30.000")
    assert _find_text(white, "F 600")
    assert _find_text(_mask(img[rows:], shaded.FINDING_COLOR), "FINDINGS 2")
    # the tool is drawn at its pose, the path ahead beyond it
    c, r = view.pixel_of(np.array([[30.0, 15.0, 0.0]]))[0].round().astype(int)
    tool_px = img[r, c].astype(int)
    assert tool_px[0] > tool_px[2] + 60 and tool_px[1] > tool_px[2] + 40
    c, r = view.pixel_of(np.array([[39.0, 21.0, 0.0]]))[0].round().astype(int)
    assert _mask(img, shaded.PATH_COLOR)[r - 2:r + 3, c - 2:c + 3].any()


def test_fixtures_are_outlined_and_named(tmp_path):
    from sim.checks.collisions import Fixture

    g = box(101, 61, 0.5, 0.0, 10.0)
    clamp = Fixture.box((35.0, 5.0, 10.0), (45.0, 15.0, 14.0), 0.5, name="CLAMP")
    view = LiveView(g.frame, out_dir=tmp_path, fixtures=[clamp])
    img = view.render(g.top())
    orange = _mask(img, (255, 150, 40))
    c0, r0 = view.pixel_of(np.array([[35.0, 10.0, 0.0]]))[0].round().astype(int)
    c1, _ = view.pixel_of(np.array([[45.0, 10.0, 0.0]]))[0].round().astype(int)
    cm, rm = view.pixel_of(np.array([[40.0, 10.0, 0.0]]))[0].round().astype(int)
    assert orange[r0, c0 - 3:c0 + 4].any() and orange[r0, c1 - 3:c1 + 4].any()   # both sides
    assert not orange[rm - 3:rm + 4, cm - 3:cm + 4].any()                         # not filled
    assert _find(orange, shaded.text_mask("CLAMP", view.text_scale))


def _find(mask: np.ndarray, pattern: np.ndarray) -> bool:
    """True when the bool ``pattern``'s set pixels all appear set in ``mask`` at some offset
    (a written text's glyph pixels)."""
    from numpy.lib.stride_tricks import sliding_window_view

    ph, pw = pattern.shape
    if mask.shape[0] < ph or mask.shape[1] < pw:
        return False
    win = sliding_window_view(mask, (ph, pw))
    return bool((win[..., pattern].all(axis=-1)).any())


def _find_text(mask: np.ndarray, text: str) -> bool:
    """``text`` written at scale 2 or (a line too long for the width) 1."""
    return any(_find(mask, shaded.text_mask(text, s)) for s in (2, 1))
