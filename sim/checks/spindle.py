"""Cutting with the spindle stopped: the moves that removed material while the spindle
did not turn, each named with where the spindle stopped (or that it never started).
"""

from __future__ import annotations

import numpy as np

from sim.checks.findings import Finding
from sim.checks.motion import is_motion, move_ids_of
from sim.checks.where import first_contact, met_at
from sim.gcode.moves import MoveKind


def _stopped(moves: np.ndarray) -> np.ndarray:
    """bool (n,): rows run with the spindle stopped."""
    return (moves["spindle_dir"] == 0) | (moves["spindle"] <= 0)


def spindle_off_from(moves: np.ndarray, move_ids=None, carry=None):
    """Per row, int64 (n, 2): for a row run with the spindle stopped, ``(move id, line)``:
    the first row of its stopped span and the line of the last row run with the spindle
    on before it (0: none, it was never started) - the M5 (or S0) lies after that line, and
    the table has no row of its own for it; for a row run with the spindle on, ``(0, its
    line)``. ``carry``: the last row's pair of the previous batch (None: no batch before)."""
    moves = np.asarray(moves)
    ids = move_ids_of(moves, move_ids)
    stopped = _stopped(moves)
    out = np.zeros((len(moves), 2), np.int64)
    cur = carry if carry is not None and carry[0] else None
    last_on = int(carry[1]) if carry is not None else 0
    for k in range(len(moves)):  # spans are few; rows are walked once
        if not stopped[k]:
            cur = None
            last_on = int(moves["line"][k])
            out[k] = (0, last_on)
            continue
        if cur is None:
            cur = (int(ids[k]), last_on)
        out[k] = cur
    return out


def spindle_stopped_cutting(moves: np.ndarray, removed, move_ids=None, min_volume: float = 1e-6,
                            carry=None, cut=None, grid=None) -> list[Finding]:
    """Moves that removed (or would remove) material with the spindle stopped.

    ``removed``: float64 (n,) mm^3 per row (from ``Cutter.cut_moves`` or
    ``probe_moves``). Rapids are left to the rapid check. Every hit names its cause, the
    span of rows run with the spindle stopped (``detail["cause"]``: after which line it
    stopped, or that it never started; ``carry``: the last row's pair of the previous
    batch, see :func:`spindle_off_from`), so that :func:`merge_findings` makes one finding of a
    program that never starts the spindle, not one per move. Position: with ``cut`` (the
    batch's CutResult) and ``grid`` (the model after it), where the move first met
    material (:func:`sim.checks.where.first_contact`); else the move's end.
    """
    moves = np.asarray(moves)
    ids = move_ids_of(moves, move_ids)
    removed = np.asarray(removed, np.float64)
    bad = np.nonzero(_stopped(moves) & (removed > min_volume) & is_motion(moves)
                     & (moves["kind"] != int(MoveKind.RAPID)))[0]
    if bad.size == 0:
        return []
    span = spindle_off_from(moves, ids, carry)
    out = []
    for k in bad:
        tip = met_at(moves, k, first_contact, cut, grid)
        first_id, on_line = (int(v) for v in span[k])
        since = f"spindle off after line {on_line}" if on_line > 0 else "spindle off: never started"
        out.append(Finding(kind="spindle_stopped_cutting", line=int(moves["line"][k]), stage=int(ids[k]),
                           position=tuple(tip), volume=float(removed[k]),
                           detail={"cause": since, "off_from_move": first_id}))
    return out
