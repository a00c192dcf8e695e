"""Machine and work coordinates of a job's program, its travel limits and their findings.

Everything the checks see is in the job's *work coordinates*: those of the job's work
system (G54 unless ``[program] work_system`` says otherwise), in which stock, fixtures and
design are written. The move table is turned into a table of tool tips in that frame,
``tip_machine - reference_wco`` (:func:`work_moves`, :func:`reference_wco`), so the
stations of a multi-fixture program (G55, G56 ... from a .var file) land where their
offsets put them relative to the job's system. Travel limits are machine coordinates of
the controlled point; they are shifted into work coordinates by the work offset in force
(:func:`limits_in_work`) and the findings shifted back (:func:`finding_to_machine`).
"""

from __future__ import annotations

import math

import numpy as np

from monitor.job import Job, JobError, work_system_index
from sim.checks.findings import Finding
from sim.errors import InputError
from sim.gcode.moves import as_move_table, work_end, work_start

#: row shifts below this are rounding of summed offsets, mm
SHIFT_EPS = 1e-9


def work_moves(moves: np.ndarray, reference_wco=None) -> np.ndarray:
    """A copy of a move table with ``start/end`` replaced by tip positions in one work frame.

    ``reference_wco`` (6,) mm: the offset (machine - work) of the job's work system
    (:func:`reference_wco`); each row's tip is placed at ``tip_machine - reference_wco``, so
    a G55 row lands at its G55 offset relative to G54 and G92 shifts stay where they put
    the tool. None: each row in its *own* work system (``end - wco``, every fixture of a
    multi-fixture program at work zero) -- what the controller reports as work position.
    ``tool_length`` becomes 0 (the table is the tip's), arc centres move with their row and
    ``wco`` becomes 0. Tables written before the ``wco`` column (old run files) are
    converted first.
    """
    moves = as_move_table(moves)
    out = moves.copy()
    shift = -np.asarray(moves["wco"][:, :3], np.float64)
    shift[:, 2] += moves["tool_length"]  # machine Z of the controlled point = tip + length
    out["start"] = work_start(moves)
    out["end"] = work_end(moves)
    out["center"] = moves["center"] + shift
    if reference_wco is not None:
        rs = row_shifts(moves, reference_wco)
        moved = np.any(rs != 0.0, axis=1)
        if moved.any():  # a single-system program stays bit for bit what it was
            out["start"][moved, :3] += rs[moved]
            out["end"][moved, :3] += rs[moved]
            out["center"][moved] += rs[moved]
    out["tool_length"] = 0.0
    out["wco"] = 0.0
    return out


def reference_wco(job: Job) -> np.ndarray:
    """The interpreter's offset (machine - work, (6,) mm) of the job's work system at the
    program start: its G5x entry from the job's .var file (in the job's machine units);
    zeros without a var file (the interpreter's offsets all start at 0)."""
    from sim.gcode import Interpreter
    from sim.gcode.varfile import read_var_file

    out = np.zeros(6)
    if job.var_file is None:
        return out
    try:
        params = read_var_file(job.var_file)
        it = Interpreter(dialect=job.dialect, machine_units=job.machine_units, var_params=params,
                         filename=str(job.var_file))
    except InputError as exc:
        raise JobError(f"[program] var: {exc}", str(job.source or "command line")) from None
    out[:] = it.g5x[work_system_index(job.work_system)]
    return out


def row_shifts(moves: np.ndarray, reference) -> np.ndarray:
    """Per row, what moves a tip from the row's *own* work coordinates (what a controller
    reports as work position) into the job's frame, float64 (n, 3) mm:
    ``wco - tool length - reference_wco`` (0 for a row in the job's work system, no G92)."""
    moves = as_move_table(moves)
    out = np.asarray(moves["wco"][:, :3], np.float64) - np.asarray(reference, np.float64).reshape(-1)[:3]
    out[:, 2] -= moves["tool_length"]
    # offsets summed in another order differ in the last bit: that is no shift
    out[np.abs(out) < SHIFT_EPS] = 0.0
    return out


# --- machine <-> work coordinates for travel limits --------------------------------------

_AXES = "XYZABC"


def limits_in_work(limits: dict | None, wco) -> dict | None:
    """Travel limits of the controlled point (machine coords) as limits of the work tip.

    ``limits``: {axis: (lo, hi)} mm/deg; ``wco`` (6,) the offset in force (G5x + G92 +
    tool length): machine = work + wco, so each bound moves by ``-wco`` of its axis.
    """
    if not limits:
        return None
    w = np.zeros(6)
    v = np.asarray(wco, np.float64).reshape(-1)[:6]
    w[:v.size] = v
    out = {}
    for axis, (lo, hi) in limits.items():
        k = _AXES.index(axis.upper())
        out[axis.upper()] = (float(lo) - w[k], float(hi) - w[k])
    return out


def finding_to_machine(f: Finding, wco) -> Finding:
    """A ``travel_limit`` finding from work-coordinate checks, told in machine coordinates
    (position, limit and message); other kinds are returned unchanged."""
    if f.kind != "travel_limit":
        return f
    from dataclasses import replace

    w = np.zeros(6)
    v = np.asarray(wco, np.float64).reshape(-1)[:6]
    w[:v.size] = v
    axis = str(f.detail.get("axis", "X")).upper()
    k = _AXES.index(axis)
    lim = float(f.detail.get("limit", math.nan)) + w[k]
    group = str(f.detail.get("group", axis + "+"))
    side = "min" if group.endswith("-") else "max"
    pos = tuple(float(p + w[i]) for i, p in enumerate(f.position))
    detail = dict(f.detail, limit=lim)
    msg = f"travel limit: {axis}{side} {lim:g} exceeded by {f.depth:.3f} at line {f.line}"
    return replace(f, position=pos, detail=detail, message=msg)
