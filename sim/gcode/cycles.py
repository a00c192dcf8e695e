"""Canned cycles G73 G74 G81-G89 as LinuxCNC's rs274 executes them (interp_cycles.cc).

The arithmetic is rs274's, in program units (so a peck count is the same to the last
bit): per block, ``old`` is the *initial level*, the plane-normal coordinate before the
first cycle of a sequence (any other motion ends the sequence); below R, the tool first
rises to R and ``old`` becomes R. The clear height is R with G99 (LinuxCNC's initial
retract mode) and ``old`` with G98. In G91, R is relative to the initial level and the
bottom to R, and the plane words are increments applied at each of the L repeats.

Per repeat (CYCLE_MACRO): the first repeat starting above R traverses at its height, then
down to R; any other traverses at the clear height, then down to R if that is higher.
Then the cycle's own moves (see :data:`BODIES`). The block ends at the hole's position
at the clear height (for G88 after the operator's manual retract: the PAUSE row moves
there).

Words: R and the bottom are needed unless the same cycle ran in the block before, as are
Q (G73/G83), P (G82 G86 G88 G89) and I J K (G87); the last values are remembered.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from sim.gcode.errors import LineError
from sim.gcode.moves import INCH, MoveKind

G83_RAPID_DELTA_INCH = 0.010  # LinuxCNC: how far above the last depth a peck returns
LETTERS = "XYZABC"
NAMES = {730: "G73", 740: "G74", 810: "G81", 820: "G82", 830: "G83", 840: "G84", 850: "G85",
         860: "G86", 870: "G87", 880: "G88", 890: "G89"}
NEEDS_P = (820, 860, 880, 890)   # dwell at the bottom, P required on the first block
USES_P = NEEDS_P + (740, 840)
NEEDS_Q = (730, 830)
SPINDLE_NEEDED = (860, 870, 880)


@dataclass
class CycleMemory:
    """What LinuxCNC keeps between cycle blocks, as the words were given (program units):
    R, the bottom (``cc``), Q, P, G87's I J K, and the initial level ``il`` (None: no
    sequence of cycles is running)."""

    r: float = 0.0
    cc: float = 0.0
    q: float = 0.0
    p: float = 0.0
    ijk: dict = field(default_factory=lambda: {"I": 0.0, "J": 0.0, "K": 0.0})
    il: float | None = None


@dataclass
class _Words:
    """One cycle block's words, the remembered ones filled in (program units)."""

    r: float
    cc: float
    q: float
    p: float
    ijk: list | None     # G87: offsets along the plane's first and second axes, top height
    repeats: int


def canned_cycle(it, motion: int, words, cols, used) -> None:
    """Execute canned cycle ``motion`` (tenths) with the block's ``words`` on interpreter ``it``.

    ``it.prev_motion`` is the motion mode before this block: the same cycle there lets the
    block omit R, the bottom, Q, P and I J K. Raises LineError where rs274 refuses the block.
    """
    from sim.gcode.interpreter import PLANE_AXES

    name = NAMES[motion]
    gcol = min([cols[k] for k in cols if k != "N"] or [1])
    _check_modes(it, name, gcol)
    w = _read_words(it, motion, name, words, cols, used, gcol)
    _check_spindle(it, motion, name, gcol)
    a, b, c = PLANE_AXES[it.plane]
    f = it.factor
    prog = [v / f if i < 3 else v for i, v in enumerate(it.work())]   # program units
    current_cc = prog[c]
    if it.cycle.il is None:
        it.cycle.il = current_cc
    old_cc = it.cycle.il
    r, cc, aa, bb, inc = _hole_geometry(it, w, words, cols, used, prog, old_cc, gcol)
    if r < cc:
        raise LineError(f"{name}: R plane ({r:g}) is below the bottom of the hole ({cc:g})", cols.get("R", gcol))
    if motion in NEEDS_Q:
        pecks = w.repeats * math.ceil((r - cc) / w.q)
        if pecks > it.limits.max_pecks:
            raise LineError(f"{name} Q{w.q:g} makes {pecks} pecks; at most {it.limits.max_pecks} "
                            "in one block (a larger Q)", cols.get("Q", gcol))
    path = _Path(it, a, b, c, it._feed_rate(gcol, words, 0.0)[0])
    if old_cc < r:   # below the R plane: straight up to it first
        path.rapid(prog[a], prog[b], r)
        old_cc = current_cc = r
    clear = r if it.retract == 990 else old_cc
    for n in range(w.repeats):   # rs274's CYCLE_MACRO
        aa, bb = _next_hole(aa + inc[0], bb + inc[1], inc[2], inc[3], gcol)
        if n == 0 and current_cc > r:
            path.rapid(aa, bb, current_cc)
            path.rapid(aa, bb, r)
        else:
            path.rapid(aa, bb, clear)
            if clear > r:
                path.rapid(aa, bb, r)
        BODIES[motion](path, aa, bb, r, clear, cc, w.q, w.p, w.ijk, it)
    _remember(it, motion, w)


