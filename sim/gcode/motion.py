"""The motion of a block (modal group 1), run on an interpreter (:mod:`sim.gcode.interpreter`)
after everything else on the line but the stops: G0 and G1 straight moves, G33 and G33.1
spindle-synchronised ones; G2/G3 (:mod:`.arcs`), G5/G5.1 (:mod:`.splines`), G38.x
(:mod:`.probe`) and the canned cycles (:mod:`.cycles`) are handed on. Under cutter
compensation the straight moves go through its engine (:mod:`.comp`).
"""

from __future__ import annotations

import math

from sim.gcode import arcs, comp, nonmodal, splines
from sim.gcode.cycles import canned_cycle
from sim.gcode.errors import LineError
from sim.gcode.modal_groups import CYCLES
from sim.gcode.moves import MoveKind
from sim.gcode.parser import AXES
from sim.gcode.probe import straight_probe


def run_motion(it, motion, explicit, words, cols, used, g53, has_axes) -> None:
    """Run motion code ``motion`` (tenths) of a block on interpreter ``it``. ``explicit``:
    the line names it (else it is the modal motion, repeated by axis words); ``g53``: the
    axis words are machine coordinates; ``has_axes``: the line has axis words."""
    first_axis_col = min([cols[a] for a in AXES + "@^" if a in cols] or [1])
    if motion in (0, 10, 330, 331):
        it.arc_not_allowed = False
    if motion in CYCLES:
        if it.comp != 400:
            raise LineError("canned cycles cannot be used with cutter compensation on", first_axis_col)
        canned_cycle(it, motion, words, cols, used)
        return
    if g53:
        end = list(it.pos)
        for i, v in nonmodal.axis_words(words, it.factor, used):
            end[i] = v
    else:
        if motion in (20, 30):
            end = None
        else:
            end = it.to_machine(it._axis_values(words, cols, used))
    if motion == 0:
        if it.comp_engine is not None:
            it.comp_engine.straight(it.work_of(end), rapid=True, col=first_axis_col)
            return
        it._rapid_to(end)
    elif motion == 10:
        if it.comp_engine is not None:
            it.comp_engine.straight(it.work_of(end), rapid=False, col=first_axis_col, words=words)
            return
        length = math.dist(it.pos[:3], end[:3]) or abs(max((abs(end[i] - it.pos[i]) for i in range(3, 6)), default=0.0))
        feed, inv = it._feed_rate(first_axis_col, words, length)
        it._line_to(end, MoveKind.FEED, feed, inv)
    elif motion in (20, 30):
        arcs.arc_motion(it, motion == 20, explicit, words, cols, used, has_axes)
    elif motion in (50, 51):
        splines.spline(it, motion, end, words, cols, used, first_axis_col)
    elif motion in (330, 331):
        if it.comp_engine is not None:  # LinuxCNC compensates G33/G33.1 as plain feeds, unsynchronised
            used.update(k for k in ("K", "I") if k in words)
            it.comp_engine.straight(it.work_of(end), rapid=False, col=first_axis_col, words=words,
                                    entry_allowed=False)
            return
        _synced(it, motion, end, words, cols, used, first_axis_col)
    elif not it.grbl:  # probe G38.x as rs274 simulates it
        comp.refuse_while_on(it, "probe", first_axis_col)
        straight_probe(it, motion, end, words, first_axis_col)
    else:  # GRBL: the table assumes the probe travels to the target
        feed, inv = it._feed_rate(first_axis_col, words, math.dist(it.pos[:3], end[:3]))
        it._line_to(end, MoveKind.PROBE, feed, inv)


def _synced(it, motion, end, words, cols, used, col) -> None:
    """G33 spindle-synchronised motion / G33.1 rigid tapping (in, then back out).

    The feed is pitch K (per revolution) times the spindle speed.
    """
    if "K" not in words:
        raise LineError(f"G{motion / 10:g} needs a K word (distance per revolution)", col)
    used.add("K")
    if it.spindle <= 0:
        raise LineError(f"G{motion / 10:g} needs the spindle turning (S > 0)", col)
    feed = words["K"] * it.factor * it.spindle
    start = list(it.pos)
    it._line_to(end, MoveKind.FEED, feed, 0.0)
    if motion == 331:
        it._line_to(start, MoveKind.FEED, feed, 0.0)
