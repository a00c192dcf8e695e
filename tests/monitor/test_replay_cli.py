"""``dexmon replay`` through ``main(argv)`` on a recorded run file."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from monitor.cli import main
from monitor.trace_io import RunView, load_trace
from sim.trace import same_model
from tests.monitor.run_helpers import PATH, STEPS, record_run

LAST = (len(PATH) - 1) * STEPS


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    path = tmp_path_factory.mktemp("run") / "job.dexrun"
    snaps, _ = record_run(path)
    return path, snaps


def test_trace_from_run_file_rebuilds_every_stage(recorded):
    path, snaps = recorded
    tr = load_trace(path)
    assert tr.last_stage == LAST and not tr.truncated
    for s in (0, LAST // 4, LAST // 2, 3 * LAST // 4, LAST):
        assert same_model(tr.grid_at(s), snaps[s]), s
        assert np.array_equal(tr.heights_at(s), snaps[s].top(), equal_nan=True)


def test_run_view_reuses_one_grid_and_one_heights_pair_any_order(recorded):
    path, snaps = recorded
    with RunView(path) as view:
        g0 = h0 = None
        for s in (LAST, LAST // 4, LAST // 2, 0, 3 * LAST // 4, LAST // 2, LAST):
            g = view.grid_at(s)
            h, ids = view.state_at(s)
            assert g0 is None or (g is g0 and np.shares_memory(h, h0))   # no new buffers
            g0, h0 = g, h
            assert same_model(g, snaps[s]), s
            assert h.shape == snaps[s].frame.shape
            assert np.array_equal(h, snaps[s].top(), equal_nan=True), s


def test_png_of_a_stage(recorded, tmp_path, capsys):
    import imageio.v3 as iio

    path, snaps = recorded
    out = tmp_path / "s.png"
    assert main(["replay", str(path), "--stage", "1/2", "--png", str(out)]) == 0
    img = iio.imread(out)
    # the 61 x 41 rays enlarged by whole pixels to at most --size (800), the strip below
    assert img.shape[1] == 61 * 13 and img.shape[0] > 41 * 13 and img.ndim == 3
    assert f"stage {LAST // 2}" in capsys.readouterr().out
    # the cut region is darker/different from the untouched stock in the picture
    end = tmp_path / "e.png"
    assert main(["replay", str(path), "--stage", "end", "--png", str(end)]) == 0
    assert not np.array_equal(iio.imread(end), img)


def test_animation_gif_and_mp4(recorded, tmp_path, capsys):
    import imageio.v3 as iio

    path, _ = recorded
    gif, mp4 = tmp_path / "a.gif", tmp_path / "a.mp4"
    assert main(["replay", str(path), "--from", "0", "--to", "30", "--gif", str(gif),
                 "--mp4", str(mp4), "--frames", "9", "--json"]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [x["frames"] for x in lines] == [9, 9]
    frames = iio.imread(gif, index=None)
    assert frames.shape[0] == 9
    assert not np.array_equal(frames[0], frames[-1])
    assert mp4.stat().st_size > 1000
    # backwards
    back = tmp_path / "b.gif"
    assert main(["replay", str(path), "--from", "30", "--to", "0", "--gif", str(back), "--frames", "9"]) == 0
    rb = iio.imread(back, index=None)
    assert np.abs(rb[0].astype(int) - frames[-1].astype(int)).mean() < 8
    assert np.abs(rb[-1].astype(int) - frames[0].astype(int)).mean() < 8


def test_findings_with_lines(recorded, capsys):
    path, _ = recorded
    assert main(["replay", str(path), "--findings"]) == 1
    out = capsys.readouterr().out
    assert "Gouge at lines 13-14, X15.000 Y16.000 Z6.500: 0.400 mm deep." in out
    assert "Rapid into stock at line 10, X2.000 Y2.000 Z8.000: 3.200 mm³." in out
    assert out.lower().count("gouge") == 1  # one sentence, no kind repeated by the message


def test_stages_are_one_range_everywhere(tmp_path, capsys):
    """Stage n = the model after the n-th recorded cut, 0 = the stock: cuts that removed
    nothing still count (the trace ends before them), and a stage outside 0..N is one
    line naming the range, exit 2 (QA 3)."""
    path = tmp_path / "air.dexrun"
    snaps, _ = record_run(path, air_cuts=3)
    last = LAST + 3
    with RunView(path) as view:
        assert view.trace.last_stage == LAST and (view.first_stage, view.last_stage) == (0, last)
        assert same_model(view.grid_at(last), snaps[LAST])
    assert main(["replay", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["last_stage"] == last
    for stage in ("0", str(last), "end"):
        assert main(["replay", str(path), "--stage", stage, "--png", str(tmp_path / "ok.png")]) == 0
    capsys.readouterr()
    for args in (["--stage", str(last + 1), "--png", str(tmp_path / "x.png")],
                 ["--export-stl", str(last + 100), str(tmp_path / "x.stl")],
                 ["--from", "0", "--to", str(last + 1), "--gif", str(tmp_path / "x.gif")]):
        assert main(["replay", str(path), *args]) == 2
        err = capsys.readouterr().err
        assert f"stage must be 0..{last}" in err and len(err.strip().splitlines()) == 1, err
        assert not (tmp_path / "x.png").exists() and not (tmp_path / "x.stl").exists()


def test_export_stl(recorded, tmp_path):
    trimesh = pytest.importorskip("trimesh")
    pytest.importorskip("sim.surface")
    path, snaps = recorded
    out = tmp_path / "m.stl"
    assert main(["replay", str(path), "--export-stl", "12", str(out)]) == 0
    mesh = trimesh.load(out)
    assert mesh.is_watertight
    assert mesh.volume == pytest.approx(snaps[12].volume(), rel=0.02)


def test_summary_and_errors(recorded, tmp_path, capsys):
    path, _ = recorded
    assert main(["replay", str(path), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["last_stage"] == LAST and s["findings"] == 2 and not s["truncated"]
    assert main(["replay", str(path), "--stage", "x", "--png", str(tmp_path / "x.png")]) == 2
    assert "--stage" in capsys.readouterr().err
    assert main(["replay", str(tmp_path / "missing.dexrun")]) == 2
    bad = tmp_path / "bad.dexrun"
    bad.write_bytes(b"not sqlite at all" * 10)
    assert main(["replay", str(bad)]) == 2
    assert "error" in capsys.readouterr().err


def test_removal_per_move_matches_the_models(recorded):
    path, snaps = recorded
    with RunView(path) as view:
        per_move = view.removal_per_move()
    total = snaps[0].volume() - snaps[LAST].volume()
    assert sum(per_move.values()) == pytest.approx(total, rel=1e-5)
    for m in range(1, len(PATH)):
        want = snaps[(m - 1) * STEPS].volume() - snaps[m * STEPS].volume()
        assert per_move.get(m, 0.0) == pytest.approx(want, rel=1e-5, abs=1e-6)


def test_run_cut_short_mid_write_replays_to_last_complete_stage(tmp_path):
    """A session killed while writing: the WAL's last transaction is torn."""
    path = tmp_path / "crash.dexrun"
    sizes = {}

    def hook(w, stage):
        w.flush()
        sizes[stage] = (path.parent / (path.name + "-wal")).stat().st_size

    snaps, w = record_run(path, chunk_every=5, stop_after=20, writer_hook=hook)
    w.flush()
    try:
        copy = tmp_path / "copy" / "crash.dexrun"
        copy.parent.mkdir()
        shutil.copy(path, copy)
        wal = (path.parent / (path.name + "-wal")).read_bytes()
        # cut the WAL in the middle of the transaction that wrote the stage-20 chunk
        cut = sizes[15] + (sizes[20] - sizes[15]) // 2
        (copy.parent / (copy.name + "-wal")).write_bytes(wal[:cut])
    finally:
        w.close()
    tr = load_trace(copy)
    assert tr.last_stage == 15
    for s in (0, 7, 15):
        assert same_model(tr.grid_at(s), snaps[s])
    assert main(["replay", str(copy), "--stage", "end", "--png", str(tmp_path / "c.png")]) == 0