def _read_words(it, motion: int, name: str, words, cols, used, gcol: int) -> _Words:
    from sim.gcode.interpreter import PLANE_AXES, PLANE_OFFSET_WORDS

    mem: CycleMemory = it.cycle
    same = it.prev_motion == motion
    lc = LETTERS[PLANE_AXES[it.plane][2]]
    r = _word(words, used, "R", mem.r if same else None, f"{name} needs an R word (retract plane)", gcol)
    cc = _word(words, used, lc, mem.cc if same else None,
               f"{name} in this plane needs a {lc} word (bottom of the hole)", gcol)
    repeats = _repeats(it, words, cols, used)
    q = p = 0.0
    if motion in NEEDS_Q:
        q = _word(words, used, "Q", mem.q if same else None, f"{name} needs a Q word (peck depth)", gcol)
        if q <= 0.0:
            raise LineError(f"{name} Q (peck depth) must be positive, got {q:g}", cols.get("Q", gcol))
    if motion in USES_P:
        p = _word(words, used, "P", mem.p if same or motion not in NEEDS_P else None,
                  f"{name} needs a P word (dwell seconds)", gcol)
    ijk = None
    if motion == 870:
        ijk = [_word(words, used, k, mem.ijk[k] if same else None,
                     "G87 needs I, J and K words (back boring offsets and top)", gcol)
               for k in PLANE_OFFSET_WORDS[it.plane]]
    return _Words(r, cc, q, p, ijk, repeats)


def _hole_geometry(it, w: _Words, words, cols, used, prog: list, old_cc: float, gcol: int):
    """(R, bottom, first hole a, b, increments) in program units. G90: the words are
    absolute; G91: R from the initial level ``old_cc``, the bottom from R, and the plane
    words (or polar @ ^) are increments applied at each repeat."""
    from sim.gcode.interpreter import PLANE_AXES

    a, b, _ = PLANE_AXES[it.plane]
    if ("@" in words or "^" in words) and it.plane != 170:
        raise LineError("polar words @ ^ need G17", cols.get("@", cols.get("^", gcol)))
    if it.distance == 900:
        target = it._axis_values(words, cols, used)   # the hole's X Y (or @ ^), work mm
        return w.r, w.cc, target[a] / it.factor, target[b] / it.factor, (0.0, 0.0, 0.0, 0.0)
    la, lb = LETTERS[a], LETTERS[b]
    inc = (words.get(la, 0.0), words.get(lb, 0.0), words.get("@", 0.0), math.radians(words.get("^", 0.0)))
    used.update(k for k in (la, lb, "@", "^") if k in words)
    r = w.r + old_cc
    return r, r + w.cc, prog[a], prog[b], inc


def _remember(it, motion: int, w: _Words) -> None:
    """Keep the words for the blocks after (rs274's cycle_r, cycle_cc, cycle_q ...)."""
    from sim.gcode.interpreter import PLANE_OFFSET_WORDS

    mem: CycleMemory = it.cycle
    mem.r, mem.cc = w.r, w.cc
    if motion in NEEDS_Q:
        mem.q = w.q
    if motion in USES_P:
        mem.p = w.p
    if w.ijk is not None:
        mem.ijk = dict(zip(PLANE_OFFSET_WORDS[it.plane], w.ijk))


