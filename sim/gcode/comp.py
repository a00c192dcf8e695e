"""Cutter radius compensation G41/G42 (tool table D) and G41.1/G42.1 (D diameter), as
LinuxCNC's interpreter does it (interp_convert.cc ``convert_straight_comp1/2``,
``convert_arc_comp1/2``, interp_queue.cc ``move_endpoint_and_flush``).

Compensation works in the XY plane (G17) and the XZ plane (G18); G19 is refused. The
geometry below is written in the plane's own coordinates (first, second): X, Y in G17 and
Z, X in G18, so "left" is a +90 degree turn from the direction of travel in that frame.

* The entry move (the first move after G41/G42) ends one tool radius off its programmed
  end, at right angles to the programmed move: to its left for G41. It must be longer than
  the radius. An entry arc ends one radius off its programmed end along the arc's radius
  and is re-centred so that it still starts where the tool is.
* Every later move ends one radius off its programmed end, at right angles to the path
  there. Where it meets the move before it:
  - convex corner (the tool would leave the work): an arc of tool radius around the
    programmed corner is inserted (a straight rapid for G0);
  - concave corner: the end of the move before (and of the moves with no motion in the
    plane that followed it) is moved to where the two compensated paths meet;
  - tangent: they simply join.
  So a move is held back until the next one is known (``_held``, LinuxCNC's queue) and
  emitted when its end can no longer move.
* A stop (M0 M1 M2 M30 M60) and G40 emit what is held; a program that ends without M2
  never makes its held moves (rs274 does not either). After G40 the program position is
  the programmed one again (G91 counts from it), the tool stays where compensation left it
  (``it.tool_pos``: the next row starts there) and the next move must be straight.
* While compensation is on LinuxCNC refuses tool changes, offset changes, probing and
  the like (:func:`refuse_while_on`).

Positions are work coordinates in mm; angles in radians.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, replace

from sim.gcode.arcs import PLANE_AXES_BY_CODE
from sim.gcode.errors import LineError
from sim.gcode.moves import MoveKind

CORNER_TOL = 0.05   # rad: a turn within this of straight on is no corner (LinuxCNC TOLERANCE_CONCAVE_CORNER)
COS_TOL = 1e-6      # LinuxCNC TOLERANCE_EQUAL: the entry arc cannot be re-centred
RADII_TOL = 0.01    # program units: a moved arc end is off the arc (a LinuxCNC "BUG" check)
HALF_PI = math.pi / 2
TWO_PI = 2 * math.pi
COMP_PLANES = {170: 0, 180: 1}   # G17 G18 -> index into PLANE_AXES_BY_CODE
LATHE_SHIFTS = {  # tool orientation -> (X, Z) shift of the controlled point, in tool radii
    1: (-1, 1), 2: (-1, -1), 3: (1, -1), 4: (1, 1), 5: (0, 1), 6: (-1, 0), 7: (0, -1), 8: (1, 0)}


# ---------------------------------------------------------------------- interpreter hooks
def set_mode(it, mode, words, cols, used) -> None:
    """G40 / G41 / G42 / G41.1 / G42.1: ``mode`` is (code in tenths, column)."""
    code, col = mode
    if code == 400:
        turn_off(it)
    else:
        it.comp_engine = turn_on(it, code, words, cols, used, col)


def refuse_while_on(it, action: str, col: int) -> None:
    """LinuxCNC refuses to ``action`` (tool change, offsets, probing ...) while
    compensation is on, whatever the radius."""
    if it.comp != 400:
        raise LineError(f"cannot {action} with cutter radius compensation on", col)


def tool_change(it, code: int, col: int) -> None:
    """Before M6 (``code`` 6) / M61: M6 is refused under compensation; LinuxCNC re-reads
    where the machine is after a tool change (where G40 left the tool)."""
    if code == 6:
        refuse_while_on(it, "change tools", col)
    if it.tool_pos is not None:
        it.pos, it.tool_pos = list(it.tool_pos), None


def dwell(it, seconds: float) -> None:
    """G4: a dwell under compensation waits behind the held moves."""
    if it.comp_engine is not None:
        it.comp_engine.dwell(seconds)
    else:
        it.emit(MoveKind.DWELL, it.pos, it.pos, dwell=seconds)


def stop(it) -> list:
    """M0 M1 M2 M30 M60: LinuxCNC emits what compensation holds at every stop.
    Returns the machine position of the tool."""
    if it.comp_engine is None:
        return list(it.pos)
    it.comp_engine.stop()
    return list(it.comp_engine.tool)


def row_ends(it, kind: int, start, end) -> tuple:
    """(start, end) of a row made while the tool is not at the program position (``it.tool_pos``,
    just after G40): the first motion starts from the tool; a dwell or stop happens there."""
    if kind in (MoveKind.DWELL, MoveKind.TOOL_CHANGE, MoveKind.PAUSE, MoveKind.END):
        return it.tool_pos, it.tool_pos
    start, it.tool_pos = it.tool_pos, None
    return start, end


def turn_on(it, code: int, words, cols, used, col: int):
    """G41 / G42 / G41.1 / G42.1 (``code`` in tenths) for interpreter ``it``.

    Returns the engine that offsets the following moves, or None for a zero radius (the
    moves then run as programmed). Raises LineError as LinuxCNC refuses the line."""
    if it.plane not in COMP_PLANES:
        raise LineError("cutter radius compensation is allowed only in the XY (G17) and XZ (G18) planes", col)
    if it.comp != 400:
        raise LineError("cannot turn cutter radius compensation on when it is already on", col)
    name = f"G{code / 10:g}"
    if code in (411, 421):  # dynamic: D is the diameter, L the lathe tool orientation
        if "D" not in words:
            raise LineError(f"{name} needs a D word (tool diameter)", col)
        used.add("D")
        radius = words["D"] * it.factor / 2.0
        orientation = 0
        if "L" in words:
            used.add("L")
            if it.plane != 180:
                raise LineError(f"{name} with an L word (lathe tool orientation) needs the XZ plane (G18)",
                                cols["L"])
            orientation = int(words["L"])
    else:
        if "D" in words and abs(words["D"] - round(words["D"])) > 1e-4:
            raise LineError(f"{name} needs a whole D word (a tool number), got D{words['D']:g}", cols["D"])
        if words.get("D") == 0:  # D0 names the tool in the spindle, like no D word (LinuxCNC)
            used.add("D")
            entry = it.tool_table.get(it.tool) if it.tool else None
        else:
            entry = it._tool_word_entry("D", words, cols, used, col)
        radius = 0.0 if entry is None else entry.diameter / 2.0
        orientation = (entry.orientation or 0) if entry is not None else 0
        if orientation not in (0, 9) and it.plane != 180:
            raise LineError(f"{name} with a lathe tool (orientation {orientation}) needs the XZ plane (G18)", col)
    left = code in (410, 411)
    if radius < 0.0:  # a negative diameter (worn below nominal) offsets to the other side
        radius, left = -radius, not left
    it.comp = 410 if left else 420
    it.comp_radius = radius
    return CompEngine(it, left, radius, orientation) if radius > 0.0 else None


def turn_off(it) -> None:
    """G40: emit what the engine holds; the tool stays where compensation left it."""
    eng = it.comp_engine
    made = eng is not None and eng.finish()   # may refuse (a gouge): compensation then stays on
    it.comp_engine = None
    it.comp = 400
    it.comp_radius = 0.0
    if made:
        it.tool_pos = eng.tool
        it.arc_not_allowed = True


def find_turn(p, c, turn: int, q) -> float:
    """Signed sweep (rad, + CCW) of an arc from ``p`` to ``q`` around ``c`` making
    ``turn`` turns (+ CCW, - CW); LinuxCNC's ``find_turn``."""
    if turn == 0:
        return 0.0
    alpha = math.atan2(p[1] - c[1], p[0] - c[0])
    beta = math.atan2(q[1] - c[1], q[0] - c[0])
    if turn > 0:
        if beta <= alpha:
            beta += TWO_PI
        return beta - alpha + (turn - 1) * TWO_PI
    if alpha <= beta:
        alpha += TWO_PI
    return beta - alpha + (turn + 1) * TWO_PI


