"""A run stopped from outside -- Ctrl-C (SIGINT), ``kill`` (SIGTERM), the terminal closing
(SIGHUP) -- ends as Ctrl-C does: "interrupted" said, the summary printed with ``ended:
interrupted``, the run file closed (its summary and row counts written), and an exit status
that is neither clean (0) nor findings (1): 128 + the signal's number."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from monitor.runreader import RunReader

ROOT = Path(__file__).resolve().parents[2]


def as_from_a_terminal() -> None:
    """The child's signals as a command typed in a terminal has them: the tests may run
    under ``nohup`` or in a background job, which ignore SIGHUP or SIGINT (dexmon keeps a
    signal it was started ignoring ignored)."""
    for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(s, signal.SIG_DFL)


def interrupted_dry_run(run: Path, sig: int, after: str = "start"):
    """A dry run of the bundled example sent ``sig`` once its output shows an ``after``
    event (the run has visibly started); (exit status, JSON lines, stderr)."""
    proc = subprocess.Popen([sys.executable, "-m", "monitor.cli", "dry-run", "--speed", "5", "--clock", "sim",
                             "--json", "--run", str(run)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=ROOT, preexec_fn=as_from_a_terminal)
    lines = []
    try:
        for line in proc.stdout:
            lines.append(json.loads(line))
            if lines[-1]["event"] == after:
                break
        assert lines and lines[-1]["event"] == after, lines
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, lines + [json.loads(x) for x in out.splitlines()], err


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGHUP"])
def test_sigterm_and_sighup_end_the_run_as_ctrl_c_does(sig, tmp_path):
    run = tmp_path / "run.sqlite"
    code, out, err = interrupted_dry_run(run, getattr(signal, sig))
    assert code >= 0, f"died of the signal ({code}): no summary, run file not closed"
    assert code == 128 + getattr(signal, sig)
    assert "interrupted" in err and "the run file keeps everything so far" in err, err
    assert "Traceback" not in err
    assert out[-1]["event"] == "summary" and out[-1]["ended"] == "interrupted", out[-1]
    meta = RunReader(run).meta()
    assert json.loads(meta["summary"])["stages"] == out[-1]["stages"]
    assert "rows" in meta  # the writer closed the file


def test_an_interrupted_run_is_not_read_as_clean(tmp_path):
    """Ctrl-C before any finding: the job was not checked to its end, so a script must not
    read it as clean (exit 0); with findings it is not 'findings' (1) either."""
    code, out, err = interrupted_dry_run(tmp_path / "early.sqlite", signal.SIGINT)
    assert out[-1]["findings"] == 0 and out[-1]["ended"] == "interrupted"
    assert code == 130, (code, err)
    # sent as the finding is said: the summary still counts every finding the run said
    code, out, err = interrupted_dry_run(tmp_path / "late.sqlite", signal.SIGINT, after="finding")
    said = [x for x in out if x["event"] == "finding"]
    assert said and out[-1]["findings"] == len(said) and out[-1]["ended"] == "interrupted"
    assert code == 130, (code, err)
