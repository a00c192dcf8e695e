"""Dry runs of the bundled example over every controller kind: the planted gouge and rapid
are predicted with lead time > 0, each alerted once, and the run file holds the run."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from drivers.state import RunState
from monitor.alerts import Alerter
from monitor.commands.dry_run import EXAMPLE_JOB, virtual_controller
from monitor.cli import main
from monitor.job import load_job
from monitor.runfile import RunWriter
from monitor.runreader import RunReader
from monitor.loop import run_controller
from monitor.program_moves import load_moves
from monitor.session import Session

GOUGE_LINE, RAPID_LINE = 22, 36


@pytest.fixture(scope="module")
def example():
    job = load_job(EXAMPLE_JOB)
    moves, _ = load_moves(job)
    return job, moves


def check_planted(findings):
    kinds = {(f["kind"], f["line"]) for f in findings}
    assert ("gouge", GOUGE_LINE) in kinds and ("rapid_into_stock", RAPID_LINE) in kinds, findings
    for f in findings:
        if (f["kind"], f["line"]) in (("gouge", GOUGE_LINE), ("rapid_into_stock", RAPID_LINE)):
            assert f["predicted"] and f["lead_time_s"] > 0, f
    keys = [(f["kind"], f["line"]) for f in findings]
    assert len(keys) == len(set(keys)), "a finding was alerted twice"


def test_cli_dry_run_bundled_example(tmp_path, capsys):
    run = tmp_path / "run.sqlite"
    # the sim clock: the machine moves per poll, so the lead times do not hang on how busy
    # the computer is (with the wall clock at 20x a loaded machine saw the gouge arrive first)
    code = main(["dry-run", "--speed", "20", "--clock", "sim", "--json", "--run", str(run)])
    out = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert code == 1
    assert out[0] == {"event": "start", "run": str(run), "program": str(load_job(EXAMPLE_JOB).program),
                      "controller": out[0]["controller"], "machine": out[0]["machine"], "stock_model": "z"}
    # the virtual machine's own limits time the program
    assert set(out[0]["machine"]["sources"].values()) == {"controller"}
    assert out[0]["machine"]["max_rate"] == [5000.0, 5000.0, 2000.0]
    findings = [x for x in out if x["event"] == "finding"]
    check_planted(findings)
    for f in findings:
        assert {"kind", "line", "position", "lead_time_s"} <= set(f)
    assert out[-1]["event"] == "summary" and out[-1]["findings"] == len(findings)
    # the virtual spindle then really gets there: each record updated, never re-alerted
    updates = [x for x in out if x["event"] == "finding_update"]
    assert sorted(u["kind"] for u in updates if u["status"] == "happened") == ["gouge", "rapid_into_stock"]
    # the gouge's second row (line 23) grew the alerted finding rather than being dropped
    # (an update carries what changed: its line_range when that grew)
    first = next(f for f in findings if f["kind"] == "gouge")
    assert [first["line_range"], *(u["line_range"] for u in updates if u["kind"] == "gouge" and "line_range" in u)][
        -1] == [22, 23]
    # an update carries the lines it added: with the alert's, every line of the gouge
    assert set(first["lines"]) | {ln for u in updates if u["kind"] == "gouge" for ln in u.get("lines_added", ())} == {22, 23}
    r = RunReader(run)
    assert [f["kind"] for f in r.findings()] == [f["kind"] for f in findings]
    assert all(f["status"] == "happened" for f in r.findings())
    assert r.state_count() > 20 and r.get_array("moves").size > 0
    assert "[stock]" in r.meta()["job"] and "planted gouge" in r.meta()["program"]
    assert len(list(r.cuts())) > 0


def test_in_process_virtual_with_mid_program_start(example, tmp_path):
    job, moves = example
    start = int(np.nonzero(moves["line"] == GOUGE_LINE + 3)[0][0])  # after the gouge
    vc = virtual_controller(moves[start:], speed=1.0, rate=50, clock="sim")
    with RunWriter(tmp_path / "r.sqlite") as w:
        s = Session(job, moves, run=w, alerter=Alerter(run=w))
        vc.connect()
        run_controller(s, vc, 0.0, done=lambda: vc.done)
        vc.close()
        s.finish()
    assert {(f["kind"], f["line"]) for f in s.findings} == {("rapid_into_stock", RAPID_LINE)}
    assert s.findings[0]["lead_time_s"] > 0


def test_feed_hold_stops_the_machine_before_the_gouge(example):
    job, moves = example
    vc = virtual_controller(moves, speed=1.0, rate=50, clock="sim")
    s = Session(job, moves, alerter=Alerter(feed_hold=vc.feed_hold))
    vc.connect()
    held = None
    for _ in range(5000):
        st = vc.poll()
        s.step(st)
        if st.state == RunState.HOLD and st.substate == 0:
            held = st
            break
    vc.close()
    assert held is not None and s.findings[0]["kind"] == "gouge"
    # the spindle never got to the gouge: the live model is untouched below the design top there
    top = s.live.top()
    f = s.live.frame
    i, j = int(round((30 - f.origin[0]) / f.spacing)), int(round((19 - f.origin[1]) / f.spacing))
    assert top[j, i] >= -5.0 - 1e-3


def _fast_vm(moves):
    from drivers.virtual.machine import VirtualMachine
    from drivers.virtual.machine_config import MachineConfig
    from monitor.commands.dry_run import VIRTUAL_ACCEL, VIRTUAL_MAX_RATE

    cfg = MachineConfig(max_rate=VIRTUAL_MAX_RATE, accel=VIRTUAL_ACCEL, soft_limits=False)
    return VirtualMachine(cfg, position=moves["start"][0])


def _session(job, moves):
    """A session compiled and ready before the machine starts (as run_session does)."""
    s = Session(job, moves, alerter=Alerter())
    s.warm_up()
    return s


def _follow_over(example, serve, until_done: bool = True):
    """Follow the example job on the fast virtual machine, run at 12x by a real-time
    runner, through the controller a peer serves: ``serve(vm) -> (url, close)``. Without
    ``until_done`` the loop is not told when the machine finished: it must see it."""
    from drivers.registry import open_controller
    from drivers.virtual.controller import ProgramFeeder
    from drivers.virtual.runner import RealTimeRunner

    job, moves = example
    s = _session(job, moves)
    vm = _fast_vm(moves)
    feeder = ProgramFeeder(moves)
    url, close = serve(vm)
    runner = RealTimeRunner(vm, speed=12.0, on_tick=feeder).start()

    def done():
        with vm.lock:
            return feeder.all_queued and not vm.busy
    try:
        controller = open_controller(url)
        controller.connect()
        try:
            run_controller(s, controller, 0.01, done=done if until_done else None, max_seconds=120)
        finally:
            controller.close()
    finally:
        runner.stop()
        close()
    return s


def test_grbl_peer_over_pty(example):
    from drivers.grbl.peer import GrblPeer

    def serve(vm):
        peer = GrblPeer(vm, run=False)
        return f"grbl://{peer.serve_pty()}", peer.close
    check_planted(_follow_over(example, serve).findings)


def test_live_on_a_grbl_device_ends_at_the_programs_end(example):
    """The machine sits idle at the final position: the run ends there by itself, with
    its findings (it used to wait for Ctrl-C: the end was the table's M2 row, which sync
    never reaches)."""
    from drivers.grbl.peer import GrblPeer

    def serve(vm):
        peer = GrblPeer(vm, run=False)
        return f"grbl://{peer.serve_pty()}", peer.close
    s = _follow_over(example, serve, until_done=False)
    assert s.end_reason == "program end"
    check_planted(s.findings)


def test_modbus_peer_over_tcp(example):
    from drivers.modbus.regmap import load_map
    from drivers.modbus.server import ModbusVirtualServer

    def serve(vm):
        server = ModbusVirtualServer(vm, load_map("generic")).start()
        return f"modbus+tcp://127.0.0.1:{server.port}?map=generic", server.stop
    check_planted(_follow_over(example, serve).findings)


def test_sigkilled_run_leaves_a_file_that_opens(tmp_path):
    run = tmp_path / "killed.sqlite"
    proc = subprocess.Popen([sys.executable, "-m", "monitor.cli", "dry-run", "--speed", "10", "--json",
                             "--run", str(run)], stdout=subprocess.PIPE, text=True,
                            cwd=Path(__file__).resolve().parents[2])
    try:
        lines = []
        for line in proc.stdout:  # killed at the second finding: seconds into the run
            lines.append(json.loads(line))
            if [x["event"] for x in lines].count("finding") == 2:
                break
        assert lines and lines[-1]["event"] == "finding", lines
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    assert proc.returncode == -signal.SIGKILL
    r = RunReader(run)
    assert r.state_count() > 10
    assert r.get_array("moves").size > 0 and "[stock]" in r.meta()["job"]
    st = r.states()
    assert np.all(np.diff(st["t"]) >= 0)


def test_one_finding_one_position_and_size_in_every_output(example, tmp_path, capsys):
    """The text alert, the JSON line (with its updates), the run file, replay --findings and
    simulate give each planted finding the same lines, position and size (QA 1 and 2)."""
    import io

    from rich.console import Console

    job, moves = example
    term, js = io.StringIO(), io.StringIO()
    run = tmp_path / "r.sqlite"
    vc = virtual_controller(moves, speed=1.0, rate=50, clock="sim")
    with RunWriter(run) as w:
        s = Session(job, moves, run=w, alerter=Alerter(console=Console(file=term, width=200), json_stream=js, run=w))
        vc.connect()
        run_controller(s, vc, 0.0, done=lambda: vc.done)
        vc.close()
        s.finish()
    # the JSON stream: each finding's last word (its finding line, then its updates, which
    # carry the lines they add)
    last = {}
    for x in map(json.loads, js.getvalue().splitlines()):
        key = x.get("id") or len(last) + 1
        rec = last.get(key, {})
        lines = sorted(set(rec.get("lines", [])) | set(x.get("lines", [])) | set(x.get("lines_added", [])))
        last[key] = {**rec, **{k: v for k, v in x.items() if k not in ("event", "id")}, "lines": lines}
    stored = RunReader(run).findings()
    assert main(["simulate", str(EXAMPLE_JOB), "--json"]) == 1
    sim = [f for x in map(json.loads, capsys.readouterr().out.splitlines()) for f in x.get("findings", [])]
    assert main(["replay", str(run), "--findings", "--json"]) == 1
    replayed = [x for x in map(json.loads, capsys.readouterr().out.splitlines()) if x.get("event") == "finding"]
    for kind, line in (("gouge", GOUGE_LINE), ("rapid_into_stock", RAPID_LINE)):
        want = next(f for f in sim if f["kind"] == kind)
        for got in ([f for f in s.findings if f["kind"] == kind][0], [f for f in last.values() if f["kind"] == kind][0],
                    [f for f in stored if f["kind"] == kind][0], [f for f in replayed if f["kind"] == kind][0]):
            assert got["line"] == line and got["lines"] == want["lines"], (got, want)
            assert np.allclose(got["position"], want["position"], atol=1e-6), (got, want)
            for size in ("area", "volume", "depth"):
                if size in want:
                    assert abs(got[size] - want[size]) <= 0.02 * abs(want[size]) + 1e-6, (size, got, want)
        x, y, z = want["position"]
        assert f"at ({x:.2f}, {y:.2f}, {z:.2f})" in term.getvalue()
