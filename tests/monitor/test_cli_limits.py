"""Inputs a command cannot use are refused with one line and exit 2, never a traceback,
a crash of the process or a run that cannot end (README: exit 2 for an error, "bad input
names file, line and what was expected").

Each test here was a failure first: a job whose dexel grid needs terabytes crashed
``dry-run``/``live`` in numpy (``ArrayMemoryError``, exit 1 = "findings") where
``simulate`` refused it cleanly."""

from __future__ import annotations

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
