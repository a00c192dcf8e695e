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
from drivers.state import ControllerLimits
from drivers.virtual.controller import ProgramFeeder
from drivers.virtual.machine import VirtualMachine
from drivers.virtual.machine_config import MachineConfig
from monitor.commands.dry_run import EXAMPLE_JOB
from monitor.commands.live import run_session
from monitor.job import load_job, parse_job_text
from monitor.machine import in_force
from monitor.program_moves import load_moves
from monitor.session import Session

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
    said = [out[0]["machine"]]  # the start record says the limits in force
    assert said[0]["sources"] == {"max_rate": "controller", "acceleration": "controller",
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


GRBL_SLOW = ControllerLimits(max_rate=(500.0,) * 3, acceleration=(20.0,) * 3, junction_deviation=0.01,
                             travel=((-200.0, 0.0),) * 3, soft_limits=True, source="GRBL $$ on /dev/ttyUSB0")


def test_job_machine_overrides_the_controller_field_by_field():
    job = parse_job_text("[machine]\nacceleration = 40\n")
    assert job.machine == {"acceleration": (40.0, 40.0, 40.0)}  # only what the job says
    got = in_force(job.machine, GRBL_SLOW, job.limits)
    assert got.machine == {"max_rate": (500.0,) * 3, "acceleration": (40.0, 40.0, 40.0),
                           "junction_deviation": 0.01}
    assert got.sources == {"max_rate": "controller", "acceleration": "job", "junction_deviation": "controller"}
    line = got.describe()
    assert "max rate X500 Y500 Z500 mm/min" in line and "(from GRBL $$ on /dev/ttyUSB0" in line
    assert "acceleration X40 Y40 Z40 mm/s^2 (from job [machine])" in line
    # soft limits on: the controller's travel is checked unless the job gives [limits]
    assert got.travel == {"X": (-200.0, 0.0), "Y": (-200.0, 0.0), "Z": (-200.0, 0.0)}
    assert "travel limits X[-200, 0]" in line
    own = in_force(None, GRBL_SLOW, {"X": (-50.0, 0.0)})
    assert own.travel == {"X": (-50.0, 0.0)} and own.travel_source == "job"
    # nothing from the controller: the defaults, said as such
    dflt = in_force(None, None)
    assert set(dflt.sources.values()) == {"default"} and "dexmon default" in dflt.describe()


def test_limits_learned_after_the_session_was_built_retime_it_in_place(example, tmp_path):
    """GRBL reads $$ only when Idle: attached to a busy machine the session starts on the
    defaults and is retimed between two steps when the limits arrive."""
    from drivers.state import MachineState, RunState
    from monitor.runfile import RunWriter
    from monitor.runreader import RunReader

    job, moves = example
    _, program = load_moves(job)
    with RunWriter(tmp_path / "r.sqlite") as w:
        s = Session(job, moves, program=program, run=w)
        brisk = s.path.duration
        assert s.in_force.sources["max_rate"] == "default"
        asked, said = [], []

        def limits():
            asked.append(1)
            return None if len(asked) < 3 else GRBL_SLOW
        s.limits_from, s.on_limits = limits, said.append
        k = len(s.path) // 3
        where = (s.path.p0[k] + s.path.p1[k]) / 2
        for i in range(4):
            s.step(MachineState(t=float(i), mpos=tuple(where), state=RunState.RUN))
            if i == 1:
                before = s.last_sync
        assert len(asked) == 3 and said == [s.in_force] and s.limits_from is None
        assert s.path.duration == pytest.approx(125.9, rel=0.01) and brisk < s.path.duration / 2
        # the progress followed stays at the same place on the path, now in the slow timing
        assert s.sync.progress > before.progress
        assert np.allclose(s.path.point_at(s.sync.progress), s.path.point_at(s.last_sync.progress))
        assert s.sync_path.t1 is s.path.t1  # sync and look-ahead read the same times
        assert s.lookahead.limits == GRBL_SLOW.travel_limits()
    r = RunReader(tmp_path / "r.sqlite")
    assert r.get_array("row_seconds").sum() == pytest.approx(s.path.duration)
    assert json.loads(r.meta()["machine"])["sources"]["max_rate"] == "controller"


def test_report_machine_time_is_the_controllers_at_any_speed(tmp_path):
    """'machine time recorded' is the controller's clock: a dry run at --speed 10 and at
    --speed 50 records the same machine time, and the program time agrees with it. The
    program starts at the first poll, and the run ends at the first poll that finds it
    done: each figure may be one poll late (in machine time), never more."""
    from monitor.cli import main
    from monitor.commands.report import cycle_time
    from monitor.runreader import RunReader
    from monitor.trace_io import RunView

    got, last_poll = {}, {}
    for speed in (10, 50):
        run = tmp_path / f"r{speed}.sqlite"
        assert main(["dry-run", "--speed", str(speed), "--quiet", "--run", str(run)]) == 1
        with RunView(run) as view:
            got[speed] = cycle_time(view)
        t = RunReader(run).states()["t"]
        last_poll[speed] = float(np.diff(t)[-5:].max())  # machine s between the last polls
    assert abs(got[10]["machine_s"] - got[50]["machine_s"]) <= last_poll[10] + last_poll[50] + 0.1
    for speed in (10, 50):
        program = got[speed]["program_s"]
        assert program * 0.97 <= got[speed]["machine_s"] <= program * 1.03 + last_poll[speed], (speed, got)
