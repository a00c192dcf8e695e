"""Cutter radius compensation G41/G42 in the XY plane, following LinuxCNC.

* Entry (first XY move after G41/G42): a straight move ends at the point of the
  circle of tool radius around the programmed end where the move is tangent to it
  (the move must be longer than the radius); an arc keeps passing through the current
  point and ends one radius off the programmed end, its centre moved along the line
  from that end to the programmed centre (LinuxCNC's ``convert_arc_comp1``).
* Then every element is offset by the radius to the left (G41) or right (G42) of the
  programmed path: lines shift along their normal, arcs keep their centre and change
  radius. At an outside (convex) corner the tool rolls around the programmed corner
  on an arc of the tool radius; at an inside (concave) corner the previous element is
  cut back to its intersection with the next one (the previous element is held back
  until the next one is known, as LinuxCNC's queue does).
* G40 emits what is held; the next move starts from the compensated position.

Everything here is work coordinates (mm) of the active system.
"""

from __future__ import annotations

import math

from sim.gcode.errors import LineError
from sim.gcode.moves import MoveKind

EPS_ANGLE = 1e-9


def _wrap(a: float) -> float:
    """Angle in (-pi, pi]."""
    a = math.fmod(a + math.pi, 2 * math.pi)
    if a <= 0:
        a += 2 * math.pi
    return a - math.pi


class _El:
    __slots__ = ("arc", "rapid", "cw", "s", "e", "c", "r", "w0", "w1", "turns", "feed", "inv", "meta",
                 "dir0", "dir1", "xy")

    def __init__(self, **kw):
        self.arc = False
        self.c = None
        self.r = 0.0
        self.turns = 1
        self.cw = False
        for k, v in kw.items():
            setattr(self, k, v)


def _line_circle(p, d, c, r):
    """Points where the infinite line p + t d meets circle (c, r)."""
    fx, fy = p[0] - c[0], p[1] - c[1]
    a = d[0] * d[0] + d[1] * d[1]
    b = 2 * (fx * d[0] + fy * d[1])
    cc = fx * fx + fy * fy - r * r
    disc = b * b - 4 * a * cc
    if a == 0 or disc < 0:
        if a != 0 and disc > -1e-9:
            disc = 0.0
        else:
            return []
    sq = math.sqrt(disc)
    return [(p[0] + t * d[0], p[1] + t * d[1]) for t in ((-b - sq) / (2 * a), (-b + sq) / (2 * a))]


def _circle_circle(c0, r0, c1, r1):
    dx, dy = c1[0] - c0[0], c1[1] - c0[1]
    d = math.hypot(dx, dy)
    if d == 0 or d > r0 + r1 + 1e-9 or d < abs(r0 - r1) - 1e-9:
        return []
    a = (r0 * r0 - r1 * r1 + d * d) / (2 * d)
    h = math.sqrt(max(r0 * r0 - a * a, 0.0))
    mx, my = c0[0] + a * dx / d, c0[1] + a * dy / d
    return [(mx + h * dy / d, my - h * dx / d), (mx - h * dy / d, my + h * dx / d)]


