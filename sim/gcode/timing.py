"""Cycle time as GRBL 1.1's planner would run a move table.

GRBL plans straight blocks (arcs are cut into chords within ``arc_tolerance``) with a
trapezoidal speed profile per block, a constant acceleration limited per axis, and a
junction speed from the junction deviation: ``v^2 = a * delta * sin(theta/2) /
(1 - sin(theta/2))``. Its planner holds only ``planner_blocks`` blocks, so a block must
be able to stop within the blocks queued after it. The machine stops completely at
dwells, tool changes, pauses, program end and spindle/coolant changes (GRBL
synchronises the buffer there).

Rotary axes are planned as grblHAL plans them: a block's length is the Euclidean norm of
all six axis changes, degrees of A B C counted as mm (LinuxCNC counts them so too for a
move that turns only rotaries), each axis capped by its own max rate and acceleration
(``max_rate`` / ``acceleration`` may give 3 values, X Y Z, the rotaries then taking
the largest of them, or 6, X Y Z A B C in deg/min and deg/s^2). A move that turns only
A takes the time A needs, not 0 s. Inverse time (G93, the ``inverse_time`` column,
1/min) sets a row's rate to ``inverse_time * its length``, so the row takes
``1 / inverse_time`` minutes at full speed, as GRBL does.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

from sim.gcode.linearize import linearize
from sim.gcode.moves import MoveKind


@dataclass(frozen=True)
class MachineLimits:
    """Per-axis limits, GRBL's defaults: ``$110..$112`` mm/min, ``$120..$122`` mm/s^2, ``$11``, ``$12``."""

    max_rate: tuple = (500.0, 500.0, 500.0)       # mm/min, X Y Z (+ A B C deg/min)
    acceleration: tuple = (10.0, 10.0, 10.0)      # mm/s^2, X Y Z (+ A B C deg/s^2)
    junction_deviation: float = 0.01              # mm
    arc_tolerance: float = 0.002                  # mm
    planner_blocks: int = 16                      # GRBL: 15 buffered + the one running
    extra: dict = field(default_factory=dict)

    @classmethod
    def from_mapping(cls, cfg) -> "MachineLimits":
        """From a dict with the field names (scalars apply to every axis)."""
        kw = {}
        for name in ("max_rate", "acceleration"):
            if name in cfg:
                v = cfg[name]
                kw[name] = tuple(float(x) for x in (v if np.ndim(v) else (v, v, v)))
        for name in ("junction_deviation", "arc_tolerance"):
            if name in cfg:
                kw[name] = float(cfg[name])
        if "planner_blocks" in cfg:
            kw["planner_blocks"] = int(cfg["planner_blocks"])
        return cls(**kw)


def six_axes(values) -> np.ndarray:
    """Per-axis limits (6,) X Y Z A B C from 3 (the rotaries take the largest) or 6 values."""
    v = np.asarray(values, np.float64).reshape(-1)
    if v.size == 6:
        return v
    if v.size != 3:
        raise ValueError(f"expected 3 (X Y Z) or 6 (X Y Z A B C) axis limits, got {v.size}")
    return np.concatenate([v, np.full(3, v.max())])


def _limit_by_axis(limit_vec: np.ndarray, unit: np.ndarray) -> np.ndarray:
    """GRBL ``limit_value_by_axis_maximum`` for every row: min over axes of limit/|u|."""
    with np.errstate(divide="ignore"):
        q = np.where(np.abs(unit) > 0, limit_vec[None, :] / np.abs(unit), np.inf)
    return q.min(axis=1)


@njit(cache=True)
def _plan(length, nominal, accel, junction_sqr, stop_before, horizon):
    """Entry speeds (squared) by GRBL's backward/forward passes; returns block times (min)."""
    n = length.shape[0]
    entry_max = np.empty(n)
    for i in range(n):
        if stop_before[i]:
            entry_max[i] = 0.0
        else:
            entry_max[i] = min(junction_sqr[i], nominal[i] * nominal[i], nominal[i - 1] * nominal[i - 1])
        # finite planner: must be able to stop within the blocks queued behind this one
        cap = 2.0 * accel[i] * horizon[i]
        if entry_max[i] > cap:
            entry_max[i] = cap
    entry = entry_max.copy()
    # backward pass (program ends at rest)
    nxt = 0.0
    for i in range(n - 1, -1, -1):
        v = nxt + 2.0 * accel[i] * length[i]
        if entry[i] > v:
            entry[i] = v
        nxt = entry[i]
    # forward pass
    for i in range(n - 1):
        v = entry[i] + 2.0 * accel[i] * length[i]
        if entry[i + 1] > v:
            entry[i + 1] = v
    times = np.zeros(n)
    for i in range(n):
        d = length[i]
        if d <= 0.0:
            continue
        a = accel[i]
        v0 = np.sqrt(entry[i])
        v1 = np.sqrt(entry[i + 1]) if i + 1 < n else 0.0
        vm = nominal[i]
        da = (vm * vm - v0 * v0) / (2.0 * a)
        dd = (vm * vm - v1 * v1) / (2.0 * a)
        if da + dd <= d:
            times[i] = (vm - v0) / a + (vm - v1) / a + (d - da - dd) / vm
        else:
            vp = np.sqrt(max((2.0 * a * d + v0 * v0 + v1 * v1) / 2.0, 0.0))
            times[i] = (vp - v0) / a + (vp - v1) / a
    return times


