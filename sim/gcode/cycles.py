"""Canned cycles G73 G81 G82 G83 G85 G86 G89 as LinuxCNC executes them.

Per hole: traverse in the plane at the current clearance height, traverse down to the R
plane, the cycle's own moves, then retract to the clear height: the R plane with G99,
the height before the cycle started (or R, if that is higher) with G98. In G91, R is
relative to the starting height, the bottom relative to R, and X Y (or polar @ ^)
increments are applied ``L`` times.
"""

from __future__ import annotations

import math

from sim.gcode.errors import LineError
from sim.gcode.moves import MoveKind

G83_RAPID_DELTA_INCH = 0.010  # LinuxCNC: how far above the last depth a peck returns


def canned_cycle(it, motion: int, words, cols, used) -> None:
    from sim.gcode.interpreter import INCH, PLANE_AXES

    a, b, c = PLANE_AXES[it.plane]
    letters = "XYZABC"
    la, lb, lc = letters[a], letters[b], letters[c]
    f = it.factor
    gcol = min([cols[k] for k in cols if k != "N"] or [1])
    first_time = it.cycle_r is None or it.cycle_motion != motion
    if "R" in words:
        it.cycle_r = words["R"]
        used.add("R")
    elif it.cycle_r is None:
        raise LineError("canned cycle needs an R word (retract plane)", gcol)
    if lc in words:
        it.cycle_z = words[lc]
        used.add(lc)
    elif it.cycle_z is None or first_time and it.cycle_motion is not None and it.cycle_motion != motion:
        if it.cycle_z is None:
            raise LineError(f"canned cycle needs a {lc} word (bottom of the hole)", gcol)
    it.cycle_motion = motion
    if "Q" in words:
        it.cycle_q = words["Q"]
        used.add("Q")
    if "P" in words:
        if motion not in (820, 860, 890):
            raise LineError(f"P word with no G4, G82, G86 or G89 to use it (G{motion // 10})", cols["P"])
        it.cycle_p = words["P"]
        used.add("P")
    L = 1
    if "L" in words:
        Lv = words["L"]
        used.add("L")
        if Lv != int(Lv) or Lv < 1:
            raise LineError(f"canned cycle L (repeats) must be a positive integer, got {Lv:g}", cols["L"])
        if Lv > it.limits.max_cycle_repeats:
            raise LineError(f"canned cycle L{Lv:.0f}: at most {it.limits.max_cycle_repeats} repeats", cols["L"])
        L = int(Lv)
    if motion in (730, 830):
        if it.cycle_q is None or it.cycle_q <= 0:
            raise LineError(f"G{motion // 10} needs a positive Q word (peck depth)", cols.get("Q", gcol))
    cur = it.work()
    old_c = cur[c]
    polar = "@" in words or "^" in words
    if it.distance == 900:
        r = it.cycle_r * f
        bottom = it.cycle_z * f
        target = it._axis_values(words, cols, used)
        aa, bb = target[a], target[b]
        inc_a = inc_b = 0.0
        polar = False
    else:
        r = it.cycle_r * f + old_c
        bottom = r + it.cycle_z * f
        aa, bb = cur[a], cur[b]
        inc_a = words.get(la, 0.0) * f
        inc_b = words.get(lb, 0.0) * f
        used.update(k for k in (la, lb) if k in words)
        used.update(k for k in ("@", "^") if k in words)
        if polar and it.plane != 170:
            raise LineError("polar words @ ^ need G17", gcol)
    if r < bottom:
        raise LineError(f"R plane ({r / f:g}) is below the bottom of the hole ({bottom / f:g})",
                        cols.get("R", gcol))
    delta = (it.cycle_q or 0.0) * f
    if motion in (730, 830):
        pecks = L * math.ceil((r - bottom) / delta)
        if pecks > it.limits.max_pecks:
            raise LineError(f"G{motion // 10} Q{it.cycle_q:g} makes {pecks} pecks; at most {it.limits.max_pecks} "
                            "in one block (a larger Q)", cols.get("Q", gcol))
    rapid_delta = G83_RAPID_DELTA_INCH * INCH
    dwell = it.cycle_p or 0.0
    gfeed, ginv = it._feed_rate(gcol, words, abs(r - bottom))

    def move(kind, pa, pb, pc):
        w = list(it.work())
        w[a], w[b], w[c] = pa, pb, pc
        end = it.to_machine(w)
        if end == it.pos:
            return
        start = list(it.pos)
        if kind == MoveKind.RAPID:
            it.emit(kind, start, end)
        else:
            it.emit(kind, start, end, feed=gfeed if it.feed_mode != 930 else abs(start[c] - end[c]) * ginv,
                    inverse=ginv)
        it.pos = end

    def dwell_row():
        here = list(it.pos)
        it.emit(MoveKind.DWELL, here, here, dwell=dwell)

    if old_c < r:
        move(MoveKind.RAPID, cur[a], cur[b], r)
        old_c = r
    clear = r if it.retract == 990 else old_c
    current_c = old_c
    for _ in range(L):
        if polar:
            rad = math.hypot(aa, bb)
            th = math.atan2(bb, aa)
            rad += words.get("@", 0.0) * f
            th += math.radians(words.get("^", 0.0))
            aa, bb = rad * math.cos(th), rad * math.sin(th)
        else:
            aa += inc_a
            bb += inc_b
        move(MoveKind.RAPID, aa, bb, current_c)
        move(MoveKind.RAPID, aa, bb, r)
        if motion == 810:
            move(MoveKind.FEED, aa, bb, bottom)
            move(MoveKind.RAPID, aa, bb, clear)
        elif motion in (820, 860):  # G86 stops the spindle at the bottom: the path is G82's
            move(MoveKind.FEED, aa, bb, bottom)
            dwell_row()
            move(MoveKind.RAPID, aa, bb, clear)
        elif motion in (730, 830):
            depth = r - delta
            while depth > bottom:
                move(MoveKind.FEED, aa, bb, depth)
                if motion == 830:
                    move(MoveKind.RAPID, aa, bb, r)
                move(MoveKind.RAPID, aa, bb, depth + rapid_delta)
                depth -= delta
            move(MoveKind.FEED, aa, bb, bottom)
            move(MoveKind.RAPID, aa, bb, clear)
        elif motion == 850:
            move(MoveKind.FEED, aa, bb, bottom)
            move(MoveKind.FEED, aa, bb, r)
            move(MoveKind.RAPID, aa, bb, clear)
        elif motion == 890:
            move(MoveKind.FEED, aa, bb, bottom)
            dwell_row()
            move(MoveKind.FEED, aa, bb, r)
            move(MoveKind.RAPID, aa, bb, clear)
        current_c = clear
