"""``VirtualController``: a whole controller in-process, executing a program on a
:class:`~drivers.virtual.machine.VirtualMachine` in real time, N x faster, or stepped.

URL form (see :mod:`drivers.registry`)::

    virtual:///abs/path/job.nc?speed=10&rate=20&faults=drop:0.05,alarm=30:1&clock=sim
    virtual://relative/job.nc?speed=4
    virtual://?rate=50            (no program: an idle machine)

Query keys: ``speed`` (simulated s per wall s, or per poll period with ``clock=sim``),
``rate`` (poll rate, Hz), ``clock`` (``wall`` or ``sim``), ``faults`` (see
:mod:`drivers.virtual.faults`), ``max_rate``/``accel`` (comma lists per axis, mm/min and
mm/s^2), ``travel`` (the GRBL travel per axis, giving soft limits ``[-travel, 0]``;
default ``none``: no soft limits, so programs run as written); for the G-code
interpreter: ``dialect`` (``linuxcnc``/``grbl``), ``var`` (a LinuxCNC .var file: work
offsets G54..G59.3 ...), ``machine_units`` (``mm``/``inch``: of the .var file and
``tool_table``), ``subroutine_path`` (folders, ``os.pathsep``-separated) and
``block_delete`` (``on``/``off``, default off: the switch that skips '/' lines), e.g.
``virtual:///jobs/mmount.ngc?var=/jobs/mmount.var&machine_units=inch``. The machine
reports as WCO the offset of the row it executes (a G55 row: its G55 offset).
"""

from __future__ import annotations

import math
import threading
from dataclasses import replace
from pathlib import Path
from urllib.parse import parse_qs, unquote, urlsplit

import numpy as np

from drivers.errors import ConnectionLost, DriverError
from drivers.state import Controller, Gap, LinkKind, MachineState, RunState, implausible, stale_state
from drivers.virtual.faults import REPLY_BAD, REPLY_DROP, REPLY_GARBLE, REPLY_LATE, FaultInjector, FaultPlan
from drivers.virtual.machine import MachineLocked, VirtualMachine
from drivers.virtual.machine_config import MachineConfig
from drivers.virtual.runner import RealTimeRunner
from sim.gcode.moves import MOVE_DTYPE


def load_moves(program, **interpreter) -> tuple[np.ndarray, str]:
    """Move table (MOVE_DTYPE) and a name from a path, a ``Program`` or a move table.

    ``interpreter``: keywords for ``sim.gcode.load_program`` when ``program`` is a path
    (``dialect``, ``var_file``, ``machine_units``, ``tool_table``, ``subroutine_path``, ``block_delete``)."""
    if program is None:
        from sim.gcode.moves import empty_moves

        return empty_moves(0), "(no program)"
    if isinstance(program, np.ndarray):
        if program.dtype != MOVE_DTYPE:
            raise DriverError(f"virtual controller: move table has dtype {program.dtype}, expected MOVE_DTYPE")
        return program, "(move table)"
    if isinstance(program, (str, Path)):
        try:
            from sim.gcode import load_program  # the one allowed drivers -> sim.gcode arrow
        except ImportError as exc:
            raise DriverError(f"virtual controller: G-code interpreter not available ({exc})") from exc
        return np.asarray(load_program(program, **interpreter).moves), str(program)
    moves = getattr(program, "moves", None)
    if moves is None:
        raise DriverError(f"virtual controller: cannot run {type(program).__name__}; expected a path, Program or move table")
    return np.asarray(moves), getattr(program, "name", "(program)")


class ProgramFeeder:
    """Keeps a machine's planner filled from a move table, as a sender streams a job.

    Call it (under ``vm.lock``) before each step of the machine, e.g. as a
    :class:`RealTimeRunner` ``on_tick``. ``faults`` fires its scheduled alarm.
    """

    def __init__(self, moves: np.ndarray, faults: FaultInjector | None = None):
        self.moves = moves
        self.faults = faults
        self.next_row = 0

    @property
    def all_queued(self) -> bool:
        return self.next_row >= len(self.moves)

    def __call__(self, vm: VirtualMachine) -> None:
        if self.faults is not None:
            code = self.faults.due_alarm(vm.time)
            if code is not None:
                vm.raise_alarm(code)
        if vm.state in (RunState.ALARM, RunState.JOG):
            return
        free = vm.planner_free()
        if free and self.next_row < len(self.moves):
            chunk = self.moves[self.next_row:self.next_row + free]
            try:
                vm.queue(chunk)
            except MachineLocked:
                return
            self.next_row += len(chunk)


