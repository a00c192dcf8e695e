"""The move table: one row per motion (or dwell, tool change ...) of a program.

Every consumer (dexel cutting, the virtual controller, look-ahead, replay) reads this one
layout. Positions are of the *controlled point* in machine coordinates, like a
controller's MPos; the tool tip is ``end - [0, 0, tool_length]`` (G43 length offset).
Work coordinates are not stored: ``wco`` is the work coordinate offset in force on the
row (G5x + G92 + the G43 length offset in Z, what GRBL reports as WCO), so the work
position is ``machine - wco`` (:func:`work_start`, :func:`work_end`), bit for bit what
the interpreter computed. One offset per row holds because an offset can only change
between moves, never during one.

Units: mm for X Y Z, degrees for A B C, mm/min for feed, rpm for spindle, s for dwell.
"""

from __future__ import annotations

import enum

import numpy as np


class MoveKind(enum.IntEnum):
    RAPID = 0        # G0 (and G28/G30/G53 traverse)
    FEED = 1         # G1
    ARC_CW = 2       # G2 (helix when the axis coordinate changes)
    ARC_CCW = 3      # G3
    DWELL = 4        # G4; duration in ``dwell``
    TOOL_CHANGE = 5  # M6; ``tool`` is the new tool. One that moves (start != end) is
                     # rs274 re-reading its position after M6/M61 (sim.gcode.tool_length)
    PROBE = 6        # G38.x; with feed 0 the 0.254 mm retract after it (sim.gcode.probe)
    PAUSE = 7        # M0 / M1 / M60; G88's moves: the operator's manual retract
    END = 8          # M2 / M30


class Plane(enum.IntEnum):
    XY = 0  # G17, arc axis Z
    XZ = 1  # G18, arc axis Y
    YZ = 2  # G19, arc axis X


#: mm in an inch: G20 program units and inch machines are converted with it
INCH = 25.4

#: bit flags of the ``coolant`` column
COOLANT_MIST = 1   # M7
COOLANT_FLOOD = 2  # M8

MOVE_DTYPE = np.dtype(
    [
        ("file", np.int16),          # index into Program.files (0 = main program)
        ("line", np.int32),          # 1-based source line number in that file
        ("kind", np.uint8),          # MoveKind
        ("start", np.float64, 6),    # machine coords X Y Z A B C at the start
        ("end", np.float64, 6),      # machine coords at the end
        ("wco", np.float64, 6),      # work coordinate offset in force: machine - work
        ("center", np.float64, 3),   # arc centre, machine coords (NaN for non-arcs)
        ("plane", np.uint8),         # Plane
        ("turns", np.int32),         # arc: 1 + extra full turns (P word); 0 otherwise
        ("feed", np.float64),        # mm/min programmed (0 for rapids: machine max rate)
        ("inverse_time", np.float64),  # G93: 1/min as programmed, else 0
        ("spindle", np.float64),     # rpm, >= 0
        ("spindle_dir", np.int8),    # +1 M3 (CW), -1 M4 (CCW), 0 M5
        ("tool", np.int32),          # tool in the spindle
        ("tool_length", np.float64), # G43 length offset in force, mm
        ("coolant", np.uint8),       # COOLANT_* bits
        ("dwell", np.float64),       # G4 seconds
    ]
)


def empty_moves(n: int = 0) -> np.ndarray:
    """Return a zeroed move table of ``n`` rows (``center`` NaN)."""
    moves = np.zeros(n, dtype=MOVE_DTYPE)
    moves["center"] = np.nan
    return moves


def work_start(moves: np.ndarray) -> np.ndarray:
    """Work coordinates X Y Z A B C at the start of each row, (n, 6) float64: ``start - wco``."""
    return moves["start"] - moves["wco"]


def work_end(moves: np.ndarray) -> np.ndarray:
    """Work coordinates X Y Z A B C at the end of each row, (n, 6) float64: ``end - wco``."""
    return moves["end"] - moves["wco"]


#: the layout before ``wco`` replaced the two work-position columns (run files written then)
_LEGACY_WORK = ("start_work", "end_work")


def as_move_table(moves: np.ndarray) -> np.ndarray:
    """``moves`` as MOVE_DTYPE: a MOVE_DTYPE array unchanged, an older table converted.

    Tables from before the ``wco`` column (``start_work``/``end_work`` fields, e.g. in old
    run files) get ``wco = start - start_work``. Raises ValueError for any other dtype.
    """
    moves = np.asarray(moves)
    if moves.dtype == MOVE_DTYPE:
        return moves
    names = moves.dtype.names or ()
    want = set(MOVE_DTYPE.names) - {"wco"}
    if not (want <= set(names) and set(_LEGACY_WORK) <= set(names)):
        raise ValueError(f"not a move table: fields {names}")
    out = np.empty(moves.shape, MOVE_DTYPE)
    for name in want:
        out[name] = moves[name]
    out["wco"] = moves["start"] - moves["start_work"]
    return out


def tip_positions(moves: np.ndarray, which: str = "end") -> np.ndarray:
    """Tool tip positions X Y Z (machine coords), shape (n, 3) float64, mm.

    ``which`` is ``"start"`` or ``"end"``; the G43 length offset is taken off Z.
    """
    pts = np.array(moves[which][:, :3], dtype=np.float64)
    pts[:, 2] -= moves["tool_length"]
    return pts