PART_A = "G21 G90 M3 S12000\nG0 Z15\nG0 X8 Y8\nG1 Z8 F600\nG1 X30 Y10\nG1 Y20 Z7\nG0 Z15\n"
PART_B = "G21 G90 M3 S12000\nG0 Z15\nG0 X12 Y20\nG1 Z6.5 F600\nG1 X28 Y12\nG2 X20 Y8 I-4 J-2\nG0 Z15\nM2\n"
STOCK = "box:5,5,0,35,25,10"


def test_resumed_simulation_equals_a_straight_one(tmp_path, capsys):
    pytest.importorskip("sim.cut")
    from monitor.runfile import RunWriter
    from monitor.trace_io import store_trace_chunk
    from sim.cut import Cutter
    from sim.gcode import load_program
    from sim.tools import parse_tool_spec
    from sim.trace import Trace

    a, b, ab = tmp_path / "a.nc", tmp_path / "b.nc", tmp_path / "ab.nc"
    a.write_text(PART_A)
    b.write_text(PART_B)
    ab.write_text(PART_A + PART_B)
    common = ["--tool", "ball:6", "--resolution", "0.5"]
    straight = tmp_path / "straight.npy"
    assert main(["simulate", str(ab), "--stock", STOCK, *common, "--heights", str(straight)]) == 0

    # record part A as a run, one stage per move
    from monitor.commands.simulate import build_stock
    grid = build_stock(STOCK, 0.5)
    moves = load_program(str(a)).moves
    cutter = Cutter(grid, parse_tool_spec("ball:6"))
    run = tmp_path / "a.dexrun"
    w = RunWriter(run)
    trace = Trace(grid)
    store_trace_chunk(w, trace)
    for k in range(len(moves)):
        res = cutter.cut_moves(moves[k:k + 1], move_ids=np.array([k + 1]))
        trace.record_cut(grid, res, k + 1)
    store_trace_chunk(w, trace)
    w.close()

    resumed = tmp_path / "resumed.npy"
    assert main(["simulate", str(b), "--resume", f"{run}:end", *common, "--heights", str(resumed)]) == 0
    h_straight, h_resumed = np.load(straight), np.load(resumed)
    assert np.array_equal(h_straight, h_resumed, equal_nan=True)
    # resuming from an earlier stage is a different part (the moves after it never ran)
    early = tmp_path / "early.npy"
    # (more material is left for part B to meet, so the checks may report findings: exit 1)
    assert main(["simulate", str(b), "--resume", f"{run}:2", *common, "--heights", str(early)]) in (0, 1)
    assert not np.array_equal(np.load(early), h_straight, equal_nan=True)
    capsys.readouterr()
    assert main(["simulate", str(b), "--resume", f"{run}", *common]) == 2
    assert "RUN:STAGE" in capsys.readouterr().err
    assert main(["simulate", str(b), "--resume", f"{run}:99", *common]) == 2
    assert main(["simulate", str(b), *common]) == 2