@dataclass
class _Held:
    """A row waiting for the next move: its end (and an arc's sweep) may still change."""

    kind: int                # MoveKind
    end: list                # work position (6), mm; the plane coordinates are compensated
    feed: float
    inverse: float
    meta: tuple              # the row attributes of the line that made it
    center: tuple = ()       # arc: plane (first, second) centre
    turn: int = 0            # arc: signed turns, + CCW
    sweep: float = 0.0       # arc: sweep as made (rad); 0 for a corner arc, whose end never moves
    direction: tuple = (0.0, 0.0)  # line: plane direction it was made in (to see it reversed)
    dwell: float = 0.0       # DWELL rows: seconds

    @property
    def arc(self) -> bool:
        return self.kind in (MoveKind.ARC_CW, MoveKind.ARC_CCW)


class CompEngine:
    """Offsets the moves of interpreter ``it`` by ``radius`` (mm, > 0) to the left or right
    of the programmed path in the current plane; ``orientation`` is a lathe tool's (0 mill)."""

    def __init__(self, it, left: bool, radius: float, orientation: int = 0):
        self.it = it
        self.left = left
        self.radius = radius
        self.orientation = orientation
        self.i1, self.i2, self.i3 = PLANE_AXES_BY_CODE[COMP_PLANES[it.plane]]
        self.first = True          # the entry move is still to come
        self.cur = None            # plane position of the tool after the last move made
        self._held: list[_Held] = []
        self.endpoint = None       # plane point where the first held move starts (None: unknown)
        self.tool = list(it.pos)   # machine position at the end of the last emitted row
        self.col = 1               # column of the line being converted (for errors)

    def __deepcopy__(self, memo):
        """A copy for the interpreter's checkpoint of a streamed line: its own held moves,
        the same interpreter."""
        twin = copy.copy(self)
        twin._restore(self._saved())
        return twin

    # ------------------------------------------------------------------ programmed moves
    def straight(self, target, rapid: bool, col: int, words=None, entry_allowed: bool = True) -> None:
        """A programmed G0 (``rapid``) or G1 to work position ``target`` (6); G33/G33.1 come
        here as G1 too (``entry_allowed`` False: LinuxCNC refuses them as the entry move)."""
        it = self.it
        self.col = col
        if self.first and not entry_allowed:
            raise LineError("the cutter compensation entry move must be G0 or G1", col)
        prog = it.work()
        length = math.dist(prog[:3], target[:3])
        feed, inv = (0.0, 0.0) if rapid else it._feed_rate(col, words or {}, length)
        kind = MoveKind.RAPID if rapid else MoveKind.FEED
        saved = self._saved()
        try:
            if self.first:
                self._entry_line(kind, prog, target, feed, inv)
            else:
                self._line(kind, prog, target, feed, inv)
        except LineError:
            self._restore(saved)
            raise
        it.pos = it.to_machine(target)

    def arc(self, cw: bool, target, center, turns: int, col: int, words) -> None:
        """A programmed G2 (``cw``) / G3 to work ``target`` around plane ``center``
        (first, second), making ``turns`` turns."""
        it = self.it
        self.col = col
        prog = it.work()
        start = (prog[self.i1], prog[self.i2])
        turn = -turns if cw else turns
        sweep = find_turn(start, center, turn, (target[self.i1], target[self.i2]))
        r0 = math.dist(start, center)
        feed, inv = it._feed_rate(col, words, math.hypot(r0 * sweep, target[self.i3] - prog[self.i3]))
        saved = self._saved()
        try:
            if self.first:
                self._entry_arc(prog, target, center, turn, feed, inv)
            else:
                self._arc(prog, target, center, turn, feed, inv)
        except LineError:
            self._restore(saved)
            raise
        it.pos = it.to_machine(target)

    def dwell(self, seconds: float) -> None:
        """G4: waits behind the held moves (it happens after them)."""
        if self._held:
            self._held.append(_Held(MoveKind.DWELL, [], 0.0, 0.0, self.it.meta(), dwell=seconds))
        else:
            self.it.emit(MoveKind.DWELL, self.tool, self.tool, dwell=seconds)

    def stop(self) -> None:
        """M0 M1 M2 M30 M60: emit what is held (compensation stays on)."""
        if self.cur is not None:
            self._move_endpoint_and_flush(self.cur)
        self._flush()

    def holds_moves(self) -> bool:
        """Moves wait for the next one (they are lost if the program ends here without M2)."""
        return self._front() is not None

    def finish(self) -> bool:
        """G40: emit what is held. True when a compensated move was made (then the tool is
        off the program position and the next move must be straight)."""
        self.stop()
        return self.cur is not None

    # ------------------------------------------------------------------ entry moves
    def _entry_line(self, kind, prog, target, feed, inv) -> None:
        r = self.radius
        cx, cy = prog[self.i1], prog[self.i2]
        px, py = target[self.i1], target[self.i2]
        dist = math.hypot(px - cx, py - cy)
        if dist <= r:
            u = self.it.factor
            raise LineError(f"length of cutter compensation entry move ({dist / u:.4f}) is not greater than "
                            f"the tool radius ({r / u:.4f})", self.col)
        alpha = math.atan2(py - cy, px - cx) + (HALF_PI if self.left else -HALF_PI)
        end = (px + r * math.cos(alpha), py + r * math.sin(alpha))
        self.endpoint = (cx, cy)
        # LinuxCNC records the offset direction, not the move's, for its gouge check
        self._hold(kind, target, end, feed, inv, direction=(math.cos(alpha), math.sin(alpha)))
        self.first = False
        self.cur = end

    def _entry_arc(self, prog, target, center, turn, feed, inv) -> None:
        r = self.radius
        cx, cy = prog[self.i1], prog[self.i2]
        ex, ey = target[self.i1], target[self.i2]
        if math.hypot(ex - cx, ey - cy) <= r:
            raise LineError("radius of cutter compensation entry arc is not greater than the tool radius", self.col)
        if self._inside(turn):
            self._check_fits(math.dist((cx, cy), center))
            gamma = math.atan2(center[1] - ey, center[0] - ex)
        else:
            gamma = math.atan2(ey - center[1], ex - center[0])
        end = (ex + r * math.cos(gamma), ey + r * math.sin(gamma))
        # re-centre: the new centre is on the line from the new end through the programmed
        # centre, as far from the start as from the new end
        half_chord = math.hypot(cy - end[1], cx - end[0]) / 2.0
        to_center = math.atan2(center[1] - end[1], center[0] - end[0])
        a_ang = math.atan2(cy - end[1], cx - end[0]) - to_center
        if abs(math.cos(a_ang)) < COS_TOL:
            self._check_fits(0.0)
        c_len = half_chord / math.cos(a_ang)
        new_center = (end[0] + c_len * math.cos(to_center), end[1] + c_len * math.sin(to_center))
        self.first = False
        if self.orientation not in (0, 9):
            # a lathe tool's controlled point first moves to the start (else no arc)
            self._hold(MoveKind.FEED, self._plane_point(target, (cx, cy), prog[self.i3]), (cx, cy), feed, inv)
            self.endpoint = (cx, cy)
        self._hold_arc(target, end, new_center, turn, find_turn((cx, cy), new_center, turn, end), feed, inv)
        self.cur = end

    # ------------------------------------------------------------------ later moves
    def _line(self, kind, prog, target, feed, inv) -> None:
        r = self.radius
        opx, opy = prog[self.i1], prog[self.i2]
        px, py = target[self.i1], target[self.i2]
        cx, cy = self.cur
        if px == opx and py == opy:  # no motion in the plane: the tool keeps its plane position
            self._hold(kind, target, (cx, cy), feed, inv)
            return
        theta = math.atan2(cy - opy, cx - opx)   # from the programmed point to the tool
        alpha = math.atan2(py - opy, px - opx)   # direction of the new move
        if self.left:
            if theta < alpha:
                theta += TWO_PI
            beta = theta - alpha - HALF_PI
            gamma = HALF_PI
        else:
            if alpha < theta:
                alpha += TWO_PI
            beta = alpha - theta - HALF_PI
            gamma = -HALF_PI
        nx, ny = math.cos(alpha + gamma), math.sin(alpha + gamma)
        end = (px + r * nx, py + r * ny)
        front = self._front()
        concave = beta < -CORNER_TOL or beta > math.pi + CORNER_TOL
        if not concave and beta > math.pi - CORNER_TOL and front is not None and front.arc \
                and not self._inside(front.turn):
            # the "h" shape: leaving an arc the tool was outside of, going back along it;
            # LinuxCNC stays on this side rather than loop around
            concave = True
        if concave:
            if front is None or not front.arc:
                half_corner = (beta + math.pi) / 2.0
                if half_corner == 0.0:
                    raise LineError("zero degree inside corner is invalid for cutter compensation", self.col)
                retreat = r / math.tan(half_corner)   # back along the previous compensated line
                meet = (cx + retreat * math.cos(theta + gamma), cy + retreat * math.sin(theta + gamma))
            else:
                meet = self._arc_meets_line(front, (opx, opy), (px, py))
            self._move_endpoint_and_flush(meet)
        elif beta > CORNER_TOL:  # convex: round the programmed corner
            self._move_endpoint_and_flush((cx, cy))
            mid = (opx + r * nx, opy + r * ny)
            corner_end = self._plane_point(target, mid, prog[self.i3])
            if kind == MoveKind.RAPID:  # there is no arc traverse: a straight rapid to the arc's end
                self._hold(MoveKind.RAPID, corner_end, mid, 0.0, 0.0)
            else:
                self._hold_arc(corner_end, mid, (opx, opy), -1 if self.left else 1, 0.0, feed, inv)
            self._flush()
            self.endpoint = mid
        else:  # straight on (or tangent)
            self._flush()
            self.endpoint = (cx, cy)
        self._hold(kind, target, end, feed, inv, direction=(px - opx, py - opy))
        self.cur = end

    def _arc(self, prog, target, center, turn, feed, inv) -> None:
        r = self.radius
        opx, opy = prog[self.i1], prog[self.i2]
        ex, ey = target[self.i1], target[self.i2]
        cx, cy = self.cur
        arc_radius = math.hypot(center[0] - ex, center[1] - ey)
        theta = math.atan2(cy - opy, cx - opx) + (-HALF_PI if self.left else HALF_PI)  # previous direction
        delta = math.atan2(center[1] - opy, center[0] - opx)
        alpha = delta - HALF_PI if turn > 0 else delta + HALF_PI   # the arc's start direction
        beta = theta - alpha if self.left else alpha - theta
        if beta > 1.5 * math.pi:
            beta -= TWO_PI
        elif beta < -HALF_PI:
            beta += TWO_PI
        inside = self._inside(turn)
        if inside:
            gamma = math.atan2(center[1] - ey, center[0] - ex)
            self._check_fits(arc_radius)
        else:
            gamma = math.atan2(ey - center[1], ex - center[0])
            delta += math.pi
        end = (ex + r * math.cos(gamma), ey + r * math.sin(gamma))
        sweep = find_turn((opx, opy), center, turn, (ex, ey))
        front = self._front()
        if beta < -CORNER_TOL or beta > math.pi + CORNER_TOL or (abs(beta - math.pi) < CORNER_TOL and not inside):
            if front is None or not front.arc:
                meet = self._line_meets_arc(center, arc_radius, theta, beta, turn)
            else:
                meet = self._arc_meets_arc(front, center, arc_radius, turn)
            self._move_endpoint_and_flush(meet)
        elif beta > CORNER_TOL:  # convex: round the programmed corner first
            mid = (opx + r * math.cos(delta), opy + r * math.sin(delta))
            self._flush()
            self._hold_arc(self._plane_point(target, mid, prog[self.i3]), mid, (opx, opy),
                           -1 if self.left else 1, 0.0, feed, inv)
            self._flush()
            self.endpoint = mid
        else:
            self._flush()
            self.endpoint = (cx, cy)
        self._hold_arc(target, end, center, turn, sweep, feed, inv)
        self.cur = end

    # ------------------------------------------------------------------ concave corners
    def _arc_meets_line(self, prev: _Held, op, p):
        """Where the held compensated arc ``prev`` meets the compensated line from ``op`` to ``p``."""
        r = self.radius
        oldrad = math.dist(prev.center, self._plane(prev.end))
        base_dir = math.atan2(p[1] - op[1], p[0] - op[0])
        theta = base_dir + HALF_PI if prev.turn > 0 else base_dir - HALF_PI
        phi = math.atan2(prev.center[1] - op[1], prev.center[0] - op[0])
        inside = self._inside(prev.turn)
        programmed_radius = oldrad + r if inside else oldrad - r
        d = programmed_radius * math.cos(theta - phi)   # old centre to the new line, across it
        ratio = (d - r if inside else d + r) / oldrad
        if not -1.0 <= ratio <= 1.0:
            raise LineError("arc to straight motion makes a corner the compensated tool can't fit in "
                            "without gouging", self.col)
        turn_sign = 1 if prev.turn > 0 else -1
        ang = theta + math.pi + (-turn_sign if inside else turn_sign) * math.acos(ratio)
        return (prev.center[0] + oldrad * math.cos(ang), prev.center[1] + oldrad * math.sin(ang))

    def _line_meets_arc(self, center, arc_radius, theta, beta, turn):
        """Where the held compensated line meets the compensated arc around ``center``."""
        r = self.radius
        across = arc_radius * math.sin(beta - HALF_PI)
        if self._inside(turn):
            dist = arc_radius - r
            ratio = (across + r) / dist
            self._check_reach(ratio)
            ang = theta + math.asin(ratio) if turn > 0 else theta - math.asin(ratio)
        else:
            dist = arc_radius + r
            ratio = (across - r) / dist
            self._check_reach(ratio)
            ang = theta + math.pi - math.asin(ratio) if turn > 0 else theta + math.pi + math.asin(ratio)
        return (center[0] + dist * math.cos(ang), center[1] + dist * math.sin(ang))

    def _arc_meets_arc(self, prev: _Held, center, arc_radius, turn):
        """Where the held compensated arc ``prev`` meets the next compensated arc."""
        oldrad = math.dist(prev.center, self._plane(prev.end))
        newrad = arc_radius - self.radius if self._inside(turn) else arc_radius + self.radius
        arc_cc = math.dist(prev.center, center)
        if oldrad == 0.0 or arc_cc == 0.0:
            raise LineError("arc to arc motion is invalid because the arcs have the same center", self.col)
        a = (oldrad ** 2 + arc_cc ** 2 - newrad ** 2) / (2 * oldrad * arc_cc)
        if not -1.0 <= a <= 1.0:
            raise LineError("arc to arc motion makes a corner the compensated tool can't fit in without gouging",
                            self.col)
        pullback = math.acos(a)
        cc_dir = math.atan2(center[1] - prev.center[1], center[0] - prev.center[0])
        same = (turn > 0) == self._inside(prev.turn)
        direction = cc_dir + pullback if same else cc_dir - pullback
        return (prev.center[0] + oldrad * math.cos(direction), prev.center[1] + oldrad * math.sin(direction))

    def _move_endpoint_and_flush(self, point) -> None:
        """Move the end of every held move to plane ``point``, emit them; the next move starts
        there. Refuses a corner the tool cannot reach (a held move would turn back)."""
        if not self._held:
            return
        it = self.it
        for h in self._held:
            if h.kind == MoveKind.DWELL:
                continue
            if h.arc:
                r1 = math.dist(self._plane(h.end), h.center)
                r2 = math.dist(point, h.center)
                if abs(r1 - r2) > RADII_TOL * it.factor:
                    raise LineError(f"cutter compensation made an arc whose radii differ ({r1 / it.factor:.4f} "
                                    f"and {r2 / it.factor:.4f})", self.col)
                if h.sweep != 0.0 and self.endpoint is not None:
                    new_sweep = find_turn(self.endpoint, h.center, h.turn, point)
                    # LinuxCNC's margin, in radians, depends on the program units
                    if abs(new_sweep) > abs(h.sweep) + (0.0254 if it.units == 210 else 0.001):
                        raise LineError("arc move in concave corner cannot be reached by the tool without "
                                        "gouging", self.col)
            elif self.endpoint is not None:
                dx, dy = point[0] - self.endpoint[0], point[1] - self.endpoint[1]
                if h.direction[0] * dx + h.direction[1] * dy < 0:
                    what = "straight traverse" if h.kind == MoveKind.RAPID else "straight feed"
                    raise LineError(f"{what} in concave corner cannot be reached by the tool without gouging",
                                    self.col)
            h.end[self.i1], h.end[self.i2] = point
        self._flush()
        self.endpoint = point

    # ------------------------------------------------------------------ the held queue
    def _saved(self) -> tuple:
        """The engine's state before a line: a refused line leaves it as it was (the
        interpreter drops the rows the line made, and may go on with the next line)."""
        return (self.first, self.cur, self.endpoint, self.tool, [replace(h, end=list(h.end)) for h in self._held])

    def _restore(self, saved: tuple) -> None:
        self.first, self.cur, self.endpoint, self.tool, self._held = saved

    def _inside(self, turn: int) -> bool:
        """The tool is on the centre side of an arc turning ``turn`` (LinuxCNC TOOL_INSIDE_ARC)."""
        return (self.left and turn > 0) or (not self.left and turn < 0)

    def _check_fits(self, arc_radius: float) -> None:
        if arc_radius <= self.radius:
            u = self.it.factor
            raise LineError(f"tool radius ({self.radius / u:.4f}) is not less than the arc radius "
                            f"({arc_radius / u:.4f}) with cutter compensation", self.col)

    def _check_reach(self, ratio: float) -> None:
        if not -1.0 <= ratio <= 1.0:
            raise LineError("arc move in concave corner cannot be reached by the tool without gouging", self.col)

    def _plane(self, w) -> tuple:
        return (w[self.i1], w[self.i2])

    def _plane_point(self, target, point, normal: float) -> list:
        """``target`` with plane coordinates ``point`` and normal coordinate ``normal``."""
        w = list(target)
        w[self.i1], w[self.i2] = point
        w[self.i3] = normal
        return w

    def _front(self):
        return next((h for h in self._held if h.kind != MoveKind.DWELL), None)

    def _hold(self, kind, target, point, feed, inv, direction=(0.0, 0.0)) -> None:
        end = list(target)
        end[self.i1], end[self.i2] = point
        self._held.append(_Held(kind, end, feed, inv, self.it.meta(), direction=direction))

    def _hold_arc(self, target, point, center, turn, sweep, feed, inv) -> None:
        end = list(target)
        end[self.i1], end[self.i2] = point
        kind = MoveKind.ARC_CCW if turn > 0 else MoveKind.ARC_CW
        self._held.append(_Held(kind, end, feed, inv, self.it.meta(), center=tuple(center), turn=turn,
                                sweep=sweep))

    def _flush(self) -> None:
        for h in self._held:
            self._emit(h)
        self._held.clear()
        self.endpoint = None

    def _emit(self, h: _Held) -> None:
        it = self.it
        if h.kind == MoveKind.DWELL:
            it.emit(MoveKind.DWELL, self.tool, self.tool, dwell=h.dwell, meta=h.meta)
            return
        shift = self._lathe_shift()
        w = list(h.end)
        w[0] += shift[0]
        w[2] += shift[2]
        end = it.to_machine(w)
        if h.arc:
            off = it.offsets()
            center = [0.0, 0.0, 0.0]
            center[self.i1] = h.center[0] + shift[self.i1] + off[self.i1]
            center[self.i2] = h.center[1] + shift[self.i2] + off[self.i2]
            center[self.i3] = self.tool[self.i3]
            it.emit(h.kind, self.tool, end, tuple(center), abs(h.turn), h.feed, h.inverse, meta=h.meta)
        else:
            it.emit(h.kind, self.tool, end, feed=h.feed, inverse=h.inverse, meta=h.meta)
        self.tool = end

    def _lathe_shift(self) -> tuple:
        """(X, Y, Z) from the radius centre to a lathe tool's controlled point (mm)."""
        sx, sz = LATHE_SHIFTS.get(self.orientation, (0, 0)) if self.i1 == 2 else (0, 0)
        return (sx * self.radius, 0.0, sz * self.radius)
