"""Find the machine in the program: which move it is on and how far along (pure numpy).

The program is flattened into a polyline (:class:`ProgramPath`): arcs become chords, every
segment keeps its move-table row and its span of *program time* (seconds from the start at
programmed feeds). Progress is a program time, so it is monotone along the program and the
lead time of anything ahead is a difference of progresses.

:class:`ProgramSync` follows live positions along that path:

* when the controller reports a line number, the machine is on that line's segments;
* otherwise it looks for the nearest point in a window of program time just around the
  last progress, takes the *earliest* candidate within the noise band (so a tool going
  back up along its plunge is not mistaken for the plunge), and never moves backwards by
  noise;
* when nothing in the window is near (a jump: the run started mid-program, the operator
  skipped ahead, or sync was lost) it searches the whole path and re-anchors.

Feed hold and overrides need nothing special: the position stops or runs faster and the
window, sized by elapsed time, follows.

Rotary machines: with ``rotary_scale`` (mm per degree) the path's points are 6-D, the
tip's X Y Z and the work angles A B C times the scale, and positions are given the same
way, so a move that turns only A is a segment like any other (not a point) and the sync
follows it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.gcode.moves import MoveKind, Plane

#: rapid rate assumed by :func:`row_seconds` when the program gives none, mm/min
DEFAULT_RAPID_RATE = 5000.0


def row_seconds(moves: np.ndarray, rapid_rate: float = DEFAULT_RAPID_RATE,
                position: str = "work") -> np.ndarray:
    """Programmed duration of every row, float64 (n,), s (length / feed; dwell rows their dwell).

    Accelerations are ignored; a better estimate (``Program.cycle_time``) can be used
    instead wherever it exists. ``position`` picks work coordinates (``start/end - wco``) or
    the machine ``start/end`` columns.
    """
    lengths = row_lengths(moves, position)
    # the rotaries' degrees count as mm, as the timing counts them (sim.gcode.timing):
    # a row turning only A takes time (only rows that turn: 3-axis rows keep their length)
    p0, p1 = _ends(moves, position)
    turn = np.asarray(p1[:, 3:6] - p0[:, 3:6], np.float64)
    turning = np.any(turn != 0.0, axis=1)
    if turning.any():
        lengths = lengths.copy()
        lengths[turning] = np.hypot(lengths[turning], np.linalg.norm(turn[turning], axis=1))
    kind = moves["kind"]
    feed = np.where(kind == MoveKind.RAPID, rapid_rate, moves["feed"]).astype(np.float64)
    # G93 inverse time: the row takes 1/F minutes whatever its length
    inv = moves["inverse_time"] > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        secs = np.where(feed > 0, lengths / np.maximum(feed, 1e-9) * 60.0, 0.0)
        secs = np.where(inv, 60.0 / np.where(inv, moves["inverse_time"], 1.0), secs)
    secs = np.where(kind == MoveKind.DWELL, moves["dwell"], secs)
    return secs


def row_lengths(moves: np.ndarray, position: str = "work") -> np.ndarray:
    """Path length of every row, float64 (n,), mm (arcs by their true length, helix included)."""
    p0, p1 = _ends(moves, position)
    p0, p1 = p0[:, :3], p1[:, :3]
    lengths = np.linalg.norm(p1 - p0, axis=1)
    arc = np.isin(moves["kind"], (MoveKind.ARC_CW, MoveKind.ARC_CCW))
    for r in np.nonzero(arc)[0]:
        pts = _arc_points(moves[r], position, chord=0.01)
        lengths[r] = float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())
    return lengths


def _ends(moves: np.ndarray, position: str) -> tuple[np.ndarray, np.ndarray]:
    """(start, end) positions, each (n, 6) (or (6,) for one row), mm: work or machine."""
    if position == "work":
        return moves["start"] - moves["wco"], moves["end"] - moves["wco"]
    return moves["start"], moves["end"]


def _plane_axes(plane: int) -> tuple[int, int, int]:
    """(first, second, normal) axis indices for an arc plane, in the G17/G18/G19 sense."""
    return {Plane.XY: (0, 1, 2), Plane.XZ: (2, 0, 1), Plane.YZ: (1, 2, 0)}[Plane(int(plane))]


def _arc_points(row, position: str, chord: float) -> np.ndarray:
    """Points along one arc row, (k, 3) mm, first = start and last = end, chord error <= ``chord``."""
    s, e = _ends(row, position)
    p0 = np.asarray(s[:3], np.float64)
    p1 = np.asarray(e[:3], np.float64)
    c = np.asarray(row["center"], np.float64)
    if not np.all(np.isfinite(c)):
        return np.stack([p0, p1])
    if position == "work":  # the centre is stored in machine coords: shift by this row's offset
        c = c - np.asarray(row["wco"][:3], np.float64)
    i, j, k = _plane_axes(row["plane"])
    r0 = np.hypot(p0[i] - c[i], p0[j] - c[j])
    if r0 <= 1e-9:
        return np.stack([p0, p1])
    a0 = np.arctan2(p0[j] - c[j], p0[i] - c[i])
    a1 = np.arctan2(p1[j] - c[j], p1[i] - c[i])
    cw = int(row["kind"]) == MoveKind.ARC_CW
    turns = max(int(row["turns"]), 1)
    sweep = (a0 - a1) if cw else (a1 - a0)
    sweep = np.mod(sweep, 2 * np.pi)
    if sweep <= 1e-12:
        sweep = 2 * np.pi
    sweep += 2 * np.pi * (turns - 1)
    step = 2 * np.arccos(max(1.0 - chord / r0, -1.0)) if chord < r0 else np.pi / 2
    n = max(int(np.ceil(sweep / max(step, 1e-3))), 2)
    f = np.linspace(0.0, 1.0, n + 1)
    ang = a0 + (-sweep if cw else sweep) * f
    r1 = np.hypot(p1[i] - c[i], p1[j] - c[j])
    rad = r0 + (r1 - r0) * f  # tolerate slightly unequal radii as a spiral
    pts = np.empty((n + 1, 3))
    pts[:, i] = c[i] + rad * np.cos(ang)
    pts[:, j] = c[j] + rad * np.sin(ang)
    pts[:, k] = p0[k] + (p1[k] - p0[k]) * f
    pts[0], pts[-1] = p0, p1
    return pts


@dataclass
class ProgramPath:
    """The program as a polyline of ``m`` segments with program time and length along it.

    Attributes
    ----------
    p0, p1 : float64 (m, 3), or (m, 6) with ``rotary_scale``
        Segment ends, mm (tool tip, work coordinates by default; then A B C deg times
        the scale).
    row : int64 (m,)
        Move-table row of each segment.
    t0, t1 : float64 (m,)
        Program time at the segment's ends, s from the program start.
    s0, s1 : float64 (m,)
        Path length at the segment's ends, mm.
    row_t0, row_t1 : float64 (n,)
        Program time at each row's start and end, s.
    lines : int32 (n,)
        Source line of each row.
    """

    p0: np.ndarray
    p1: np.ndarray
    row: np.ndarray
    t0: np.ndarray
    t1: np.ndarray
    s0: np.ndarray
    s1: np.ndarray
    row_t0: np.ndarray
    row_t1: np.ndarray
    lines: np.ndarray

    @classmethod
    def from_moves(cls, moves: np.ndarray, seconds: np.ndarray | None = None, chord: float = 0.05,
                   position: str = "work", rotary_scale: float | None = None) -> "ProgramPath":
        """Flatten a move table (MOVE_DTYPE, n rows); ``seconds`` (n,) per row or estimated.

        ``rotary_scale``: mm per degree; given, the points get the A B C columns times it
        (6-D, see the module docstring)."""
        n = len(moves)
        secs = row_seconds(moves, position=position) if seconds is None else np.asarray(seconds, np.float64)
        if secs.shape != (n,):
            raise ValueError(f"seconds must have shape ({n},), got {secs.shape}")
        s, e = _ends(moves, position)
        # tip = controlled point minus the G43 length in the machine columns
        lift = np.zeros((n, 3))
        if position == "machine":
            lift[:, 2] = moves["tool_length"]
        starts = np.asarray(s[:, :3], np.float64) - lift
        ends = np.asarray(e[:, :3], np.float64) - lift
        if rotary_scale is not None:
            starts = np.hstack([starts, rotary_scale * np.asarray(s[:, 3:6], np.float64)])
            ends = np.hstack([ends, rotary_scale * np.asarray(e[:, 3:6], np.float64)])
            lift = np.hstack([lift, np.zeros((n, 3))])
        row_t1 = np.cumsum(secs)
        row_t0 = row_t1 - secs
        arc = np.isin(moves["kind"], (MoveKind.ARC_CW, MoveKind.ARC_CCW))
        pieces_p0, pieces_p1, pieces_row, pieces_f0, pieces_f1 = [starts], [ends], [np.arange(n)], \
            [np.zeros(n)], [np.ones(n)]
        keep = ~arc
        for r in np.nonzero(arc)[0]:
            pts = _arc_points(moves[r], position, chord)
            k = len(pts) - 1
            f = np.linspace(0.0, 1.0, k + 1)
            if rotary_scale is not None:  # the angles turn evenly along the arc
                pts = np.hstack([pts, starts[r, 3:] + f[:, None] * (ends[r, 3:] - starts[r, 3:])])
            pts = pts - lift[r]
            pieces_p0.append(pts[:-1])
            pieces_p1.append(pts[1:])
            pieces_row.append(np.full(k, r))
            pieces_f0.append(f[:-1])
            pieces_f1.append(f[1:])
        p0 = np.concatenate([pieces_p0[0][keep]] + pieces_p0[1:])
        p1 = np.concatenate([pieces_p1[0][keep]] + pieces_p1[1:])
        row = np.concatenate([pieces_row[0][keep]] + pieces_row[1:]).astype(np.int64)
        f0 = np.concatenate([pieces_f0[0][keep]] + pieces_f0[1:])
        f1 = np.concatenate([pieces_f1[0][keep]] + pieces_f1[1:])
        order = np.lexsort((f0, row))
        p0, p1, row, f0, f1 = p0[order], p1[order], row[order], f0[order], f1[order]
        t0 = row_t0[row] + f0 * secs[row]
        t1 = row_t0[row] + f1 * secs[row]
        seg_len = np.linalg.norm(p1 - p0, axis=1)
        s1 = np.cumsum(seg_len)
        s0 = s1 - seg_len
        return cls(p0, p1, row, t0, t1, s0, s1, row_t0, row_t1, np.asarray(moves["line"], np.int32))

    @property
    def duration(self) -> float:
        """Program time of the whole path, s."""
        return float(self.row_t1[-1]) if self.row_t1.size else 0.0

    def __len__(self) -> int:
        return int(self.row.size)

    def segment_at(self, progress: float) -> int:
        """Index of the segment holding program time ``progress`` (clamped to the path)."""
        k = int(np.searchsorted(self.t1, progress, side="left"))
        return min(max(k, 0), len(self) - 1)

    def point_at(self, progress: float) -> np.ndarray:
        """Tip position at program time ``progress``, (3,) mm."""
        k = self.segment_at(progress)
        dt = self.t1[k] - self.t0[k]
        f = 0.0 if dt <= 0 else float(np.clip((progress - self.t0[k]) / dt, 0.0, 1.0))
        return self.p0[k] + f * (self.p1[k] - self.p0[k])

    def length_at(self, progress: float) -> float:
        """Path length travelled at program time ``progress``, mm."""
        k = self.segment_at(progress)
        dt = self.t1[k] - self.t0[k]
        f = 0.0 if dt <= 0 else float(np.clip((progress - self.t0[k]) / dt, 0.0, 1.0))
        return float(self.s0[k] + f * (self.s1[k] - self.s0[k]))

    def progress_at_length(self, s: float) -> float:
        """Program time where the path length reaches ``s`` mm (clamped)."""
        k = min(int(np.searchsorted(self.s1, s, side="left")), len(self) - 1)
        ds = self.s1[k] - self.s0[k]
        f = 0.0 if ds <= 0 else float(np.clip((s - self.s0[k]) / ds, 0.0, 1.0))
        return float(self.t0[k] + f * (self.t1[k] - self.t0[k]))

    def project(self, point: np.ndarray, lo: int = 0, hi: int | None = None):
        """Nearest points on segments ``lo..hi-1`` to ``point`` (3,).

        Returns ``(dist (k,) mm, progress (k,) s)`` for those segments, in segment order.
        """
        hi = len(self) if hi is None else hi
        return self._project(point, slice(lo, hi))

    def project_segments(self, point: np.ndarray, segs: np.ndarray):
        """As :meth:`project` for the segments ``segs`` (int array), in that order."""
        return self._project(point, np.asarray(segs, np.int64))

    def _project(self, point, sel):
        a = self.p0[sel]
        d = self.p1[sel] - a
        dd = np.einsum("ij,ij->i", d, d)
        w = np.asarray(point, np.float64)[None, :] - a
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where(dd > 0, np.einsum("ij,ij->i", w, d) / dd, 0.0)
        f = np.clip(f, 0.0, 1.0)
        dist = np.linalg.norm(w - f[:, None] * d, axis=1)
        t0 = self.t0[sel]
        prog = t0 + f * (self.t1[sel] - t0)
        return dist, prog


@dataclass(frozen=True)
class SyncResult:
    """Where the machine is in the program.

    ``progress`` program time s; ``segment`` index in the path; ``row`` move-table row;
    ``line`` its source line; ``distance`` mm from the live position to the path there;
    ``how`` is ``"line"``, ``"track"``, ``"search"`` (re-anchored by a whole-path search) or
    ``"lost"`` (nothing near; progress kept).
    """

    progress: float
    segment: int
    row: int
    line: int
    distance: float
    how: str


class ProgramSync:
    """Follow live tip positions along a :class:`ProgramPath`.

    Parameters
    ----------
    path : ProgramPath
    noise : float
        Position noise band, mm: candidates within ``best + noise`` count as equally near,
        and a match farther than ``lost`` from the path is not trusted.
    lost : float
        Distance (mm) beyond which the windowed match is rejected and the whole path searched.
    back : float
        How far behind the last progress (s) a windowed match may lie (noise, jitter);
        progress itself never goes backwards unless re-anchored.
    ahead : float
        Minimum forward window, s of program time; it grows with the time since the last
        update (times ``max_speedup``, for overrides above 100 %).
    """

    def __init__(self, path: ProgramPath, noise: float = 0.05, lost: float = 1.0, back: float = 0.5,
                 ahead: float = 1.0, max_speedup: float = 3.0):
        if len(path) == 0:
            raise ValueError("the program has no moves to follow")
        self.path = path
        self.noise = float(noise)
        self.lost = float(lost)
        self.back = float(back)
        self.ahead = float(ahead)
        self.max_speedup = float(max_speedup)
        self.progress: float | None = None
        self._last_t: float | None = None
        self._line_order: np.ndarray | None = None
        self._line_sorted: np.ndarray | None = None

    def reset(self, progress: float | None = None) -> None:
        self.progress = progress
        self._last_t = None

    def update(self, point, t: float | None = None, line: int | None = None, search: bool = False) -> SyncResult:
        """Take one live tip position (3,) mm at time ``t`` s (and the reported line, if any).

        ``search``: look over the whole path (preferring ahead of the last progress)
        instead of the window around it -- after a gap, where the machine went meanwhile
        is unknown."""
        point = np.asarray(point, np.float64)[:self.path.p0.shape[1]]
        dt = 0.0 if (t is None or self._last_t is None) else max(float(t) - self._last_t, 0.0)
        if t is not None:
            self._last_t = float(t)
        if line is not None and line > 0:
            got = self._by_line(point, int(line))
            if got is not None:
                return got
        if self.progress is None or search:
            return self._search(point)
        return self._track(point, dt)

    # -- strategies
    def _result(self, seg: int, prog: float, dist: float, how: str) -> SyncResult:
        row = int(self.path.row[seg])
        return SyncResult(float(prog), int(seg), row, int(self.path.lines[row]), float(dist), how)

    def _by_line(self, point, line: int) -> SyncResult | None:
        if self._line_order is None:  # segments grouped by source line, built once
            seg_lines = self.path.lines[self.path.row]
            self._line_order = np.argsort(seg_lines, kind="stable")
            self._line_sorted = seg_lines[self._line_order]
        # the key in the array's own dtype: another one makes searchsorted convert the
        # whole array (every segment) on each call
        bounds = np.iinfo(self._line_sorted.dtype)
        if not bounds.min <= line <= bounds.max:  # no row has such a line
            return None
        key = self._line_sorted.dtype.type(line)
        a = int(np.searchsorted(self._line_sorted, key, side="left"))
        b = int(np.searchsorted(self._line_sorted, key, side="right"))
        if b <= a:
            return None
        segs = self._line_order[a:b]
        dist, prog = self.path.project_segments(point, segs)
        k = self._earliest(dist, prog, floor=None if self.progress is None else self.progress - self.back)
        p = prog[k] if self.progress is None else max(prog[k], min(self.progress, self.path.t1[segs[k]]))
        self.progress = float(p)
        return self._result(int(segs[k]), self.progress, dist[k], "line")

    def _track(self, point, dt: float) -> SyncResult:
        path = self.path
        lo = path.segment_at(self.progress - self.back)
        hi_t = self.progress + max(self.ahead, self.max_speedup * dt * 1.5)
        hi = max(path.segment_at(hi_t) + 1, min(lo + 8, len(path)))
        dist, prog = path.project(point, lo, hi)
        # prefer matches at or ahead of the progress (a retract up its own plunge line is
        # ahead, not back on the plunge); a match behind only holds the progress (noise)
        fwd = prog >= self.progress
        best = float(dist.min())
        if fwd.any() and dist[fwd].min() <= best + self.noise:
            k = self._earliest(dist, prog, floor=self.progress)
        else:
            k = int(np.argmin(dist))
        if dist[k] > self.lost:
            return self._search(point, fallback=True)
        self.progress = max(self.progress, float(prog[k]))
        seg = lo + k if prog[k] >= self.progress else path.segment_at(self.progress)
        return self._result(seg, self.progress, dist[k], "track")

    def _search(self, point, fallback: bool = False) -> SyncResult:
        dist, prog = self.path.project(point)
        floor = None
        if self.progress is not None:
            # prefer a match ahead of where we were; fall back to anywhere
            ahead = prog >= self.progress - self.back
            if np.any(ahead & (dist <= self.lost)):
                floor = self.progress - self.back
        k = self._earliest(dist, prog, floor)
        if dist[k] > self.lost:
            keep = self.progress if self.progress is not None else float(prog[k])
            if self.progress is None:
                self.progress = keep
            return self._result(self.path.segment_at(keep), keep, dist[k], "lost")
        self.progress = float(prog[k])
        return self._result(k, self.progress, dist[k], "search")

    def _earliest(self, dist: np.ndarray, prog: np.ndarray, floor: float | None) -> int:
        """Index of the earliest candidate (by progress) within the noise band of the best."""
        ok = np.ones(dist.size, bool) if floor is None else prog >= floor
        if not ok.any():
            ok[:] = True
        best = dist[ok].min()
        near = ok & (dist <= best + self.noise)
        idx = np.nonzero(near)[0]
        return int(idx[np.argmin(prog[idx])])
