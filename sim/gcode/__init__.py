"""G-code interpreter (LinuxCNC RS274NGC and GRBL 1.1 dialects) producing move tables.

>>> from sim.gcode import interpret
>>> prog = interpret("G21 G90 G0 X10\\nG1 Y5 F300\\nM2")
>>> prog.moves["kind"].tolist()
[0, 1, 8]
"""

from sim.gcode.errors import GCodeError, ProgramFileError
from sim.gcode.interpreter import Interpreter
from sim.gcode.limits import Limits
from sim.gcode.moves import (MOVE_DTYPE, MoveKind, Plane, as_move_table, empty_moves, tip_positions, work_end,
                             work_start)
from sim.gcode.program import Program, interpret, load_program
from sim.gcode.state import ModalState

__all__ = [
    "GCodeError", "Interpreter", "Limits", "MOVE_DTYPE", "ModalState", "MoveKind", "Plane", "Program", "ProgramFileError",
    "as_move_table", "empty_moves", "interpret", "load_program", "tip_positions", "work_end", "work_start",
]
