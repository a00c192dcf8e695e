"""Where the machine stands when the program starts: the *start position*.

The G-code interpreter starts every program at machine zero, but no machine does: a homed
machine stands at the top of its Z travel. A stock that contains machine zero would get a
false rapid into stock (and a false gouge) at the first move, and skipping that move
instead would hide a first rapid that really goes through the stock or past a travel
limit. So every command (``simulate``, ``dry-run``, ``live``) runs the program from one
start position: the rows before the first motion keep the machine there, and the first
motion runs from there to the program's first point, cut and checked as programmed.

The start position is the job's ``[machine] start = [x, y, z]``: machine coordinates of
the controlled point (mm, like ``[limits]`` and like the position a controller reports:
where the machine stands when the program starts, typically where it homes). Without it,
a safe one: the top of the Z travel (``[limits] z`` max) above the program's first point,
as a homed machine stands; without Z limits, :data:`CLEARANCE_MM` above the highest of the
stock, the fixtures and the program's own tip positions.

Machine coordinates become the move table's by the work offsets: the table holds the
interpreter's machine coordinates (work + the job's .var offsets), the machine's are work +
the job's ``work_offset`` (or, with ``"controller"``, the .var's again).
"""

from __future__ import annotations

import numpy as np

from sim.gcode.moves import MoveKind

#: the tip's height above the highest of stock, fixtures and program at the default start
#: position when the job gives no Z travel, mm
CLEARANCE_MM = 10.0
#: rows that move the machine from one point to another
_MOTION = (MoveKind.RAPID, MoveKind.FEED, MoveKind.ARC_CW, MoveKind.ARC_CCW)


def first_motion_row(moves: np.ndarray) -> int | None:
    """Index of the program's first motion row (rapid, feed or arc), None without one."""
    rows = np.flatnonzero(np.isin(moves["kind"], _MOTION))
    return int(rows[0]) if rows.size else None


def start_at(moves: np.ndarray, start) -> np.ndarray:
    """A copy of the move table ``moves`` that starts at ``start`` ((3,) mm, the table's
    machine coordinates of the controlled point): the rows before the first motion stand
    there, and the first motion runs from there to its end. A program whose first motion
    is an arc is left as it is (an arc from another point would be another arc)."""
    out = moves.copy()
    k = first_motion_row(moves)
    if k is None or int(moves["kind"][k]) in (MoveKind.ARC_CW, MoveKind.ARC_CCW):
        return out
    p = np.asarray(start, np.float64).reshape(3)
    out["start"][:k + 1, :3] = p
    out["end"][:k, :3] = p
    return out


def start_point(moves: np.ndarray, given=None, z_top: float | None = None, material_top: float | None = None,
                to_table=(0.0, 0.0, 0.0), reference=(0.0, 0.0, 0.0)) -> np.ndarray | None:
    """The start position in the table's machine coordinates, (3,) mm; None for a program
    without motion.

    Parameters
    ----------
    moves : MOVE_DTYPE (n,), the interpreter's table (controlled point, its machine coords).
    given : (3,) machine coordinates of the controlled point (``[machine] start``), or None.
    z_top : the top of the Z travel, machine coordinates (``[limits] z`` max), or None.
    material_top : the highest point of stock and fixtures in the job's work frame, mm, or None.
    to_table : (3,) what turns machine coordinates into the table's (the .var offset of
        the job's work system minus the job's work offset), mm.
    reference : (3,) the .var offset of the job's work system (table - work frame), mm.
    """
    k = first_motion_row(moves)
    if k is None:
        return None
    shift = np.asarray(to_table, np.float64).reshape(3)
    if given is not None:
        return np.asarray(given, np.float64).reshape(3) + shift
    out = np.array(moves["end"][k, :3], np.float64)
    if z_top is not None:
        out[2] = float(z_top) + shift[2]
        return out
    from monitor.work_coords import work_moves

    motion = moves[np.isin(moves["kind"], _MOTION)]
    tips = work_moves(motion, np.concatenate([np.asarray(reference, np.float64).reshape(3), np.zeros(3)]))
    highest = float(np.max(tips["end"][:, 2]))
    if material_top is not None:
        highest = max(highest, float(material_top))
    # the first row's controlled point stands its tool length above its tip
    out[2] = highest + CLEARANCE_MM + float(reference[2]) + float(moves["tool_length"][k])
    return out


def job_start(job, moves: np.ndarray) -> np.ndarray | None:
    """:func:`start_point` of a :class:`monitor.job.Job`: its ``[machine] start``, its Z
    travel, its stock's and fixtures' tops, its work offset and .var file."""
    from monitor.work_coords import reference_wco

    ref = reference_wco(job)[:3]
    zero = ref if job.work_offset is None else np.asarray(job.work_offset, np.float64)
    z_limits = {k.lower(): v for k, v in (job.limits or {}).items()}.get("z")
    z_top = None if z_limits is None else z_limits[1]
    # the material's top only matters without a start and a Z travel (an STL is loaded for it)
    top = material_top(job) if job.start is None and z_top is None else None
    return start_point(moves, given=job.start, z_top=z_top, material_top=top, to_table=ref - zero, reference=ref)


def material_top(job) -> float | None:
    """The highest Z of the job's stock and fixtures (work frame, mm); None without them.
    An STL is loaded for its bounds."""
    from monitor.workpiece import solid_bounds

    solids = ([job.stock] if job.stock is not None else []) + list(job.fixtures)
    if not solids:
        return None
    return max(float(solid_bounds(s, "[stock]" if s is job.stock else "[[fixtures]]")[1][2]) for s in solids)
