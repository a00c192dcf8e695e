"""G38.2-G38.5 straight probing as LinuxCNC's stand-alone rs274 simulates it.

No probe input exists in a simulation, so rs274's canon (src/emc/sai/saicanon.cc) never
trips: the probe travels the whole way to its target, ``GET_EXTERNAL_PROBE_TRIPPED_VALUE``
is 0, and the probed position is the target. It then backs the probe off 0.254 mm
(0.01 in) from the target towards where the move started, and the interpreter, reading
its position back after a probe (``set_probe_data``), continues from there.

What rs274 leaves behind, which dexmon reproduces here:

- a PROBE row from the start to the target (the probed point), at the feed rate;
- a PROBE row with feed 0 from there to the target backed off 0.254 mm towards the
  start (saicanon's retract; none when the probe did not move in X Y Z): the next move
  starts there;
- #5061-#5066 = the target X Y Z A B C, work coordinates in program units; #5067-#5069
  (U V W) = 0; #5070 = 0 (not tripped), so ``while [#5070 NE 0]`` search loops end.

The move is refused as rs274 refuses it: with cutter compensation on, in G95 (feed per
revolution), without a feed rate (probing uses the units-per-minute rate of the last F
given outside G93, in G93 too), and for G38.2 or G38.4 when the target is the start point.
"""

from __future__ import annotations

import math

from sim.gcode.errors import LineError
from sim.gcode.moves import MoveKind

#: saicanon backs off 0.254 mm in G21 and 0.01 in in G20: the same 0.254 mm
BACKOFF_MM = 0.254
#: G38.2 and G38.4 must move (they fail when the probe does not change state); G38.3 and
#: G38.5 (probe_type & 1: "suppress the error") may start at their target
MUST_MOVE = (382, 384)
#: #5061..#5069: probed X Y Z A B C U V W; #5070: 1 if the probe tripped
FIRST_RESULT = 5061
TRIPPED = 5070


def straight_probe(it, motion: int, end: list, words, col: int) -> None:
    """Execute G38.x (``motion`` 382..385) to ``end`` (machine mm/deg) on interpreter ``it``.

    Raises LineError where rs274 refuses the block; the interpreter's state is untouched then.
    """
    name = f"G{motion / 10:g}"
    if it.comp != 400:
        raise LineError(f"{name} cannot probe with cutter radius compensation on (G40 first)", col)
    if it.feed_mode == 950:
        raise LineError(f"{name} cannot probe in feed per revolution mode (G95)", col)
    if it.feed_word <= 0.0:
        # the feed rate of the last F given in G94 (a G93 F is the move's; G94/G95 reset it)
        raise LineError(f"{name} cannot probe with a zero feed rate: give an F word in G94 mode", col)
    start = list(it.pos)
    if motion in MUST_MOVE and all(_same(a, b) for a, b in zip(start, end)):
        raise LineError(f"{name} start point is the probe target: nothing to probe "
                        "(LinuxCNC: start point too close to probe point)", col)
    # rs274's canon backs off towards where *it* believes the probe started: an offset
    # change no motion has carried yet (tool_length) is not in its position
    canon_start = [start[i] + it.tlo[i] - it.canon_tlo[i] for i in range(6)]
    feed = it.feed_word * it.factor
    it.emit(MoveKind.PROBE, start, end, feed=feed)
    _set_results(it, it.work_of(end))
    it.pos = list(end)
    back = _backed_off(canon_start, end)
    if back != it.pos:
        it.emit(MoveKind.PROBE, it.pos, back)   # feed 0: the retract, not a probing move
        it.pos = back


def _same(a: float, b: float) -> bool:
    """rs274 compares the start and the target exactly, in program units; dexmon's mm
    positions carry the rounding of the unit conversion, so equal means within 1e-9."""
    return abs(a - b) <= 1e-9 * max(1.0, abs(a), abs(b))


def _set_results(it, target: list) -> None:
    """#5061-#5070 from the probed point ``target`` (work mm/deg), in program units."""
    numbered = it.params.numbered
    for axis in range(6):
        numbered[FIRST_RESULT + axis] = target[axis] / it.factor if axis < 3 else target[axis]
    for k in range(FIRST_RESULT + 6, TRIPPED):
        numbered[k] = 0.0          # U V W: dexmon has no such axes
    numbered[TRIPPED] = 0.0        # a simulated probe never trips


def _backed_off(start: list, end: list) -> list:
    """Machine position after the probe: ``end`` moved BACKOFF_MM towards ``start`` in X Y Z
    (saicanon's STRAIGHT_PROBE); A B C stay at the target. ``end`` itself for a probe that
    did not move in X Y Z."""
    d = [start[i] - end[i] for i in range(3)]
    dist = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    out = list(end)
    if dist != 0.0:
        for i in range(3):
            out[i] = end[i] + BACKOFF_MM * d[i] / dist
    return out
