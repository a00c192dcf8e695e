"""Replay pictures of the bundled job (monitor/examples/clamp_job), coloured by meaning.

Checked by simple facts (the gouge is red, the colour bar is there, the part fills the
frame, few distinct hues, axes, tool and holder drawn) and against small reference
images in tests/data/images within a threshold.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from monitor.cli import main
from monitor.render import meaning, shaded
from tests.monitor.render.imagecheck import check_image, hue_shares

#: the bundled job's planted faults: a gouge on line 22 (X30 Y19..22, 0.5 mm deep) and a
#: rapid through the stock on line 36
GOUGE_LINE = 22


@pytest.fixture(scope="module")
def example_run(tmp_path_factory):
    run = tmp_path_factory.mktemp("example") / "face.dexrun"
    assert main(["dry-run", "--clock", "sim", "--speed", "20", "--quiet", "--run", str(run)]) == 1
    return run


@pytest.fixture(scope="module")
def end_picture(example_run):
    from monitor.render.runpicture import RunPictures
    from monitor.trace_io import RunView

    with RunView(example_run) as view:
        pics = RunPictures(view, size=600)
        img = pics.picture(view.last_stage)
        yield pics, img


def test_run_picture_colours_the_gouge_red_and_carries_the_colour_bar(end_picture):
    pics, img = end_picture
    assert pics.color_by == "deviation"          # the job has a design: deviation map by default
    rows, cols = pics.live.picture_shape
    model = img[:rows]
    # the gouge under line 22's dip: the picture around X30 Y22 is in the red scale
    c, r = pics.live.pixel_of(np.array([[30.0, 22.0, -5.0]]))[0].round().astype(int)
    win = model[r - 8:r + 9, c - 8:c + 9].reshape(-1, 3).astype(int)
    red = (win[:, 0] > win[:, 1] + 60) & (win[:, 0] > win[:, 2] + 60)
    assert red.mean() > 0.5, win[:5]
    # a faced area within tolerance of the design is neutral grey, not red or blue
    c, r = pics.live.pixel_of(np.array([[45.0, 28.0, -5.0]]))[0].round().astype(int)
    px = np.median(model[r - 3:r + 4, c - 3:c + 4].reshape(-1, 3), axis=0)   # between the path's lines
    assert abs(px[0] - px[2]) < 25 and abs(px[0] - px[1]) < 25, px
    # the colour bar: both scales' darkest and lightest stops are drawn in the strip
    strip = img[rows:].reshape(-1, 3)
    pal = meaning.deviation_palette()
    for k in (0, 1, meaning.SCALE_STEPS, meaning.SCALE_STEPS + 1, 2 * meaning.SCALE_STEPS):
        assert (strip == pal[k]).all(axis=1).any(), k


def test_run_picture_has_few_hues_and_move_ids_only_on_request(example_run, end_picture):
    from monitor.render.runpicture import RunPictures
    from monitor.trace_io import RunView

    pics, img = end_picture
    rows = pics.live.picture_shape[0]
    hues = hue_shares(img[:rows])
    assert (hues > 0.01).sum() <= 8, np.round(hues, 3)   # meaning, not noise
    with RunView(example_run) as view:
        by_move = RunPictures(view, size=600, color_by="move").picture(view.last_stage)
    assert (hue_shares(by_move[:rows]) > 0.01).sum() > (hues > 0.01).sum()


def test_run_picture_frames_the_part_with_axes_tool_and_holder(example_run, end_picture):
    from monitor.render.runpicture import RunPictures
    from monitor.trace_io import RunView

    pics, img = end_picture
    rows, cols = pics.live.picture_shape
    model = img[:rows]
    stock = ~(model == np.array(shaded.BACKGROUND, np.uint8)).all(axis=2)
    assert stock.mean() > 0.7           # the part fills the frame (cropped to the stock)
    for color in (meaning.AXIS_X_COLOR, meaning.AXIS_Y_COLOR, meaning.RAPID_COLOR, shaded.PATH_COLOR,
                  shaded.FINDING_COLOR):
        assert (model == np.array(color, np.uint8)).all(axis=2).any(), color
    with RunView(example_run) as view:
        pics = RunPictures(view, size=600)
        stage = pics_stage = view.stage_table["stage"][np.nonzero(view.stage_table["line"] == GOUGE_LINE)[0][-1]]
        status, tip, row = pics.status(int(stage))
        assert status["stage"] == pics_stage and status["line"] == GOUGE_LINE and status["time"] > 0
        assert status["tool"] == "FLAT 6" and tip is not None
        pic = pics.picture(int(stage))[:rows]
    from monitor.render.live import HOLDER_COLOR

    c, r = pics.live.pixel_of(tip[None])[0].round().astype(int)
    near = pic[max(r - 10, 0):r + 11, max(c - 10, 0):c + 11].reshape(-1, 3).astype(int)
    yellow = (near[:, 0] > 90) & (near[:, 1] > 0.7 * near[:, 0]) & (near[:, 2] < 0.4 * near[:, 0])
    assert yellow.mean() > 0.3                                    # the tool at its tip
    assert (pic == np.array(HOLDER_COLOR, np.uint8)).all(axis=2).any()


def test_findings_are_ringed_from_the_stage_they_were_found_at(example_run):
    from monitor.render.runpicture import RunPictures
    from monitor.trace_io import RunView

    with RunView(example_run) as view:
        pics = RunPictures(view, size=300)
        rows = pics.live.picture_shape[0]
        found = sorted(int(f["stage"]) for f in view.findings)
        red = np.array(shaded.FINDING_COLOR, np.uint8)
        before = pics.picture(found[0] - 1)[:rows]
        after = pics.picture(found[0])[:rows]
    assert not (before == red).all(axis=2).any()      # nothing known yet
    assert (after == red).all(axis=2).any()


@pytest.mark.parametrize("size", [300, 600])
def test_the_legend_fits_a_narrow_picture(example_run, size):
    """Under ~600 px the legend is drawn smaller and wrapped, and the status line onto two
    lines: nothing is cut off at the right edge, and the legend's last pieces (the excess
    end of the colour bar, the finding colour) are there."""
    from monitor.render.live import STRIP_BG
    from monitor.render.runpicture import RunPictures
    from monitor.trace_io import RunView

    with RunView(example_run) as view:
        pics = RunPictures(view, size=size)
        img = pics.picture(view.last_stage)
    rows, cols = pics.live.picture_shape
    assert cols < 600
    strip = img[rows:]
    drawn = np.abs(strip.astype(int) - np.array(STRIP_BG)).sum(axis=-1) > 0
    assert not drawn[:, -3:].any()
    legend = strip[-pics.live._legend_rows * 10 * pics.live.text_scale - 8:]
    for color in (meaning.EXCESS_DARK, shaded.FINDING_COLOR, shaded.TOOL_COLOR):
        assert np.all(legend == np.array(color, np.uint8), axis=-1).sum() > 10, color


def test_run_picture_matches_its_reference(example_run):
    from monitor.render.runpicture import RunPictures
    from monitor.trace_io import RunView

    with RunView(example_run) as view:
        img = RunPictures(view, size=300).picture(view.last_stage)
    check_image(img, "replay_example_end.png", threshold=6.0)


def test_replay_addresses_a_moment_by_line_time_and_stage(example_run, tmp_path, capsys):
    from monitor.trace_io import RunView

    with RunView(example_run) as view:
        tab = view.stage_table
        at_line = int(tab["stage"][np.nonzero(tab["line"] == GOUGE_LINE)[0][-1]])
        t0 = float(view.reader.states()["t"][0])
        k = len(tab) // 2
        at_time, secs = int(tab["stage"][k]), float(tab["t"][k] - t0)
    out = tmp_path / "p.png"
    assert main(["replay", str(example_run), "--line", str(GOUGE_LINE), "--png", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["stage"] == at_line
    assert main(["replay", str(example_run), "--time", f"{secs:.6f}", "--png", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["stage"] == at_time
    assert main(["replay", str(example_run), "--line", "999", "--png", str(out)]) == 2
    err = capsys.readouterr().err
    assert "line 999" in err and "--line" in err and len(err.strip().splitlines()) == 1
    assert main(["replay", str(example_run), "--line", "22", "--stage", "3", "--png", str(out)]) == 2
    assert "one of" in capsys.readouterr().err


def test_replay_size_enlarges(example_run, tmp_path, capsys):
    import imageio.v3 as iio

    small, big = tmp_path / "s.png", tmp_path / "b.png"
    assert main(["replay", str(example_run), "--stage", "end", "--png", str(small), "--size", "300"]) == 0
    assert main(["replay", str(example_run), "--stage", "end", "--png", str(big), "--size", "1200"]) == 0
    a, b = iio.imread(small), iio.imread(big)
    assert 200 < a.shape[1] <= 300 and 900 < b.shape[1] <= 1200


def test_replay_findings_say_stage_and_time(example_run, capsys):
    assert main(["replay", str(example_run), "--findings"]) == 1
    out = capsys.readouterr().out.splitlines()
    gouge = next(x for x in out if x.startswith("Gouge"))
    assert " Stage " in gouge and "into the run." in gouge
    assert main(["replay", str(example_run), "--findings", "--json"]) == 1
    recs = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert all(isinstance(r["at_stage"], int) and r["at_s"] >= 0 for r in recs)


def test_animation_frames_carry_the_overlay_and_their_count(example_run, tmp_path, capsys):
    import imageio.v3 as iio

    gif, mp4 = tmp_path / "a.gif", tmp_path / "a.mp4"
    assert main(["replay", str(example_run), "--from", "0", "--to", "end", "--gif", str(gif), "--mp4", str(mp4),
                 "--frames", "7", "--size", "300", "--json"]) == 0
    said = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    frames = iio.imread(gif, index=None)
    assert said[0]["frames"] == frames.shape[0] == 7
    assert said[1]["frames"] == iio.imread(mp4, index=None).shape[0] == 7
    # every frame has the strip with the legend's colour bar (the live view's overlay)
    pal = meaning.deviation_palette()
    for f in frames:
        assert (np.abs(f[-40:].reshape(-1, 3).astype(int) - pal[1].astype(int)).sum(axis=1) < 30).any()


def test_3d_view_frames_the_part_with_the_deviation_bar(example_run, tmp_path):
    pytest.importorskip("pyvista")
    from monitor.render import view3d
    from monitor.render.runpicture import RunPictures
    from monitor.trace_io import RunView

    with RunView(example_run) as view:
        pics = RunPictures(view, size=300)
        img = view3d.stage_png(pics, view.last_stage, window_size=(300, 300))
    bg = np.array([0x1c, 0x1e, 0x24])
    filled = (np.abs(img.astype(int) - bg).sum(axis=2) > 30)
    assert filled[:, :240].mean() > 0.3            # the part fills the view (the bar is on the right)
    flat = img.reshape(-1, 3).astype(int)
    red = (flat[:, 0] > flat[:, 1] + 80) & (flat[:, 0] > flat[:, 2] + 80)
    assert red.sum() > 40                          # the gouge and the bar's red end
    bar = img[:, 255:].reshape(-1, 3).astype(int)
    assert ((bar[:, 2] > bar[:, 0] + 80)).sum() > 30   # the bar's blue scale
    check_image(img, "replay_example_end_3d.png", threshold=10.0)


def test_report_of_the_example_shows_the_part_the_findings_and_agreeing_times(example_run, tmp_path, capsys):
    import base64
    import io
    import re

    import imageio.v3 as iio

    pytest.importorskip("pyvista")
    out = tmp_path / "r.html"
    assert main(["report", str(example_run), "-o", str(out)]) == 0
    text = out.read_text()
    imgs = dict(re.findall(r'<img alt="([^"]*)" src="data:image/png;base64,([^"]+)"', text))
    pic = {k: iio.imread(io.BytesIO(base64.b64decode(v))) for k, v in imgs.items()}
    assert {"final part in 3-D", "end", "start", "removal and feed over time", "close 3-D view of gouge",
            "section through gouge"} <= set(pic)
    # pictures large enough to see the finding, the gouge in red in its close view and section
    for name in ("close 3-D view of gouge", "section through gouge"):
        img = pic[name].reshape(-1, 3).astype(int)
        assert min(pic[name].shape[:2]) >= 280
        assert ((img[:, 0] > img[:, 1] + 80) & (img[:, 0] > img[:, 2] + 80)).sum() > 200, name
    # the listing round line 22 with the gouge's lines marked
    assert re.search(r"<span class='hit'>\s+22  G1 X30 Z-5\.5", text)
    # the times side by side agree (dry-run: the virtual machine runs the program as timed)
    assert "Cutting recorded / programmed" in text and "(agree)" in text
    assert re.search(r"<tr><td>T1</td><td>0:\d\d\.\d\d</td>", text)     # programmed time per tool
    # the finding's stage and time in its sentence, told from the same start as the plot
    assert re.search(r"Gouge at lines 22-23.*Stage \d+, 0:\d\d\.\d\d into the run\.", text)


def test_the_browser_view_tells_the_same_stage_time_as_the_pictures(example_run):
    # one stage, one time: the page's stage line and the picture strip read one stage table
    from monitor.render.runpicture import RunPictures
    from monitor.trace_io import RunView
    from monitor.web.runmodel import RunModel

    with RunView(example_run) as view:
        pics, model = RunPictures(view, size=300), RunModel(view)
        for stage in (view.first_stage + 1, (view.first_stage + view.last_stage) // 2, view.last_stage):
            status, _tip, _row = pics.status(stage)
            assert model.at(stage).t == pytest.approx(status["time"])
            assert model.at(stage).line == status["line"]