def _check_modes(it, name: str, col: int) -> None:
    if it.comp != 400:
        raise LineError("canned cycles cannot be used with cutter compensation on", col)
    if it.feed_mode == 930:
        raise LineError(f"{name}: canned cycles cannot be used in inverse time mode (G93)", col)
    if it.feed_word <= 0.0:
        raise LineError(f"{name} cannot feed with a zero feed rate: give an F word", col, 22)


def _check_spindle(it, motion: int, name: str, col: int) -> None:
    if motion in SPINDLE_NEEDED and it.spindle_dir == 0:
        raise LineError(f"{name} needs the spindle turning (M3 or M4)", col)
    if motion == 840 and it.spindle_dir != 1:
        raise LineError("G84 (right-hand tapping) needs the spindle turning clockwise (M3)", col)
    if motion == 740 and it.spindle_dir != -1:
        raise LineError("G74 (left-hand tapping) needs the spindle turning counterclockwise (M4)", col)


def _word(words, used, letter: str, remembered, missing: str, col: int) -> float:
    """The block's ``letter`` word, else ``remembered``; LineError ``missing`` if neither."""
    if letter in words:
        used.add(letter)
        return words[letter]
    if remembered is None:
        raise LineError(missing, col)
    return remembered


def _repeats(it, words, cols, used) -> int:
    if "L" not in words:
        return 1
    used.add("L")
    lv = words["L"]
    if lv != int(lv) or lv < 1:
        raise LineError(f"canned cycle L (repeats) must be a positive integer, got {lv:g}", cols["L"])
    if lv > it.limits.max_cycle_repeats:
        raise LineError(f"canned cycle L{lv:.0f}: at most {it.limits.max_cycle_repeats} repeats", cols["L"])
    return int(lv)


def _next_hole(aa: float, bb: float, d_radius: float, d_angle: float, col: int) -> tuple[float, float]:
    """The hole after a G91 polar increment (radius, then angle, about the program origin)."""
    for grow, turn in ((d_radius, 0.0), (0.0, d_angle)):
        if grow or turn:
            if aa == 0.0 and bb == 0.0:
                raise LineError("incremental polar motion is indeterminate at the origin", col)
            theta = math.atan2(bb, aa) + turn
            radius = math.hypot(bb, aa) + grow
            aa, bb = radius * math.cos(theta), radius * math.sin(theta)
    return aa, bb


class _Path:
    """Emits the cycle's moves: plane coordinates ``aa`` ``bb`` and height ``cc`` in program
    units (work coordinates), the other axes where they are."""

    def __init__(self, it, a: int, b: int, c: int, feed: float):
        self.it, self.a, self.b, self.c, self.feed = it, a, b, c, feed

    def _machine(self, aa: float, bb: float, cc: float) -> list:
        it = self.it
        w = it.work()
        f = it.factor
        w[self.a], w[self.b], w[self.c] = aa * f, bb * f, cc * f
        return it.to_machine(w)

    def _go(self, kind: int, aa: float, bb: float, cc: float, feed: float = 0.0) -> None:
        it = self.it
        end = self._machine(aa, bb, cc)
        it.emit(kind, list(it.pos), end, feed=feed)   # zero-length too, as rs274 prints it
        it.pos = end

    def rapid(self, aa: float, bb: float, cc: float) -> None:
        self._go(MoveKind.RAPID, aa, bb, cc)

    def feed_to(self, aa: float, bb: float, cc: float) -> None:
        self._go(MoveKind.FEED, aa, bb, cc, self.feed)

    def dwell(self, seconds: float) -> None:
        here = list(self.it.pos)
        self.it.emit(MoveKind.DWELL, here, here, dwell=seconds)

    def pause(self, aa: float, bb: float, cc: float) -> None:
        """A program stop during which the operator moves the machine to ``aa bb cc``."""
        it = self.it
        end = self._machine(aa, bb, cc)
        it.emit(MoveKind.PAUSE, list(it.pos), end)
        it.pos = end

    def spindle(self, direction: int) -> None:
        self.it.spindle_dir = direction


