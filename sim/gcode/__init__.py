"""G-code interpreter (LinuxCNC RS274NGC and GRBL 1.1 dialects) producing move tables."""

from sim.gcode.moves import MOVE_DTYPE, MoveKind, Plane, empty_moves, tip_positions

__all__ = ["MOVE_DTYPE", "MoveKind", "Plane", "empty_moves", "tip_positions"]
