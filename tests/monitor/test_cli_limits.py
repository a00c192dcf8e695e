"""Inputs a command cannot use are refused with one line and exit 2, never a traceback,
a crash of the process or a run that cannot end (README: exit 2 for an error, "bad input
names file, line and what was expected").

Each test here was a failure first: a job whose dexel grid needs terabytes crashed
``dry-run``/``live`` in numpy (``ArrayMemoryError``, exit 1 = "findings") where
``simulate`` refused it cleanly."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from monitor.cli import main

EXAMPLE = Path(__file__).resolve().parents[2] / "monitor" / "examples" / "clamp_job" / "job.toml"


def one_line_error(capsys, rc: int) -> str:
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    return err


@pytest.mark.parametrize("flags", [
    ["--resolution", "1e-9"],                                   # 6e10 x 4e10 rays
    ["--stock", "box:0,0,-20,60000,40000,0"],                   # a 60 m x 40 m block at 0.25 mm
], ids=["resolution", "stock"])
@pytest.mark.parametrize("command", ["dry-run", "live"])
def test_a_job_whose_grid_is_too_large_is_refused_like_simulate(command, flags, tmp_path, capsys):
    run = tmp_path / "r.sqlite"
    extra = ["--controller", "virtual://"] if command == "live" else ["--clock", "sim"]
    rc = main([command, str(EXAMPLE), *flags, *extra, "--quiet", "--run", str(run)])
    err = one_line_error(capsys, rc)
    assert "dexel grid needs about" in err and "over the 4096 MB limit" in err, err
    assert not run.exists()  # nothing was followed: no run file left behind


def test_simulate_refuses_the_same_job_with_the_same_words(tmp_path, capsys):
    rc = main(["simulate", str(EXAMPLE), "--resolution", "1e-9", "--json"])
    err = one_line_error(capsys, rc)
    assert "dexel grid needs about" in err and "over the 4096 MB limit" in err, err


# --- numbers on the command line --------------------------------------------------------
# argparse's type=float/int takes nan, inf, 0 and negatives: a frame rate of 0 was a
# ZeroDivisionError in the GIF writer, -1 an OverflowError, nan a ValueError; --frames 0
# and -3 were taken silently, report --size 0 divided by zero.

@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    from tests.monitor.run_helpers import record_run

    path = tmp_path_factory.mktemp("run") / "job.dexrun"
    record_run(path)
    return path


@pytest.mark.parametrize("option, value, expected", [
    ("--fps", "0", "--fps: expected a positive number, got 0"),
    ("--fps", "-1", "--fps: expected a positive number, got -1"),
    ("--fps", "nan", "--fps: expected a positive number, got nan"),
    ("--fps", "inf", "--fps: expected a positive number, got inf"),
    ("--frames", "0", "--frames: expected a positive whole number, got 0"),
    ("--frames", "-3", "--frames: expected a positive whole number, got -3"),
])
def test_replay_animation_numbers_must_mean_something(recorded, tmp_path, capsys, option, value, expected):
    gif = tmp_path / "o.gif"
    rc = main(["replay", str(recorded), "--from", "0", "--to", "5", "--gif", str(gif), option, value])
    assert expected in one_line_error(capsys, rc)
    assert not gif.exists()


@pytest.mark.parametrize("option, value, expected", [
    ("--size", "0", "--size: expected a picture size of at least 16 pixels, got 0"),
    ("--size", "-5", "--size: expected a picture size of at least 16 pixels, got -5"),
    ("--max-findings", "-1", "--max-findings: expected a whole number >= 0, got -1"),
])
def test_report_numbers_must_mean_something(recorded, tmp_path, capsys, option, value, expected):
    out = tmp_path / "r.html"
    rc = main(["report", str(recorded), "-o", str(out), option, value])
    assert expected in one_line_error(capsys, rc)
    assert not out.exists()


def test_report_with_no_finding_pictures_is_fine(recorded, tmp_path, capsys):
    assert main(["report", str(recorded), "-o", str(tmp_path / "r.html"), "--max-findings", "0"]) == 0


@pytest.mark.parametrize("value", ["nan", "inf", "0", "-1"])
def test_simulate_memory_limit_must_be_a_positive_number(capsys, value):
    # nan switched the limit off (every comparison false); -1 refused every grid with
    # "over the -1 MB limit"
    rc = main(["simulate", str(EXAMPLE), "--memory-limit", value, "--json"])
    assert f"--memory-limit: expected a positive number, got {value}" in one_line_error(capsys, rc)


@pytest.mark.parametrize("command", ["simulate", "dry-run"])
def test_max_loop_zero_is_refused_not_the_default(command, tmp_path, capsys):
    # simulate read 0 as "not given" (the default 100,000 passes) while dry-run refused it
    extra = ["--json"] if command == "simulate" else ["--quiet", "--run", str(tmp_path / "r.sqlite")]
    rc = main([command, str(EXAMPLE), "--max-loop", "0", *extra])
    assert "--max-loop" in one_line_error(capsys, rc)


@pytest.mark.parametrize("value", ["inf", "nan", "0"])
def test_view_fps_must_be_a_finite_positive_number(tmp_path, capsys, value):
    rc = main(["dry-run", "--frames", str(tmp_path / "f"), "--view-fps", value, "--quiet",
               "--run", str(tmp_path / "r.sqlite")])
    assert f"--view-fps: expected a positive number, got {value}" in one_line_error(capsys, rc)


# --- picture sizes ------------------------------------------------------------------------
# --size had no upper bound: replay --size 100000 grew to 24 GB until the OS killed the
# process (exit 137, no message)

@pytest.mark.parametrize("command", ["replay", "report"])
def test_a_picture_size_past_the_cap_is_refused_with_what_it_would_take(recorded, tmp_path, capsys, command):
    from monitor.options import MAX_PICTURE_PX

    out = tmp_path / ("o.png" if command == "replay" else "r.html")
    argv = ([command, str(recorded), "--stage", "end", "--png", str(out)] if command == "replay"
            else [command, str(recorded), "-o", str(out)])
    rc = main([*argv, "--size", "100000"])
    err = one_line_error(capsys, rc)
    assert f"--size: expected at most {MAX_PICTURE_PX} pixels, got 100000" in err
    assert "GB to draw" in err  # what the size asked for would take
    assert not out.exists()


def test_the_largest_picture_size_is_taken(recorded, tmp_path, capsys):
    from monitor.options import MAX_PICTURE_PX, picture_size

    assert picture_size(MAX_PICTURE_PX) == MAX_PICTURE_PX


# --- dry-run speed and poll rate ----------------------------------------------------------

@pytest.mark.parametrize("value", ["inf", "nan", "0", "-5"])
def test_dry_run_speed_must_be_a_finite_positive_number(tmp_path, capsys, value):
    # inf was taken: the whole program ran between two polls
    rc = main(["dry-run", "--speed", value, "--quiet", "--run", str(tmp_path / "r.sqlite")])
    assert f"--speed: expected a positive number, got {value}" in one_line_error(capsys, rc)
    assert not (tmp_path / "r.sqlite").exists()


def _dry_run_polling_at(poll_hz: str, tmp_path, capsys) -> str:
    """The one-line error of a dry run of the example job with ``poll_hz`` set."""
    job = tmp_path / "job.toml"
    job.write_text(EXAMPLE.read_text().replace("poll_hz = 50", f"poll_hz = {poll_hz}"))
    for name in ("face.nc", "tools.tbl", "design.stl"):
        (tmp_path / name).write_bytes((EXAMPLE.parent / name).read_bytes())
    rc = main(["dry-run", str(job), "--clock", "sim", "--quiet", "--run", str(tmp_path / "r.sqlite")])
    return one_line_error(capsys, rc)


def test_a_poll_rate_no_loop_can_keep_is_refused(tmp_path, capsys):
    # poll_hz = 1e9 with --clock sim moved the machine 5 ns a poll: the run never ended
    err = _dry_run_polling_at("1e9", tmp_path, capsys)
    assert "[controller] poll_hz" in err and "at most 1000 Hz" in err


def test_a_poll_rate_too_slow_to_watch_the_tool_is_refused(tmp_path, capsys):
    # poll_hz = 0.001 was taken: a read every 17 minutes, the tool 80 m further at 5000
    # mm/min between two, and a feed hold up to 17 minutes late
    err = _dry_run_polling_at("0.001", tmp_path, capsys)
    assert "[controller] poll_hz" in err and "at least 1 Hz" in err


def _findings(capsys, tmp_path, speed: str) -> list[tuple]:
    rc = main(["dry-run", "--clock", "sim", "--speed", speed, "--json", "--run", str(tmp_path / f"s{speed}.sqlite")])
    events = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    found = sorted((e["kind"], tuple(e["line_range"])) for e in events if e["event"] == "finding")
    assert rc == (1 if found else 0)
    return found


def test_a_dry_run_polled_once_over_the_whole_program_finds_what_a_slow_one_does(tmp_path, capsys):
    """At --speed 10000 one poll step (200 s) is longer than the example (46 s). Before:
    with --clock sim the first poll already came a step late, at the program's end, and
    the run found nothing; with the wall clock the one jump from before M3 to after M5 was
    judged by the spindle both polls reported (off) and made the whole program a false
    spindle_stopped_cutting (lines 11-32)."""
    slow = _findings(capsys, tmp_path, "50")
    assert [k for k, _ in slow] == ["gouge", "rapid_into_stock"]
    assert _findings(capsys, tmp_path, "10000") == slow
