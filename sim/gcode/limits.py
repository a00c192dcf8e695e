"""How far a program may go before it is called runaway: one place for every bound.

A mutated or careless program can ask for a billion loop passes, a cycle repeated
``L1e9`` times, an arc of a hundred thousand turns or a coordinate of ``10**300`` mm.
None of these is a program any machine runs; each is refused at its line with a
:class:`~sim.gcode.errors.LineError` that names the limit, instead of hanging, filling
memory, or handing a compiled kernel numbers it cannot handle. Loop passes are the one
bound a real program may need to raise (``--max-loop``); the others are far beyond any
machine. (Bracket nesting is bounded where expressions are read:
:data:`sim.gcode.parser.MAX_NESTING`.)
"""

from __future__ import annotations

from dataclasses import dataclass

#: a linear coordinate (mm, machine or work) beyond this is no machine's travel
MAX_LINEAR_MM = 1.0e5
#: a rotary coordinate (deg) beyond this is no machine's (about 28,000 turns)
MAX_ROTARY_DEG = 1.0e7


@dataclass(frozen=True)
class Limits:
    """Bounds on what one program may ask for.

    Attributes
    ----------
    max_loop : int
        Passes of one ``while``/``do``/``repeat`` loop each time it is entered (and the
        largest ``repeat`` count).
    max_steps : int (derived)
        Blocks executed beyond the file's own lines (loop passes and subroutine calls):
        ten times ``max_loop``, so the one knob raises both.
    max_cycle_repeats : int
        ``L`` of a canned cycle.
    max_pecks : int
        Pecks of one ``G73``/``G83`` hole (depth / Q).
    max_arc_turns : int
        ``P`` of an arc (full turns).
    max_line_chars : int
        Characters of one source line (LinuxCNC reads 255, GRBL 80).
    max_tool : int
        Largest tool number.
    """

    max_loop: int = 100_000
    max_cycle_repeats: int = 10_000
    max_pecks: int = 10_000
    max_arc_turns: int = 1_000
    max_line_chars: int = 4_096
    max_tool: int = 2**31 - 1

    @property
    def max_steps(self) -> int:
        return 10 * self.max_loop


DEFAULT_LIMITS = Limits()
