"""``dexmon live`` behind a passthrough: when the monitor is done, the summary comes first,
then the passthrough keeps serving the user's sender until it disconnects, then closes."""

from __future__ import annotations

import argparse
import json

from monitor.commands.dry_run import EXAMPLE_JOB, VIRTUAL_MACHINE, virtual_controller
from monitor.commands.live import run_session
from monitor.job import load_job
from monitor.program_moves import load_moves


def _serving_controller(moves, capsys, calls):
    """The virtual controller with a passthrough's wait_sender_closed."""
    vc = virtual_controller(moves[:3], speed=20.0, rate=50)
    real_close = vc.close

    def wait_sender_closed(timeout=None, grace=1.0):
        out = capsys.readouterr()
        calls.append(("wait", out.out, out.err))
        return True

    def close():
        calls.append(("close",))
        real_close()

    vc.wait_sender_closed, vc.close = wait_sender_closed, close
    return vc


def test_summary_then_serve_the_sender_then_close(tmp_path, capsys):
    job = load_job(EXAMPLE_JOB)
    job.machine = dict(VIRTUAL_MACHINE)
    moves, _ = load_moves(job)
    calls: list = []
    vc = _serving_controller(moves, capsys, calls)
    args = argparse.Namespace(run=str(tmp_path / "r.sqlite"), quiet=False, json=True)
    run_session(args, job, vc, done=lambda: vc.done)
    assert [c[0] for c in calls] == ["wait", "close"]
    _, out, err = calls[0]
    assert json.loads(out.splitlines()[-1])["event"] == "summary"  # printed before the wait
    assert "passthrough stays open for your sender until it disconnects; Ctrl-C to stop" in err