class VirtualController(Controller):
    """A controller that runs ``program`` on a simulated machine.

    Parameters
    ----------
    program : path, ``sim.gcode`` Program, MOVE_DTYPE array, or None (idle machine)
    speed : float, time scale (> 0)
    rate : float, poll rate (Hz) used by :meth:`states` and, with ``clock="sim"``, the
        simulated step of each :meth:`poll` (``speed / rate`` seconds)
    clock : ``"wall"`` (a :class:`RealTimeRunner` thread) or ``"sim"`` (deterministic:
        time moves only when polled)
    config : MachineConfig
    faults : FaultPlan, spec string or None
    interpreter : keywords for ``sim.gcode.load_program`` when ``program`` is a path
        (``var_file``, ``machine_units``, ``dialect``, ``tool_table``, ``subroutine_path``)
    """

    def __init__(self, program=None, speed: float = 1.0, rate: float = 20.0, clock: str = "wall",
                 config: MachineConfig | None = None, faults=None, url: str = "", interpreter: dict | None = None):
        if clock not in ("wall", "sim"):
            raise DriverError(f"virtual controller: clock={clock!r}; expected 'wall' or 'sim'")
        if not (0 < speed < math.inf and 0 < rate < math.inf):
            raise DriverError(f"virtual controller: speed and rate must be finite numbers > 0 "
                              f"(got speed={speed}, rate={rate})")
        self.moves, self.name = load_moves(program, **(interpreter or {}))
        self.speed = float(speed)
        self.rate = float(rate)
        self.clock = clock
        # dry runs take programs as written (positive work coordinates): no soft limits unless asked
        self.config = config or MachineConfig(travel_min=None, travel_max=None)
        self.faults = FaultInjector(faults if isinstance(faults, FaultPlan) else FaultPlan.parse(faults))
        self.url = url or f"virtual://{self.name}"
        self.vm: VirtualMachine | None = None
        self._runner: RealTimeRunner | None = None
        self._feeder = ProgramFeeder(self.moves, self.faults)
        self._connected = False
        self._started = False  # the program is fed from the first poll on
        self._late_wait = threading.Event()
        self.events: list[tuple[float, str, object]] = []
        self.gaps: list[Gap] = []
        self._last: MachineState | None = None   # the last fresh state
        self._lost: tuple[float, str, int] | None = None  # outage: (t lost, why, polls missed)

    # ------------------------------------------------------------------ lifecycle
    def connect(self) -> None:
        start = self.moves["start"][0] if len(self.moves) else None
        self.vm = VirtualMachine(self.config, position=start)
        if len(self.moves):  # a controller reports its work offset before the program runs
            self.vm.set_wco(self.moves["wco"][0])
        self.vm.on_event = self._record
        self._feeder = ProgramFeeder(self.moves, self.faults)
        self.vm.refill = self._tick  # fed as blocks complete, however long a poll's step
        self._last, self._lost = None, None
        self._started = False
        self._connected = True
        if self.clock == "wall":
            self._runner = RealTimeRunner(self.vm, speed=self.speed, on_tick=self._tick).start()
        else:
            self._tick(self.vm)

    def close(self) -> None:
        self._connected = False
        self._late_wait.set()
        if self._runner is not None:
            self._runner.stop()
            self._runner = None

    @property
    def done(self) -> bool:
        """True once every row was queued and the machine stands idle (or in alarm)."""
        vm = self.vm
        if vm is None:
            return False
        with vm.lock:
            if vm.state == RunState.ALARM:
                return True
            return self._feeder.all_queued and not vm.busy

    def machine_limits(self):
        """The configured machine's limits (known before :meth:`connect`)."""
        return self.config.limits(f"virtual machine {self.url}")

    # ------------------------------------------------------------------ polling
    def poll(self) -> MachineState:
        """The machine's state now, as the contract wants it (:class:`Controller`): the
        injected faults give DISCONNECTED (link down, or the machine's thread stopped),
        MISSED (reply dropped or garbled) and BAD (non-finite numbers) states at the
        last known position, never an exception once connected."""
        if not self._connected or self.vm is None:
            raise ConnectionLost(f"{self.url}: not connected")
        vm = self.vm
        first = not self._started
        if first:
            with vm.lock:
                self._started = True
        if self._runner is not None and self._runner.error is not None:
            return self._link_down(self._now(), f"virtual machine stopped: {self._runner.error}")
        if self.clock == "sim":
            with vm.lock:
                self._tick(vm)
                # a poll reports the step since the one before; the first has none and sees
                # the machine as it stands at connect, as the wall clock's first poll does
                # (a step of speed / rate longer than the program ended it before the
                # monitor saw it start: nothing was cut or checked)
                if not first:
                    vm.advance(self.speed / self.rate)
        with vm.lock:
            sim_t, t = vm.time, self._now()
        if self.faults.disconnected(sim_t):
            return self._link_down(t, f"link down (fault injection at t={self.faults.plan.disconnect:g} s)")
        if self._lost is not None:
            self._link_back(t)
        fault = self.faults.reply_fault()
        if fault == REPLY_DROP:
            return self._stale(RunState.MISSED, t, "no reply to the status request (fault injection)")
        if fault == REPLY_LATE:
            late = self.faults.plan.late_s
            if self.clock == "sim":
                with vm.lock:
                    vm.advance(late * self.speed)
            else:
                self._late_wait.wait(late)  # the reply is late: the caller waits with it
        with vm.lock:
            state = vm.snapshot()
        if fault == REPLY_GARBLE:
            raw = self.faults.garble_bytes(_status_text(state).encode())
            return self._stale(RunState.MISSED, state.t, f"garbled reply {raw!r}: expected a status report")
        if fault == REPLY_BAD:
            state = replace(state, mpos=(math.nan,) + state.mpos[1:])
        why = implausible(state)
        if why is not None:
            text = _status_text(state).strip()
            self._link_event(LinkKind.BAD, f"{self.url}: {why}: {text}", raw=text, t=state.t)
            return self._stale(RunState.BAD, state.t, f"{why}: {text}")
        self._last = state
        return state

    def _now(self) -> float:
        """The machine's clock now (s): what a fresh snapshot would say. Under vm.lock."""
        return self.vm.t0 + self.vm.time

    def _stale(self, state: RunState, t: float, raw: str) -> MachineState:
        return stale_state(self._last, state, max(t, self._last.t if self._last else t), raw)

    def _link_down(self, t: float, reason: str) -> MachineState:
        """A DISCONNECTED state; the first of an outage starts it and says so."""
        if self._lost is None:
            self._lost = (t, reason, 0)
            self._link_event(LinkKind.LOST, f"{self.url}: {reason}", t=t)
        t_lost, why, polls = self._lost
        self._lost = (t_lost, why, polls + 1)
        return self._stale(RunState.DISCONNECTED, t, reason)

    def _link_back(self, t: float) -> None:
        """The link is back: the outage becomes a :class:`Gap`; with ``reset=1`` the
        controller restarted meanwhile and comes back at 0 in alarm."""
        t_lost, why, polls = self._lost
        self._lost = None
        came_back = ""
        if self.faults.plan.reset:
            with self.vm.lock:
                self.vm.power_cycle()
            came_back = "reset: position lost, in alarm"
        gap = Gap(t_lost, t, why, polls_missed=polls, came_back=came_back)
        self.gaps.append(gap)
        self._link_event(LinkKind.BACK, f"{self.url}: link back after {gap.seconds:.1f} s "
                                        f"({polls} polls missed)", gap=gap, t=t)
        if came_back:
            self._link_event(LinkKind.RESET, f"{self.url}: controller came back reset ({came_back})", t=t)

    # ------------------------------------------------------------------ commands
    def feed_hold(self) -> None:
        with self._machine() as vm:
            vm.feed_hold()

    def resume(self) -> None:
        with self._machine() as vm:
            vm.resume()

    def _machine(self):
        if self.vm is None or not self._connected:
            raise ConnectionLost(f"{self.url}: not connected")
        vm = self.vm

        class _Held:
            def __enter__(self_inner):
                vm.lock.acquire()
                return vm

            def __exit__(self_inner, *exc):
                vm.lock.release()
                return False

        return _Held()

    # ------------------------------------------------------------------ internals
    def _tick(self, vm: VirtualMachine) -> None:
        """Feed program rows into free planner blocks; fire a scheduled alarm. Under vm.lock.
        The program starts at the first poll, as an operator starts the cycle once the
        monitor is ready: however long the monitor takes between connect and its first
        poll, it sees the whole program, and the machine time it records is the same
        at any speed."""
        if self._started:
            self._feeder(vm)

    def _record(self, name: str, payload) -> None:
        if name == "block_done":
            payload = int(payload["line"])
        self.events.append((self.vm.time if self.vm else 0.0, name, payload))
        if len(self.events) > 10000:
            del self.events[:5000]


