"""Run a :class:`~drivers.virtual.machine.VirtualMachine` against the wall clock."""

from __future__ import annotations

import math
import threading
import time
from typing import Callable

from drivers.virtual.machine import VirtualMachine


class RealTimeRunner:
    """A daemon thread that advances ``vm`` by wall-clock time x ``speed``.

    Every ``tick`` seconds (wall) it takes ``vm.lock``, calls ``on_tick(vm)`` if given
    (a program feeder fills the planner there) and advances the machine by the wall time
    elapsed since the last tick x ``speed``. Peers hold ``vm.lock`` while they touch the
    machine. ``vm.t0`` is set so that ``snapshot().t`` is ``time.monotonic()`` at speed 1.

    Parameters
    ----------
    vm : VirtualMachine
    speed : float, simulated seconds per wall second (> 0)
    tick : float, wall seconds between steps (GRBL's stepper segments are ~8 ms)
    on_tick : callable(vm) or None, called under the lock before each step
    """

    def __init__(self, vm: VirtualMachine, speed: float = 1.0, tick: float = 0.004,
                 on_tick: Callable[[VirtualMachine], None] | None = None):
        if not 0 < speed < math.inf:
            raise ValueError(f"speed must be a finite number > 0, got {speed}")
        self.vm = vm
        self.speed = float(speed)
        self.tick = float(tick)
        self.on_tick = on_tick
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None

    def start(self) -> "RealTimeRunner":
        if self._thread is not None:
            return self
        self._stop.clear()
        with self.vm.lock:
            if self.speed == 1.0:
                self.vm.t0 = time.monotonic() - self.vm.time
        self._thread = threading.Thread(target=self._run, name="virtual-machine", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _run(self) -> None:
        last = time.monotonic()
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                with self.vm.lock:
                    if self.on_tick is not None:
                        self.on_tick(self.vm)
                    self.vm.advance((now - last) * self.speed)
                last = now
                self._stop.wait(self.tick)  # pacing the clock, not synchronising
        except BaseException as exc:  # surfaced to whoever owns the runner
            self.error = exc

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()
        return False