class CompEngine:
    """Offsets the XY path of interpreter ``it`` by ``radius`` (mm) to the left or right."""

    def __init__(self, it, left: bool, radius: float):
        self.it = it
        self.left = left
        self.radius = radius
        self.side = 1.0 if left else -1.0   # normal = direction rotated by side * 90 degrees
        self.queue: list[_El] = []
        self.first = True
        self.tool_xy = None  # compensated XY of the tool (work), None before the entry move
        self.prog_xy = None

    # ------------------------------------------------------------------ helpers
    def _normal(self, ang: float):
        a = ang + self.side * math.pi / 2
        return math.cos(a), math.sin(a)

    def _arc_offset_radius(self, R: float, cw: bool) -> float:
        # the left of a CCW arc is its centre side
        toward_center = (self.left and not cw) or (not self.left and cw)
        return R - self.radius if toward_center else R + self.radius

    def _feed(self, words, length, col, rapid):
        if rapid:
            return 0.0, 0.0
        return self.it._feed_rate(col, words or {}, length)

    def _new(self, **kw) -> _El:
        el = _El(**kw)
        el.meta = self.it.meta()
        return el

    # ------------------------------------------------------------------ input
    def straight(self, target, rapid: bool, col: int, words=None) -> None:
        """A programmed straight move to work position ``target`` (6)."""
        it = self.it
        w0 = it.work()  # programmed start
        p0 = (w0[0], w0[1])
        p1 = (target[0], target[1])
        moved_xy = p0 != p1
        if self.radius == 0.0:
            self._direct(target, rapid, col, words)
            return
        if self.first:
            if not moved_xy:
                self._direct(target, rapid, col, words)
                return
            cx, cy = p0
            dist = math.hypot(p1[0] - cx, p1[1] - cy)
            if dist <= self.radius:
                raise LineError(
                    f"cutter compensation entry move ({dist / it.factor:.4f}) is not longer than the tool "
                    f"radius ({self.radius / it.factor:.4f})", col)
            alpha = math.atan2(p1[1] - cy, p1[0] - cx)
            theta = math.acos(self.radius / dist)
            gamma = alpha + math.pi - theta if self.left else alpha + math.pi + theta
            e = (p1[0] + self.radius * math.cos(gamma), p1[1] + self.radius * math.sin(gamma))
            direction = math.atan2(e[1] - cy, e[0] - cx)
            feed, inv = self._feed(words, dist, col, rapid)
            el = self._new(rapid=rapid, s=p0, e=e, w0=list(w0), w1=list(target), feed=feed, inv=inv,
                           dir0=direction, dir1=direction, xy=True)
            self.first = False
            self.queue.append(el)
        else:
            if not moved_xy:
                el = self._new(rapid=rapid, s=self.queue[-1].e if self.queue else self.tool_xy,
                               e=None, w0=list(w0), w1=list(target), feed=0.0, inv=0.0, dir0=None, dir1=None,
                               xy=False)
                el.e = el.s
                if not rapid:
                    el.feed, el.inv = self._feed(words, abs(target[2] - w0[2]), col, rapid)
                self.queue.append(el)
            else:
                ang = math.atan2(p1[1] - p0[1], p1[0] - p0[0])
                nx, ny = self._normal(ang)
                s = (p0[0] + self.radius * nx, p0[1] + self.radius * ny)
                e = (p1[0] + self.radius * nx, p1[1] + self.radius * ny)
                feed, inv = self._feed(words, math.dist(p0, p1), col, rapid)
                el = self._new(rapid=rapid, s=s, e=e, w0=list(w0), w1=list(target), feed=feed, inv=inv,
                               dir0=ang, dir1=ang, xy=True)
                self._join(el, col)
        it.pos = it.to_machine(target)

    def arc(self, cw: bool, target, center, turns: int, col: int, words) -> None:
        """A programmed arc to work ``target`` around work XY ``center``."""
        it = self.it
        w0 = it.work()
        p0 = (w0[0], w0[1])
        p1 = (target[0], target[1])
        c = center
        R = math.hypot(p0[0] - c[0], p0[1] - c[1])
        sgn = -1.0 if cw else 1.0
        if self.radius == 0.0:
            self._plain_arc(cw, target, c, turns, col, words)
            return
        if self.first:
            # LinuxCNC convert_arc_comp1
            if (self.left and not cw) or (not self.left and cw):
                if R <= self.radius:
                    raise LineError("tool radius is not less than the arc radius with cutter compensation", col)
                gamma = math.atan2(c[1] - p1[1], c[0] - p1[0])
            else:
                gamma = math.atan2(p1[1] - c[1], p1[0] - c[0])
            e = (p1[0] + self.radius * math.cos(gamma), p1[1] + self.radius * math.sin(gamma))
            b_len = math.hypot(p0[1] - e[1], p0[0] - e[0]) / 2.0
            ab = math.atan2(c[1] - e[1], c[0] - e[0])
            a_ang = math.atan2(p0[1] - e[1], p0[0] - e[0]) - ab
            if abs(math.cos(a_ang)) < 1e-4:
                raise LineError("tool radius is not less than the arc radius with cutter compensation", col)
            c_len = b_len / math.cos(a_ang)
            nc = (e[0] + c_len * math.cos(ab), e[1] + c_len * math.sin(ab))
            r_new = math.hypot(nc[0] - e[0], nc[1] - e[1])
            d0 = math.atan2(p0[1] - nc[1], p0[0] - nc[0]) + sgn * math.pi / 2
            d1 = math.atan2(e[1] - nc[1], e[0] - nc[0]) + sgn * math.pi / 2
            length = self._arc_len(p0, e, nc, cw, turns, target[2] - w0[2])
            feed, inv = self._feed(words, length, col, False)
            el = self._new(rapid=False, arc=True, cw=cw, s=p0, e=e, c=nc, r=r_new, w0=list(w0), w1=list(target),
                           turns=turns, feed=feed, inv=inv, dir0=d0, dir1=d1, xy=True)
            self.first = False
            self.queue.append(el)
        else:
            r_off = self._arc_offset_radius(R, cw)
            if r_off <= 0.0:
                raise LineError(
                    f"tool radius ({self.radius / it.factor:.4f}) is not less than the arc radius "
                    f"({R / it.factor:.4f}) with cutter compensation", col)
            a0 = math.atan2(p0[1] - c[1], p0[0] - c[0])
            a1 = math.atan2(p1[1] - c[1], p1[0] - c[0])
            s = (c[0] + r_off * math.cos(a0), c[1] + r_off * math.sin(a0))
            e = (c[0] + r_off * math.cos(a1), c[1] + r_off * math.sin(a1))
            length = self._arc_len(s, e, c, cw, turns, target[2] - w0[2])
            feed, inv = self._feed(words, length, col, False)
            el = self._new(rapid=False, arc=True, cw=cw, s=s, e=e, c=tuple(c), r=r_off, w0=list(w0),
                           w1=list(target), turns=turns, feed=feed, inv=inv,
                           dir0=a0 + sgn * math.pi / 2, dir1=a1 + sgn * math.pi / 2, xy=True)
            self._join(el, col)
        it.pos = it.to_machine(target)

    @staticmethod
    def _arc_len(s, e, c, cw, turns, dz):
        from sim.gcode.arcs import _sweep

        a0 = math.atan2(s[1] - c[1], s[0] - c[0])
        a1 = math.atan2(e[1] - c[1], e[0] - c[0])
        r = math.hypot(s[0] - c[0], s[1] - c[1])
        return math.hypot(r * _sweep(a0, a1, cw, turns), dz)

    # ------------------------------------------------------------------ corners
    def _join(self, el: _El, col: int) -> None:
        prev = next((q for q in reversed(self.queue) if q.xy), None)
        if prev is None:
            self.queue.append(el)
            return
        turn = _wrap(el.dir0 - prev.dir1)
        concave = turn * self.side > EPS_ANGLE
        gap = math.dist(prev.e, el.s)
        if gap < 1e-9:
            self._flush_queue()
            el.s = prev.e
        elif concave:
            x = self._intersect(prev, el)
            if x is None:
                self._flush_queue()
                self.queue.append(self._new(rapid=el.rapid, s=prev.e, e=el.s, w0=list(el.w0), w1=list(el.w0),
                                            feed=el.feed, inv=el.inv, dir0=el.dir0, dir1=el.dir0, xy=True))
            else:
                prev.e = x
                for q in self.queue[self.queue.index(prev) + 1:]:
                    q.s = q.e = x
                el.s = x
            self._flush_queue()
        else:
            self._flush_queue()
            # roll around the programmed corner (= prev's programmed end)
            corner = (el.w0[0], el.w0[1])
            arc = self._new(rapid=el.rapid, arc=True, cw=self.left, s=prev.e, e=el.s, c=corner, r=self.radius,
                            w0=list(el.w0), w1=list(el.w0), turns=1, feed=el.feed if not el.rapid else 0.0,
                            inv=el.inv, dir0=prev.dir1, dir1=el.dir0, xy=True)
            self._emit(arc)
        self.queue.append(el)

    def _intersect(self, a: _El, b: _El):
        """Intersection of a's and b's offset paths nearest to where they should meet."""
        near = ((a.e[0] + b.s[0]) / 2, (a.e[1] + b.s[1]) / 2)
        cands = []
        if not a.arc and not b.arc:
            d1 = (math.cos(a.dir1), math.sin(a.dir1))
            d2 = (math.cos(b.dir0), math.sin(b.dir0))
            den = d1[0] * d2[1] - d1[1] * d2[0]
            if abs(den) < 1e-12:
                return None
            t = ((b.s[0] - a.e[0]) * d2[1] - (b.s[1] - a.e[1]) * d2[0]) / den
            return (a.e[0] + t * d1[0], a.e[1] + t * d1[1])
        if not a.arc:
            cands = _line_circle(a.e, (math.cos(a.dir1), math.sin(a.dir1)), b.c, b.r)
        elif not b.arc:
            cands = _line_circle(b.s, (math.cos(b.dir0), math.sin(b.dir0)), a.c, a.r)
        else:
            cands = _circle_circle(a.c, a.r, b.c, b.r)
        if not cands:
            return None
        return min(cands, key=lambda p: math.dist(p, near))

    # ------------------------------------------------------------------ output
    def _flush_queue(self) -> None:
        for q in self.queue:
            self._emit(q)
        self.queue.clear()

    def _emit(self, el: _El) -> None:
        it = self.it
        w0 = list(el.w0)
        w1 = list(el.w1)
        w0[0], w0[1] = el.s
        w1[0], w1[1] = el.e
        start = it.to_machine(w0)
        end = it.to_machine(w1)
        if el.arc:
            off = it.offsets()
            center = (el.c[0] + off[0], el.c[1] + off[1], start[2])
            it.emit(MoveKind.ARC_CW if el.cw else MoveKind.ARC_CCW, start, end, center, el.turns, el.feed,
                    el.inv, meta=el.meta)
        else:
            it.emit(MoveKind.RAPID if el.rapid else MoveKind.FEED, start, end, feed=el.feed, inverse=el.inv,
                    meta=el.meta)
        self.tool_xy = el.e

    def _direct(self, target, rapid, col, words) -> None:
        it = self.it
        end = it.to_machine(target)
        if rapid:
            it._rapid_to(end)
        else:
            feed, inv = it._feed_rate(col, words or {}, math.dist(it.pos[:3], end[:3]))
            it._line_to(end, MoveKind.FEED, feed, inv)

    def _plain_arc(self, cw, target, c, turns, col, words) -> None:
        from sim.gcode.arcs import _sweep

        it = self.it
        w0 = it.work()
        off = it.offsets()
        end = it.to_machine(target)
        center = (c[0] + off[0], c[1] + off[1], it.pos[2])
        a0 = math.atan2(w0[1] - c[1], w0[0] - c[0])
        a1 = math.atan2(target[1] - c[1], target[0] - c[0])
        r = math.hypot(w0[0] - c[0], w0[1] - c[1])
        length = math.hypot(r * _sweep(a0, a1, cw, turns), target[2] - w0[2])
        feed, inv = it._feed_rate(col, words, length)
        it.emit(MoveKind.ARC_CW if cw else MoveKind.ARC_CCW, list(it.pos), end, center, turns, feed, inv)
        it.pos = end

    def flush(self) -> None:
        """G40 / program end: emit what is held; the tool stays where it is."""
        self._flush_queue()
        it = self.it
        if self.tool_xy is not None:
            w = it.work()
            w[0], w[1] = self.tool_xy
            it.pos = it.to_machine(w)
