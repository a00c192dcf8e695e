"""The job's program as a move table, and its time per row.

:func:`load_moves` runs the G-code interpreter on the job's program (dialect, tool table,
.var file, subroutines) and starts the table where the machine starts
(:mod:`monitor.start`); :func:`program_seconds` times its rows with the machine limits in
force (``Program.cycle_time``, a GRBL-like planner), or by length / feed when that fails.
"""

from __future__ import annotations

import numpy as np

from monitor.job import Job
from monitor.sync import row_seconds
from monitor.work_coords import work_moves


def load_moves(job: Job) -> tuple[np.ndarray, object]:
    """The job's program as a move table (MOVE_DTYPE), via the G-code interpreter, and the
    program; both start where the machine starts (:mod:`monitor.start`), not at machine zero."""
    from monitor.start import job_start, start_at
    from sim.gcode import Limits, load_program

    program = load_program(job.program, dialect=job.program_dialect, tool_table=job.tool_table, var_file=job.var_file,
                           machine_units=job.machine_units, limits=Limits(max_loop=job.max_loop),
                           block_delete=job.block_delete,
                           subroutine_path=[str(d) for d in job.subroutine_path] or None)
    moves = np.asarray(program.moves)
    start = job_start(job, moves)
    if start is not None:
        program.moves = moves = start_at(moves, start)  # its cycle time runs from there too
    return moves, program


def program_seconds(program, moves: np.ndarray, machine=None) -> np.ndarray:
    """Per-row program seconds, float64 (n,): ``program.cycle_time(machine)`` (GRBL-like
    trapezoids and junction deviation) when it works, else length / feed."""
    if program is not None:
        try:
            got = program.cycle_time(machine)
            secs = np.asarray(got[1] if isinstance(got, tuple) else got, np.float64)
            if secs.shape == (len(moves),) and np.all(np.isfinite(secs)):
                return secs
        except Exception:  # an interpreter without timing, or a table it cannot plan
            pass
    return row_seconds(work_moves(moves))