def test_format_finding_says_line_range_worst_line_and_programmed_tip():
    """Findings from sim.checks carry ``line_range`` (their ``lines`` may be cut short),
    ``worst_line``, the contact ``position`` and the ``programmed`` tip; older runs lack
    them and read as before."""
    from monitor.commands.replay import format_finding
    from monitor.render.live import finding_label

    f = {"kind": "gouge", "line": 22, "lines": [22, 23, 24], "line_range": [22, 90], "lines_total": 40,
         "worst_line": 31, "position": [30.0, 19.0, -5.5], "programmed": [30.0, 19.0, -2.5], "depth": 0.5}
    text = format_finding(f)
    assert text.startswith("Gouge at lines 22-90 (40 lines) (worst at line 31), X30.000 Y19.000 Z-5.500 "
                           "(programmed tip X30.000 Y19.000 Z-2.500): 0.500 mm deep"), text
    assert finding_label(f) == "GOUGE L22-90"
    old = {"kind": "gouge", "line": 13, "lines": [13, 14], "position": [15.0, 16.0, 6.5], "depth": 0.4}
    assert format_finding(old) == "Gouge at lines 13-14, X15.000 Y16.000 Z6.500: 0.400 mm deep."


def test_finding_moments_take_the_stage_cut_time_else_the_program_time(recorded):
    from monitor.render.runpicture import finding_moments

    path, _ = recorded
    with RunView(path) as view:
        got = finding_moments(view, [{"kind": "gouge", "stage": 4, "line": 13},
                                     {"kind": "gouge", "line": 999, "time_s": 7.5},
                                     {"kind": "gouge"}])
    # record_run stamps stage n's cut at n * 0.1 s and writes no states: times from 0
    assert got[0] == (4, pytest.approx(0.4)) and got[1] == (None, 7.5) and got[2] == (None, None)


def test_a_run_recorded_away_from_its_job_still_knows_its_job_and_tool(tmp_path):
    # the bundled job names its files relative to its own folder; the run file is written
    # elsewhere: replay, report and the browser view all read the job through RunView.job
    run = tmp_path / "elsewhere" / "face.dexrun"
    run.parent.mkdir()
    assert main(["dry-run", "--clock", "sim", "--speed", "50", "--quiet", "--run", str(run)]) == 1
    with RunView(run) as view:
        assert view.job is not None
        assert view.tool() is not None and view.tool().diameter == pytest.approx(6.0)
