"""State-change latency harness shared by the driver benchmarks (GRBL, Modbus).

A :class:`XStepper` moves a virtual machine's X at random instants and stamps each
change; :func:`watch_x` polls a connected controller's ``states()`` for a while; and
:func:`poll_summary` turns both into the JSON fields the benchmarks print.
"""

from __future__ import annotations

import random
import threading
import time

import numpy as np


class XStepper:
    """Steps ``vm.position[0]`` by -1 mm every 50-150 ms (seeded) from its own thread.

    ``changes`` holds ``(t_change, new_x)`` per step, ``t_change`` being
    ``time.monotonic()`` taken under ``vm.lock`` together with the move, so a polled
    state can never show a change before its stamp. Usable as a context manager.
    """

    def __init__(self, vm, seed: int = 1):
        self.vm = vm
        self.changes: list[tuple[float, float]] = []
        self._stop = threading.Event()
        self._rng = random.Random(seed)
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        x = 0.0
        while not self._stop.wait(self._rng.uniform(0.05, 0.15)):
            x -= 1.0
            with self.vm.lock:
                self.vm.position[0] = x
                self.changes.append((time.monotonic(), x))

    def start(self) -> "XStepper":
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()

    def __enter__(self) -> "XStepper":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def watch_x(controller, seconds: float, t_start: float) -> list[tuple[float, float]]:
    """``(state.t, state.mpos[0])`` of every state ``controller.states()`` yields, up to
    and including the first stamped ``seconds`` (s) after ``t_start`` (monotonic s)."""
    seen: list[tuple[float, float]] = []
    for st in controller.states():
        seen.append((st.t, st.mpos[0]))
        if st.t - t_start >= seconds:
            break
    return seen


def change_latency_ms(seen, changes) -> np.ndarray:
    """Latency (ms, float64 (k,)) of each change: the stamp of the first polled state at
    or after the change whose X shows it (X at or below the new X), minus the change's
    stamp. ``seen``: ``(t, x)`` polled states; ``changes``: ``(t_change, new_x)``.
    Changes no polled state shows are left out."""
    ts = np.array([s[0] for s in seen])
    xs = np.array([s[1] for s in seen])
    lat = []
    for t_change, x in changes:
        idx = np.nonzero((xs <= x + 1e-6) & (ts >= t_change))[0]
        if len(idx):
            lat.append(ts[idx[0]] - t_change)
    return np.array(lat) * 1e3


def poll_summary(seen, changes, request_s) -> dict:
    """The benchmarks' shared JSON fields: achieved poll rate (Hz) over ``seen``, counts,
    change latency p50/p99/max (ms, 2 decimals) and the back-to-back request time
    ``request_s`` (s each) as p50/p99 (ms, 3 decimals)."""
    elapsed = seen[-1][0] - seen[0][0]
    lat_ms = change_latency_ms(seen, changes)
    return {
        "achieved_hz": round((len(seen) - 1) / elapsed, 2),
        "polls": len(seen),
        "changes": len(changes),
        "latency_ms_p50": round(float(np.percentile(lat_ms, 50)), 2),
        "latency_ms_p99": round(float(np.percentile(lat_ms, 99)), 2),
        "latency_ms_max": round(float(lat_ms.max()), 2),
        "request_ms_p50": round(float(np.percentile(request_s, 50)) * 1e3, 3),
        "request_ms_p99": round(float(np.percentile(request_s, 99)) * 1e3, 3),
    }