def _status_text(st: MachineState) -> str:
    """The state as a GRBL report (for garbled and bad replies): X Y Z, and A B C as
    grblHAL sends them when a rotary is off zero (a bad A must show in the text)."""
    axes = st.mpos if any(v != 0.0 for v in st.mpos[3:]) else st.mpos[:3]
    pos = ",".join(f"{v:.3f}" for v in axes)
    return f"<{st.state.value}|MPos:{pos}|FS:{st.feed:.0f},{st.spindle:.0f}>\r\n"


def _floats(text: str, key: str) -> tuple[float, ...]:
    try:
        return tuple(float(v) for v in text.split(","))
    except ValueError:
        raise DriverError(f"virtual URL: {key}={text!r}: expected comma-separated numbers") from None


def from_url(url: str) -> VirtualController:
    """Build a :class:`VirtualController` from a ``virtual://`` URL (see module doc)."""
    parts = urlsplit(url)
    path = unquote(parts.netloc + parts.path)
    query = {k: v[-1] for k, v in parse_qs(parts.query, keep_blank_values=True).items()}
    known = {"speed", "rate", "clock", "faults", "max_rate", "accel", "travel", "dialect", "var", "machine_units",
             "tool_table", "subroutine_path", "block_delete"}
    unknown = sorted(set(query) - known)
    if unknown:
        raise DriverError(f"virtual URL {url!r}: unknown option {unknown[0]!r}; expected one of {', '.join(sorted(known))}")
    try:
        speed = float(query.get("speed", 1.0))
        rate = float(query.get("rate", 20.0))
    except ValueError:
        raise DriverError(f"virtual URL {url!r}: speed and rate must be numbers") from None
    cfg_kw: dict = {"travel_min": None, "travel_max": None}
    if "max_rate" in query:
        cfg_kw["max_rate"] = _floats(query["max_rate"], "max_rate")
    if "accel" in query:
        cfg_kw["accel"] = _floats(query["accel"], "accel")
    if "travel" in query:
        if query["travel"].lower() == "none":
            cfg_kw.update(travel_min=None, travel_max=None)
        else:
            tr = _floats(query["travel"], "travel")
            cfg_kw.update(travel_min=tuple(-abs(v) for v in tr), travel_max=tuple(0.0 for _ in tr))
    if "accel" in cfg_kw and "max_rate" not in cfg_kw or "max_rate" in cfg_kw and "accel" not in cfg_kw:
        n = len(cfg_kw.get("accel", cfg_kw.get("max_rate")))
        cfg_kw.setdefault("max_rate", (500.0,) * n)
        cfg_kw.setdefault("accel", (10.0,) * n)
    try:
        config = MachineConfig(**cfg_kw)
    except ValueError as exc:
        raise DriverError(f"virtual URL {url!r}: {exc}") from None
    program = path or None
    if program is not None and not Path(program).is_file():
        raise DriverError(f"virtual URL {url!r}: program file {program!r} not found")
    interpreter = _interpreter_options(url, query)
    if interpreter and program is None:
        raise DriverError(f"virtual URL {url!r}: {', '.join(sorted(interpreter))} given but no program")
    return VirtualController(program, speed=speed, rate=rate, clock=query.get("clock", "wall"),
                             config=config, faults=query.get("faults"), url=url, interpreter=interpreter)