def _g81(p: _Path, x, y, r, clear, bottom, q, dwell, ijk, it):
    p.feed_to(x, y, bottom)
    p.rapid(x, y, clear)


def _g82(p: _Path, x, y, r, clear, bottom, q, dwell, ijk, it):
    p.feed_to(x, y, bottom)
    p.dwell(dwell)
    p.rapid(x, y, clear)


def _pecks(p: _Path, x, y, r, clear, bottom, q, back_to_r: bool):
    """G83 (back to R after each peck) and G73 (chip break: back up a little)."""
    delta = G83_RAPID_DELTA_INCH * (INCH if p.it.units == 210 else 1.0)
    depth = r - q
    while depth > bottom:
        p.feed_to(x, y, depth)
        if back_to_r:
            p.rapid(x, y, r)
        p.rapid(x, y, depth + delta)
        depth -= q
    p.feed_to(x, y, bottom)
    p.rapid(x, y, clear)


def _g83(p, x, y, r, clear, bottom, q, dwell, ijk, it):
    _pecks(p, x, y, r, clear, bottom, q, back_to_r=True)


def _g73(p, x, y, r, clear, bottom, q, dwell, ijk, it):
    _pecks(p, x, y, r, clear, bottom, q, back_to_r=False)


def _tap(p: _Path, x, y, r, clear, bottom, q, dwell, ijk, it):
    """G84 / G74 floating tapping: feed in, reverse the spindle, dwell, feed out, restore."""
    turning = it.spindle_dir
    p.feed_to(x, y, bottom)
    p.spindle(-turning)
    p.dwell(dwell)
    p.feed_to(x, y, clear)
    p.spindle(turning)


def _g85(p: _Path, x, y, r, clear, bottom, q, dwell, ijk, it):
    p.feed_to(x, y, bottom)
    p.feed_to(x, y, r)
    p.rapid(x, y, clear)


def _g86(p: _Path, x, y, r, clear, bottom, q, dwell, ijk, it):
    turning = it.spindle_dir
    p.feed_to(x, y, bottom)
    p.dwell(dwell)
    p.spindle(0)
    p.rapid(x, y, clear)
    p.spindle(turning)


def _g87(p: _Path, x, y, r, clear, bottom, q, dwell, ijk, it):
    """Back boring: in beside the hole with the spindle stopped, bore up to the top
    (K in G17, absolute; relative to the bottom in G91), out beside the hole again."""
    turning = it.spindle_dir
    ox, oy = x + ijk[0], y + ijk[1]
    top = ijk[2] + (bottom if it.distance == 910 else 0.0)
    p.rapid(ox, oy, r)
    p.spindle(0)
    p.rapid(ox, oy, bottom)
    p.rapid(x, y, bottom)
    p.spindle(turning)
    p.feed_to(x, y, top)
    p.feed_to(x, y, bottom)
    p.spindle(0)
    p.rapid(ox, oy, bottom)
    p.rapid(ox, oy, clear)
    p.rapid(x, y, clear)
    p.spindle(turning)


def _g88(p: _Path, x, y, r, clear, bottom, q, dwell, ijk, it):
    """Bore, dwell, stop the spindle and the program: the operator retracts by hand, to
    the clear height as rs274 assumes (the PAUSE row moves there)."""
    turning = it.spindle_dir
    p.feed_to(x, y, bottom)
    p.dwell(dwell)
    p.spindle(0)
    p.pause(x, y, clear)
    p.spindle(turning)


def _g89(p: _Path, x, y, r, clear, bottom, q, dwell, ijk, it):
    p.feed_to(x, y, bottom)
    p.dwell(dwell)
    p.feed_to(x, y, clear)


BODIES = {810: _g81, 820: _g82, 830: _g83, 730: _g73, 840: _tap, 740: _tap, 850: _g85, 860: _g86,
          870: _g87, 880: _g88, 890: _g89}
