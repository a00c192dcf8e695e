"""``dexmon live`` through ``main(argv)`` against controllers that do not answer (QA 12)."""

from __future__ import annotations

import socket

import pytest

from monitor.cli import main
from monitor.commands.dry_run import EXAMPLE_JOB


def _closed_port() -> int:
    """A loopback port nothing listens on (bound, then closed)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("url", ["grbl+socket://127.0.0.1:{port}", "modbus+tcp://127.0.0.1:{port}?map=generic"])
def test_unreachable_controller_leaves_no_run_file_and_says_why(url, tmp_path, capsys):
    run = tmp_path / "runs" / "r.sqlite"
    run.parent.mkdir()
    code = main(["live", str(EXAMPLE_JOB), "--controller", url.format(port=_closed_port()), "--run", str(run)])
    out, err = capsys.readouterr()
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "refused" in err.lower(), err
    assert "run file" not in out  # the run file is announced only once the machine answers
    assert list(run.parent.iterdir()) == []
