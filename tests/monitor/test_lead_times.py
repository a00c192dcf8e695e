"""Lead times from the machine's own limits (issue 12).

The GRBL peer's machine runs at 500 mm/min and 20 mm/s^2 (not the planner's brisk
defaults); the monitor, attached over a pty, must predict the planted findings of the
bundled example with lead times within 10 % of when the machine really got to their lines.
Both times are the machine's simulated clock: the machine here advances a fixed simulated
step per tick, so a loaded test machine slows the run down but changes no figure.
"""

from __future__ import annotations

import argparse
import json
import threading
import time

import numpy as np
import pytest

from drivers.grbl.peer import GrblPeer
from drivers.grbl.protocol import settings_limits
from drivers.state import ControllerLimits
from drivers.virtual.controller import ProgramFeeder
from drivers.virtual.machine import MachineConfig, VirtualMachine
from monitor.commands.dry_run import EXAMPLE_JOB
from monitor.commands.live import run_session
from monitor.job import load_job, parse_job_text
from monitor.machine import in_force
from monitor.session import Session, load_moves

GOUGE_LINE, RAPID_LINE = 22, 36
#: the slow machine: GRBL's rates of a small hobby mill
SLOW = MachineConfig(max_rate=(500.0,) * 3, accel=(20.0,) * 3, soft_limits=False, travel_min=None,
                     travel_max=None)
#: simulated seconds the test's machine advances per tick (a tick waits ~2 ms: ~10x)
SIM_STEP = 0.02


@pytest.fixture(scope="module")
def example():
    job = load_job(EXAMPLE_JOB)
    moves, _ = load_moves(job)
    return job, moves


class SteppedMachine:
    """Advances ``vm`` by :data:`SIM_STEP` simulated seconds per tick on a thread, feeding
    the program into its planner once :meth:`go` is called (as a sender streams it), and
    notes when the machine first ran each source line (simulated s)."""

    def __init__(self, vm: VirtualMachine, moves: np.ndarray):
        self.vm = vm
        self.feeder = ProgramFeeder(moves)
        self.feeding = threading.Event()
        self.reached: dict[int, float] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> "SteppedMachine":
        self._thread.start()
        return self

    def go(self) -> None:
        self.feeding.set()

    def done(self) -> bool:
        with self.vm.lock:
            return self.feeder.all_queued and not self.vm.busy

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)

    def _run(self) -> None:
        while not self._stop.is_set():
            with self.vm.lock:
                if self.feeding.is_set():
                    self.feeder(self.vm)
                self.vm.advance(SIM_STEP)
                line = self.vm.snapshot().line
                if line is not None and line not in self.reached:
                    # the line began within the step just run
                    self.reached[line] = self.vm.time - SIM_STEP / 2
            self._stop.wait(0.002)  # pacing the machine, not synchronising


def _logged_reports(peer: GrblPeer, vm: VirtualMachine) -> list[tuple[float, float]]:
    """Log ``(wall monotonic, machine time)`` of every status report the peer makes."""
    log: list[tuple[float, float]] = []
    make = peer.status_report

    def status_report() -> str:
        with vm.lock:
            text = make()
            log.append((time.monotonic(), vm.time))
        return text
    peer.status_report = status_report
    return log


def _machine_time_at(log, t: float) -> float:
    """Machine time of the report a state stamped ``t`` (wall, at arrival) was read from:
    the last one made before it arrived (the next is asked only after it arrived)."""
    walls = np.array([w for w, _ in log])
    k = int(np.searchsorted(walls, t, side="right")) - 1
    assert k >= 0, "no report before the state"
    return log[k][1]


def test_lead_times_on_a_slow_grbl_are_the_machines(example, tmp_path, capsys):
    """Reproduces issue 12: with no [machine] the planner assumed 5000 mm/min and the
    lead times were a third of the real ones; the driver's $$ now times the program."""
    job, moves = example
    vm = VirtualMachine(SLOW, position=moves["start"][0])
    peer = GrblPeer(vm, run=False)
    reports = _logged_reports(peer, vm)
    machine = SteppedMachine(vm, moves).start()
    from drivers.registry import open_controller

    controller = open_controller(f"grbl://{peer.serve_pty()}")
    # the program starts once the driver's handshake ($I $$ $# $G, asked while Idle) is over
    sender = threading.Thread(target=lambda: _go_after_handshake(peer, machine), daemon=True)
    sender.start()
    args = argparse.Namespace(run=str(tmp_path / "run.sqlite"), json=True, quiet=False, view=False, frames=None)
    try:
        code = run_session(args, job, controller, done=machine.done)
    finally:
        machine.stop()
        peer.close()
    out = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert code == 1
    said = [x for x in out if x["event"] == "machine"]
    assert said and said[0]["sources"] == {"max_rate": "controller", "acceleration": "controller",
                                           "junction_deviation": "controller"}, said
    assert said[0]["max_rate"] == [500.0] * 3 and "GRBL $$" in said[0]["message"]
    findings = {x["line"]: x for x in out if x["event"] == "finding"}
    assert {GOUGE_LINE, RAPID_LINE} <= set(findings), out
    for line in (GOUGE_LINE, RAPID_LINE):
        f = findings[line]
        measured = machine.reached[line] - _machine_time_at(reports, f["t"])
        assert measured > 1.0, (line, measured)
        assert abs(f["lead_time_s"] - measured) <= 0.1 * measured, (line, f["lead_time_s"], measured)
    summary = out[-1]
    assert summary["program_s"] == pytest.approx(vm.time, rel=0.1)


def _go_after_handshake(peer: GrblPeer, machine: SteppedMachine, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while "$G" not in peer.received_lines and time.monotonic() < deadline:
        time.sleep(0.01)  # polling a list the peer appends to; no event exists for it
    machine.go()
