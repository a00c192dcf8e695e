"""Where the browser view listens, and what is said when others can reach it."""

from __future__ import annotations

import pytest

from monitor.cli import main
from monitor.web.address import exposure_warning, is_loopback, parse_address, url
from sim.errors import InputError


@pytest.mark.parametrize("text, expected", [
    (None, ("127.0.0.1", 0)), ("", ("127.0.0.1", 0)), ("8080", ("127.0.0.1", 8080)),
    (":8080", ("127.0.0.1", 8080)), ("0.0.0.0:9000", ("0.0.0.0", 9000)), ("localhost", ("localhost", 0)),
    ("[::1]:81", ("::1", 81)), ("::1", ("::1", 0)),
])
def test_addresses(text, expected):
    assert parse_address(text) == expected


@pytest.mark.parametrize("text", ["host:port", "127.0.0.1:70000", ":-1"])
def test_a_bad_port_is_one_line_naming_the_option(text):
    with pytest.raises(InputError, match=r"--web.*expected HOST:PORT with a port 0\.\.65535"):
        parse_address(text, "--web")


def test_only_a_loopback_address_goes_unwarned():
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert exposure_warning("127.0.0.1", 80) is None
    warning = exposure_warning("0.0.0.0", 8080)
    assert "0.0.0.0:8080" in warning and "no password" in warning
    assert url("0.0.0.0", 8080) == "http://127.0.0.1:8080/"
    assert url("::1", 81) == "http://[::1]:81/"


def test_view_of_a_missing_run_file_or_a_bad_address_is_exit_2(tmp_path, capsys):
    assert main(["view", str(tmp_path / "nope.dexrun")]) == 2
    assert "no such run file" in capsys.readouterr().err
    assert main(["view", str(tmp_path / "nope.dexrun"), "--address", "x:y"]) == 2
    assert "--address" in capsys.readouterr().err


def test_announce_says_the_address_and_warns_on_stderr_for_another_host(capsys):
    import json
    from types import SimpleNamespace

    from monitor.web.app import announce

    app = SimpleNamespace(server=SimpleNamespace(port=8080), url="http://127.0.0.1:8080/")
    announce(app, "0.0.0.0", as_json=True)
    out, err = capsys.readouterr()
    assert json.loads(out) == {"event": "web", "url": app.url, "host": "0.0.0.0", "port": 8080}
    assert err.startswith("dexmon: warning: the browser view listens on 0.0.0.0:8080") and err.count("\n") == 1
    announce(app, "127.0.0.1", as_json=False)
    out, err = capsys.readouterr()
    assert out == f"browser view: {app.url}\n" and err == ""


def test_a_port_in_use_is_one_line_naming_the_option(tmp_path):
    """Said before anything is served: no traceback, exit 2."""
    import os
    import socket
    import subprocess
    import sys

    from tests.monitor.web.browser import ROOT

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        run = tmp_path / "any.dexrun"
        from tests.monitor.run_helpers import record_run

        record_run(run)
        r = subprocess.run([sys.executable, "-m", "monitor.cli", "view", str(run), "--address", f"127.0.0.1:{port}"],
                           capture_output=True, text=True, timeout=120, cwd=ROOT,
                           env={**os.environ, "PYVISTA_OFF_SCREEN": "true"})
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        f"dexmon view: error: --address: cannot serve the browser view on 127.0.0.1:{port}: Address already in use"]
