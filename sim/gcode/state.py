"""The modal state of the interpreter, as a plain value a caller may keep."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def _fmt_g(code10: int) -> str:
    """G code from its tenths representation: 10 -> 'G1', 591 -> 'G59.1'."""
    whole, tenth = divmod(int(code10), 10)
    return f"G{whole}" if tenth == 0 else f"G{whole}.{tenth}"


@dataclass
class ModalState:
    """Everything a controller keeps between lines, in mm / mm/min / rpm / degrees.

    G codes are kept in tenths (``motion=10`` is G1, ``coord_system=591`` is G59.1).
    ``position`` is machine coordinates X Y Z A B C of the controlled point;
    ``work_position`` = position - work_offset - g92_offset - tool_offset.
    """

    motion: int = 0
    plane: int = 170
    distance: int = 900
    arc_distance: int = 911
    feed_mode: int = 940
    units: int = 210
    cutter_comp: int = 400
    tool_length_mode: int = 490
    coord_system: int = 540
    path_mode: int = 610
    retract_mode: int = 980
    feed: float = 0.0            # mm/min (G94) as programmed
    feed_word: float = 0.0       # the F number as written (program units)
    spindle: float = 0.0
    spindle_dir: int = 0
    tool: int = 0                # tool in the spindle
    selected_tool: int = 0       # T word (next tool for M6)
    tool_length: float = 0.0     # Z of the tool offset in force, mm
    comp_radius: float = 0.0     # cutter compensation radius in force, mm
    coolant: int = 0
    position: np.ndarray = field(default_factory=lambda: np.zeros(6))
    work_position: np.ndarray = field(default_factory=lambda: np.zeros(6))
    work_offset: np.ndarray = field(default_factory=lambda: np.zeros(6))   # active G54..G59.3
    g92_offset: np.ndarray = field(default_factory=lambda: np.zeros(6))
    tool_offset: np.ndarray = field(default_factory=lambda: np.zeros(6))
    file: int = 0
    line: int = 0

    @property
    def metric(self) -> bool:
        return self.units == 210

    def gcodes(self) -> list[str]:
        """Active modal G codes in GRBL's ``$G`` order (motion, wcs, plane, units, distance, feed)."""
        return [
            _fmt_g(self.motion), _fmt_g(self.coord_system), _fmt_g(self.plane), _fmt_g(self.units),
            _fmt_g(self.distance), _fmt_g(self.feed_mode), _fmt_g(self.cutter_comp),
            _fmt_g(self.tool_length_mode), _fmt_g(self.path_mode), _fmt_g(self.retract_mode),
            _fmt_g(self.arc_distance),
        ]

    def mcodes(self) -> list[str]:
        out = ["M3" if self.spindle_dir > 0 else "M4" if self.spindle_dir < 0 else "M5"]
        if self.coolant & 1:
            out.append("M7")
        if self.coolant & 2:
            out.append("M8")
        if not self.coolant:
            out.append("M9")
        return out
