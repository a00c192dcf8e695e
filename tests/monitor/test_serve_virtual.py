"""``dexmon serve-virtual`` through ``main(argv)`` and as a real process."""

from __future__ import annotations

import os
import selectors
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from drivers.modbus.driver import ModbusController
from drivers.modbus.regmap import load_map
from drivers.state import RunState
from monitor.cli import main

ROOT = Path(__file__).resolve().parents[2]
JOB = "G21 G90\nG0 X-5 Y-5\nG1 X-20 F300\nG1 Y-10\nM2\n"


@pytest.fixture
def job(tmp_path):
    p = tmp_path / "job.nc"
    p.write_text(JOB)
    return p


def read_lines_until(proc, prefixes, timeout=60.0):
    """Lines printed by ``proc`` until one starting with each of ``prefixes`` was seen."""
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    found: dict[str, str] = {}
    deadline = time.monotonic() + timeout
    while set(prefixes) - set(found):
        left = deadline - time.monotonic()
        assert left > 0, f"serve-virtual printed no {set(prefixes) - set(found)} in time"
        if not sel.select(left):
            continue
        line = proc.stdout.readline()
        assert line, f"serve-virtual exited early: rc={proc.wait()} stderr={proc.stderr.read()}"
        for p in prefixes:
            if line.startswith(p):
                found[p] = line.strip()
    return found


def spawn(*args):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.Popen([sys.executable, "-m", "monitor.cli", "serve-virtual", *args], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_runs_program_to_the_end_in_process(job, capsys):
    rc = main(["serve-virtual", str(job), "--modbus", "tcp:0", "--speed", "50", "--exit-when-done"])
    out = capsys.readouterr().out.splitlines()
    assert rc == 0
    assert out[0].startswith("modbus tcp: 127.0.0.1:") and out[0].endswith("map generic")
    assert any(l == "program done: Idle at X-20.000 Y-10.000 Z0.000" for l in out)
    assert out[-1] == "stopped"


def test_modbus_server_process_serves_the_moving_machine_and_stops_on_sigterm(job):
    # real time: the feeds of lines 3-4 last 4 s, longer than a loaded machine takes to
    # connect (the served machine runs from its start, as a real one does)
    proc = spawn(str(job), "--modbus", "tcp:0", "--speed", "1")
    try:
        found = read_lines_until(proc, ["modbus tcp:"])
        port = int(found["modbus tcp:"].split(":")[2].split()[0])
        c = ModbusController(load_map("generic"), host="127.0.0.1", port=port, timeout=2.0)
        c.connect()
        states = []
        try:
            for st in c.states(0.02):
                states.append(st)
                if st.state == RunState.IDLE and st.mpos[1] == pytest.approx(-10.0, abs=1e-4):
                    break
                assert len(states) < 3000
        finally:
            c.close()
        assert any(s.state == RunState.RUN and s.line in (3, 4) for s in states)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=30)
        assert proc.returncode == 0, err
        assert out.strip().endswith("stopped")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_grbl_and_modbus_together(job):
    pytest.importorskip("drivers.grbl.peer")
    proc = spawn("--grbl", "tcp:0", "--modbus", "tcp:0", "--speed", "10")
    try:
        found = read_lines_until(proc, ["grbl tcp:", "modbus tcp:"])
        gport = int(found["grbl tcp:"].rsplit(":", 1)[1])
        with socket.create_connection(("127.0.0.1", gport), timeout=10) as s:
            s.settimeout(10)
            s.sendall(b"?")
            buf = b""
            while b">" not in buf:
                chunk = s.recv(1024)
                assert chunk, "GRBL peer closed the socket"
                buf += chunk
            assert b"<Idle|" in buf
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
        assert proc.returncode == 0, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.parametrize(
    "argv,message",
    [
        (["serve-virtual"], "nothing to serve"),
        (["serve-virtual", "--modbus", "udp:502"], "--modbus 'udp:502': expected 'tcp:PORT'"),
        (["serve-virtual", "--grbl", "serial"], "expected 'pty' or 'tcp:PORT'"),
        (["serve-virtual", "--modbus", "tcp:0", "--speed", "0"], "--speed"),
        # inf was taken: the runner advanced the machine by inf (or 0 x inf = nan) seconds
        (["serve-virtual", "--modbus", "tcp:0", "--speed", "inf"], "--speed: expected a positive number, got inf"),
        (["serve-virtual", "--modbus", "tcp:0", "--speed", "nan"], "--speed: expected a positive number, got nan"),
        (["serve-virtual", "--modbus", "tcp:0", "--max-rate", "fast"], "--max-rate 'fast'"),
        (["serve-virtual", "--modbus", "tcp:0", "--map", "/nonexistent/map.toml"], "/nonexistent/map.toml: cannot read register map"),
        (["serve-virtual", "--modbus", "tcp:0", "--faults", "boom=1"], "bad item 'boom=1'"),
    ],
)
def test_bad_arguments_are_one_line_errors(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_missing_program_is_a_clear_error(tmp_path, capsys):
    assert main(["serve-virtual", str(tmp_path / "nope.nc"), "--modbus", "tcp:0"]) == 2
    err = capsys.readouterr().err
    assert "nope.nc" in err and "Traceback" not in err
