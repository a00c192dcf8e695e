"""``dexmon live|dry-run --view / --frames DIR``: the live view drawn from its own thread."""

from __future__ import annotations

import json

import numpy as np
import pytest

from monitor.cli import main
from monitor.render import shaded
from monitor.render.feed import ViewFeed, feed_status, path_ahead, tops_of
from monitor.render.live import LiveView, finding_marks
from monitor.runreader import RunReader
from monitor.sync import ProgramPath
from sim.frame import Frame
from sim.gcode.moves import MoveKind, empty_moves
from tests.sim.trace_helpers import ball_cut, box

TOOL_RIM = tuple(int(c * 0.45 + 0.5) for c in shaded.TOOL_COLOR)  # draw_tool's outline


def _mask(img, color) -> np.ndarray:
    return (img == np.asarray(color, np.uint8)).all(axis=2)


def _view_of(frame_meta, tmp_path) -> LiveView:
    """A LiveView laid out like the CLI's for the run's frame (same scale and strip)."""
    f = Frame.top(frame_meta["origin"][0], frame_meta["origin"][1],
                  frame_meta["origin"][0] + (frame_meta["nu"] - 1) * frame_meta["spacing"],
                  frame_meta["origin"][1] + (frame_meta["nv"] - 1) * frame_meta["spacing"], frame_meta["spacing"])
    return LiveView(f, out_dir=tmp_path / "layout", axes=True)


def _pixel(view, x: float, y: float) -> tuple[int, int]:
    """(row, col) of work point (x, y) in the frames."""
    c, r = view.pixel_of(np.array([[x, y, 0.0]]))[0]
    return int(round(r)), int(round(c))