def _interpreter_options(url: str, query: dict) -> dict:
    """``load_program`` keywords from the URL's ``dialect``, ``var``, ``machine_units``,
    ``tool_table``, ``subroutine_path`` and ``block_delete``; DriverError naming the option that is wrong."""
    import os

    kw: dict = {}
    if "dialect" in query:
        if query["dialect"] not in ("linuxcnc", "grbl"):
            raise DriverError(f"virtual URL {url!r}: dialect={query['dialect']!r}; expected linuxcnc or grbl")
        kw["dialect"] = query["dialect"]
    if "machine_units" in query:
        if query["machine_units"] not in ("mm", "inch"):
            raise DriverError(f"virtual URL {url!r}: machine_units={query['machine_units']!r}; expected mm or inch")
        kw["machine_units"] = query["machine_units"]
    for key, name in (("var", "var_file"), ("tool_table", "tool_table")):
        if key in query:
            if not Path(query[key]).is_file():
                raise DriverError(f"virtual URL {url!r}: {key} file {query[key]!r} not found")
            kw[name] = query[key]
    if "subroutine_path" in query:
        dirs = [d for d in query["subroutine_path"].split(os.pathsep) if d]
        for d in dirs:
            if not Path(d).is_dir():
                raise DriverError(f"virtual URL {url!r}: subroutine_path folder {d!r} not found")
        kw["subroutine_path"] = dirs
    if "block_delete" in query:
        switch = {"on": True, "1": True, "true": True, "off": False, "0": False, "false": False}
        if query["block_delete"].lower() not in switch:
            raise DriverError(f"virtual URL {url!r}: block_delete={query['block_delete']!r}; expected on or off")
        kw["block_delete"] = switch[query["block_delete"].lower()]
    return kw