def cycle_time(moves: np.ndarray, machine=None) -> tuple[float, np.ndarray]:
    """Run time of a move table on a GRBL-planned machine.

    Parameters
    ----------
    moves : MOVE_DTYPE array (n,)
    machine : MachineLimits, a mapping of its fields, or None (GRBL defaults).

    Returns
    -------
    (total seconds, per-row seconds (n,) float64); dwells count their P seconds.
    """
    if machine is None:
        machine = MachineLimits()
    elif not isinstance(machine, MachineLimits):
        machine = MachineLimits.from_mapping(machine)
    n = len(moves)
    if n == 0:
        return 0.0, np.zeros(0)
    lin = linearize(moves, machine.arc_tolerance)
    # map each linear block back to its row
    is_arc = (moves["kind"] == MoveKind.ARC_CW) | (moves["kind"] == MoveKind.ARC_CCW)
    from sim.gcode.linearize import chord_counts
    from sim.gcode.arcs import arc_rows_geometry

    counts = np.ones(n, dtype=np.int64)
    if is_arc.any():
        r, _a, sw, _ax = arc_rows_geometry(moves[is_arc])
        counts[is_arc] = chord_counts(r, sw, machine.arc_tolerance)
    owner = np.repeat(np.arange(n), counts)
    delta = lin["end"] - lin["start"]  # X Y Z mm, A B C deg (as mm)
    length = np.linalg.norm(delta, axis=1)
    unit = np.divide(delta, length[:, None], out=np.zeros_like(delta), where=length[:, None] > 0)
    max_rate = six_axes(machine.max_rate)
    accel = six_axes(machine.acceleration) * 3600.0  # mm/min^2
    kinds = lin["kind"]
    moving = (length > 0) & np.isin(kinds, [MoveKind.RAPID, MoveKind.FEED, MoveKind.ARC_CW, MoveKind.ARC_CCW,
                                            MoveKind.PROBE])
    rate_cap = _limit_by_axis(max_rate, unit)
    programmed = lin["feed"]
    inverse = lin["inverse_time"]
    if np.any(inverse > 0):  # G93: the whole row (all its chords) in 1 / F minutes
        row_length = np.bincount(owner, weights=length, minlength=n)[owner]
        programmed = np.where(inverse > 0, inverse * row_length, programmed)
    feed = np.where(kinds == MoveKind.RAPID, rate_cap, np.minimum(programmed, rate_cap))
    feed = np.where(feed > 0, feed, rate_cap)
    acc = _limit_by_axis(accel, unit)
    # keep only moving blocks for planning; stops between them come from the others
    idx = np.flatnonzero(moving)
    per_block = np.zeros(len(lin))
    if len(idx):
        stop_rows = ~moving & np.isin(kinds, [MoveKind.DWELL, MoveKind.TOOL_CHANGE, MoveKind.PAUSE, MoveKind.END])
        stops_before = np.cumsum(stop_rows)[idx]
        stop_before = np.zeros(len(idx), dtype=np.bool_)
        stop_before[0] = True
        stop_before[1:] = stops_before[1:] != stops_before[:-1]
        sp = lin["spindle"][idx] * lin["spindle_dir"][idx]
        cool = lin["coolant"][idx]
        stop_before[1:] |= (sp[1:] != sp[:-1]) | (cool[1:] != cool[:-1])
        u = unit[idx]
        cos_t = np.ones(len(idx))
        cos_t[1:] = -np.einsum("ij,ij->i", u[1:], u[:-1])
        jun = np.full(len(idx), 1e30)
        mid = (cos_t > -0.999999) & (cos_t < 0.999999)
        ju = np.zeros_like(u)
        ju[1:] = u[1:] - u[:-1]
        jn = np.linalg.norm(ju, axis=1)
        ju = np.divide(ju, jn[:, None], out=np.zeros_like(ju), where=jn[:, None] > 0)
        jacc = _limit_by_axis(accel, ju)
        s2 = np.sqrt(np.clip(0.5 * (1.0 - cos_t), 0.0, 1.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            v2 = jacc * machine.junction_deviation * s2 / (1.0 - s2)
        jun = np.where(mid, v2, jun)
        jun = np.where(cos_t >= 0.999999, 0.0, jun)
        L = length[idx]
        # distance available to stop within the planner buffer behind each block
        csum = np.concatenate(([0.0], np.cumsum(L)))
        k = max(int(machine.planner_blocks) - 1, 1)
        hi = np.minimum(np.arange(len(idx)) + k, len(idx))
        horizon = csum[hi] - csum[np.arange(len(idx))]
        t = _plan(L, feed[idx], acc[idx], jun, stop_before, horizon)
        per_block[idx] = t * 60.0
    per_block += np.where(kinds == MoveKind.DWELL, lin["dwell"], 0.0)
    per_row = np.bincount(owner, weights=per_block, minlength=n)
    return float(per_row.sum()), per_row