def test_dry_run_frames_show_the_cut_tool_path_and_findings(tmp_path, capsys):
    import imageio.v3 as iio

    frames, run = tmp_path / "frames", tmp_path / "run.sqlite"
    code = main(["dry-run", "--speed", "20", "--json", "--run", str(run), "--frames", str(frames),
                 "--view-fps", "20"])
    out = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert code == 1
    files = sorted(frames.glob("frame_*.png"))
    summary = out[-1]
    assert summary["event"] == "summary" and summary["frames"] == len(files) >= 10
    assert [p.name for p in files[:2]] == ["frame_000001.png", "frame_000002.png"]
    meta = RunReader(run).meta()["frame"]
    meta = json.loads(meta) if isinstance(meta, str) else meta
    first, last = iio.imread(files[0]), iio.imread(files[-1])
    view = _view_of(meta, tmp_path)
    rows, cols = view.picture_shape
    assert first.shape == last.shape == (rows + view.strip_height, cols, 3)
    assert max(first.shape[:2]) >= 600   # the small grid is enlarged
    # every planted finding is ringed where it is, in the last frame: red pixels around
    # the finding's position, none in its middle
    findings = [x for x in out if x["event"] == "finding"]
    assert {f["kind"] for f in findings} == {"gouge", "rapid_into_stock"}
    red = _mask(last, shaded.FINDING_COLOR)
    size = max(6, max(last.shape[:2]) // 90)
    for f in findings:
        r, c = _pixel(view, *f["position"][:2])
        ring = red[max(r - size - 1, 0):r + size + 2, max(c - size - 1, 0):c + size + 2]
        assert ring.sum() >= 2 * size, f
        assert not red[r - 1:r + 2, c - 1:c + 2].any()
    # the tool is drawn (its rim) in frames taken while it is over the stock, and the path
    # ahead is drawn while there is program left
    assert sum(_mask(iio.imread(p), TOOL_RIM).sum() > 10 for p in files) >= len(files) // 2
    assert _mask(iio.imread(files[len(files) // 2])[:rows], shaded.PATH_COLOR).sum() > 20
    # the model is cut as the machine goes: the faced area changes the picture (the step
    # along each pass's edge and the dip of the gouge)
    sr, sc = _pixel(view, 10.0, 12.0)
    s = view.scale
    stock = (slice(sr - 40 * s, sr + 40 * s), slice(sc - 30 * s, sc + 30 * s))
    assert not np.array_equal(first[stock], last[stock])
    gr, gc = _pixel(view, 30.0, 21.0)  # the gouge dips between X34 and X26 on Y22
    win = (slice(gr - 4 * s, gr + 5 * s), slice(gc - 8 * s, gc + 9 * s))
    # (the labels are drawn over the picture: the shading is compared on the model alone)
    assert np.ptp(last[win].astype(int)) > np.ptp(first[win].astype(int))
    # each finding is labelled with its kind and line, in the finding colour
    for f in findings:
        label = f["kind"].upper().replace("_", " ") + " L"
        assert any(_has_text(red[:rows], label, k) for k in (1, 2)), label
    # the text strip says how many findings there are
    assert any(_has_text(_mask(last[rows:], shaded.FINDING_COLOR), f"FINDINGS {len(findings)}", k) for k in (1, 2))


def _has_text(mask, text, scale) -> bool:
    from numpy.lib.stride_tricks import sliding_window_view

    pat = shaded.text_mask(text, scale)
    win = sliding_window_view(mask, pat.shape)
    return bool(win[..., pat].all(axis=-1).any())


def test_dry_run_frames_carry_the_replay_overlay(tmp_path, capsys):
    """The live frames draw what the replay pictures draw: axes and the work origin, the
    path near the machine with its rapids (dashed, in the rapid colour), the stage and
    the tool in the strip."""
    import imageio.v3 as iio

    from monitor.render.meaning import AXIS_X_COLOR, AXIS_Y_COLOR, RAPID_COLOR

    frames, run = tmp_path / "frames", tmp_path / "run.sqlite"
    assert main(["dry-run", "--clock", "sim", "--speed", "20", "--quiet", "--run", str(run), "--frames",
                 str(frames), "--view-fps", "20"]) == 1
    meta = RunReader(run).meta()["frame"]
    meta = json.loads(meta) if isinstance(meta, str) else meta
    rows, _ = _view_of(meta, tmp_path).picture_shape
    pictures = [iio.imread(p) for p in sorted(frames.glob("frame_*.png"))]
    assert len(pictures) >= 10
    for img in pictures[1:]:
        model = img[:rows]
        assert _mask(model, AXIS_X_COLOR).sum() > 10 and _mask(model, AXIS_Y_COLOR).sum() > 10
    assert max(_mask(img[:rows], RAPID_COLOR).sum() for img in pictures) > 20


def test_view_without_display_is_one_line_suggesting_frames(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    run = tmp_path / "r.sqlite"
    code = main(["dry-run", "--view", "--quiet", "--run", str(run)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--view" in err[0] and "--frames DIR" in err[0]
    assert not run.exists()  # nothing was opened


def test_view_and_frames_exclude_each_other(capsys):
    assert main(["dry-run", "--view", "--frames", "x"]) == 2
    assert "not allowed with argument" in capsys.readouterr().err


def test_window_is_drawn_by_the_main_thread_while_the_loop_runs_on_a_worker(tmp_path, monkeypatch, capsys):
    """With a (here: matplotlib Agg) window the session loop runs on a worker thread and
    the main thread presents the frames."""
    import threading

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import monitor.render.live as live_mod
    import monitor.render.view3d as view3d

    monkeypatch.setattr(view3d, "has_display", lambda: True)
    monkeypatch.setattr(live_mod, "has_display", lambda: True)
    presented = []
    real_present = LiveView.present

    def present(self, img):
        presented.append(threading.current_thread() is threading.main_thread())
        real_present(self, img)

    monkeypatch.setattr(LiveView, "present", present)
    code = main(["dry-run", "--speed", "25", "--json", "--run", str(tmp_path / "r.sqlite"), "--view"])
    out = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert code == 1 and {x["kind"] for x in out if x["event"] == "finding"} == {"gouge", "rapid_into_stock"}
    assert len(presented) >= 5 and all(presented)
    assert plt.get_fignums() == []  # the window is closed at the end


# --- the feed on its own ----------------------------------------------------------------

def _line_path(points) -> ProgramPath:
    pts = np.asarray(points, np.float64)
    m = empty_moves(len(pts) - 1)
    m["kind"] = MoveKind.FEED
    m["feed"] = 600.0
    m["line"] = np.arange(len(m)) + 1
    m["start"][:, :3], m["end"][:, :3] = pts[:-1], pts[1:]
    return ProgramPath.from_moves(m, position="machine")


def test_feed_keeps_its_heights_in_step_with_the_model_from_changed_rays_only(tmp_path):
    import imageio.v3 as iio

    g = box(81, 61, 0.5)
    view = LiveView(g.frame, tool=3.0, out_dir=tmp_path)
    path = _line_path([(5, 15, 8), (35, 15, 8), (35, 25, 8)])
    feed = ViewFeed(view, g.top(), path=path, horizon=lambda p: p + 100.0, fps=1000.0).start()
    tips = [(5 + 3 * k, 15, 8.0) for k in range(11)]
    for k, tip in enumerate(tips):
        rays = ball_cut(g, (tip[0], tip[1], 11.0), 3.0, k + 1)
        feed.post(rays, tops_of(g, rays), tip=np.array(tip), progress=path.t1[0] * k / 10,
                  findings=[{"kind": "gouge", "position": [30.0, 20.0, 9.0]}])
    feed.close()
    assert feed.error is None and 1 <= feed.frames <= len(tips)
    assert np.array_equal(feed.heights, g.top(), equal_nan=True)
    # the last frame shows the final state: the same picture as drawn from the model itself
    want = view.render(g.top(), tips[-1], path_ahead(path, path.t1[0], path.t1[0] + 100.0),
                       [{"kind": "gouge", "position": [30.0, 20.0, 9.0]}], status=feed_status(path, path.t1[0]))
    got = iio.imread(sorted(tmp_path.glob("frame_*.png"))[-1])
    assert np.array_equal(got, want)


def test_feed_merges_posts_within_the_frame_budget(tmp_path):
    g = box(21, 21, 1.0)
    view = LiveView(g.frame, out_dir=tmp_path)
    feed = ViewFeed(view, g.top(), fps=1e-3)  # one frame, then none for 1000 s
    feed.start()
    for k in range(20):
        rays = ball_cut(g, (10.0, 10.0, 11.0 - 0.1 * k), 3.0, k + 1)
        feed.post(rays, tops_of(g, rays))
    feed.close()  # stopping draws what is pending at once
    assert feed.frames <= 2 and np.array_equal(feed.heights, g.top(), equal_nan=True)


def test_tops_of_rays_equals_the_full_top():
    g = box(31, 17, 0.5)
    ball_cut(g, (7.0, 4.0, 9.0), 3.0, 1)
    rays = np.array([0, 5, 100, 250, g.frame.n_rays - 1], np.int64)
    assert np.array_equal(tops_of(g, rays), g.top().reshape(-1)[rays])
    assert tops_of(g, np.zeros(0, np.int64)).shape == (0,)


def test_path_ahead_and_finding_marks():
    path = _line_path([(0, 0, 0), (10, 0, 0), (10, 10, 0)])
    t_end = path.t1[-1]
    ahead = path_ahead(path, path.t1[0] / 2, t_end)
    assert np.allclose(ahead, [(5, 0, 0), (10, 0, 0), (10, 10, 0)])
    assert np.allclose(path_ahead(path, 0.0, path.t1[0] / 2)[0], (0, 0, 0))
    marks = finding_marks([{"kind": "gouge", "position": [1, 2, 3]},
                           {"kind": "travel_limit", "position": [110, 2, 3]}, {"kind": "x"}],
                          wco=(100, 0, 0, 0, 0, 0))
    assert np.allclose([m["position"] for m in marks], [(1, 2, 3), (10, 2, 3)])
    assert [m["kind"] for m in marks] == ["gouge", "travel_limit"]


def test_feed_needs_a_positive_rate(tmp_path):
    from sim.errors import InputError

    f = Frame.top(0, 0, 4, 4, 1.0)
    with pytest.raises(InputError, match="frames per second"):
        ViewFeed(LiveView(f, out_dir=tmp_path), np.zeros(f.shape, np.float32), fps=0)


@pytest.mark.parametrize("max_size", [None, 40])
def test_incremental_shading_equals_shading_everything(tmp_path, max_size):
    """Re-shading only the changed box gives the picture of shading the whole model, also
    at the grid's edges and when the picture strides over rays."""
    g = box(81, 61, 0.5)
    kw = dict(tool=3.0, max_size=max_size, stock_top=g.top(), max_depth=5.0)
    inc = LiveView(g.frame, out_dir=tmp_path / "a", **kw)
    full = LiveView(g.frame, out_dir=tmp_path / "b", **kw)
    inc.render(g.top())
    nu = g.frame.nu
    for k, (x, y) in enumerate([(0.0, 0.0), (20.0, 15.0), (40.0, 30.0), (21.0, 16.0), (39.5, 0.0)]):
        rays = ball_cut(g, (x, y, 8.5), 2.5, k + 1)
        changed = (int(rays.min()) // nu, int(rays.max()) // nu + 1, int((rays % nu).min()), int((rays % nu).max()) + 1)
        tip = np.array([x, y, 8.5])
        got = inc.render(g.top(), tip, None, [{"position": [x, y, 9.0]}], changed=changed).copy()
        want = full.render(g.top(), tip, None, [{"position": [x, y, 9.0]}])
        assert np.array_equal(got, want), k
