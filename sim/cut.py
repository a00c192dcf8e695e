"""Material removal: cut a whole move table into a :class:`~sim.grid.DexelGrid` in one call.

How each move row is swept (tip positions from :func:`sim.gcode.moves.tip_positions`):

* RAPID / FEED, top frame, flat / ball / bull / vbit / drill tool: the exact closed-form
  sweep of :mod:`sim.sweep_kernels` (one compiled loop over the whole batch).
* ARC_CW / ARC_CCW, same tools: the arc or helix is split into chords whose sagitta is
  within ``tol.chord`` and each chord is swept exactly (so the result is within
  ``tol.chord`` of the true swept volume).
* Anything else (custom or non-convex profiles, frames whose rays are not +Z, tilted
  axes through :meth:`Cutter.cut_poses`): instances of motion spaced at most
  ``tol.instance_fraction * spacing`` apart (Huang & Oliver eq. 3-5); arcs are followed
  along the true arc.
* DWELL, TOOL_CHANGE, PROBE, PAUSE, END rows remove nothing.

The A B C columns turn nothing unless the Cutter has a :class:`sim.kinematics.Kinematics`
with rotaries (``kinematics=``): then a batch with any row whose rotaries are not all 0
(or change) is cut by instances of motion of the machine axes interpolated linearly
(:func:`sim.kinematics.move_instances`, no tool point moves more than
``tol.instance_fraction * spacing`` between two), each placed on the part by the
kinematics (see :mod:`sim.rotary_plan`). Without one (the default) the moves are
3-axis with the tool axis along +Z. Tilted and 5-axis poses can also be cut directly
through :meth:`Cutter.cut_poses` / :meth:`Cutter.cut_segment` with axes.
Rapids cut like feeds (the checks decide whether that was allowed); the cutter does not
judge ``center_cutting`` either.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from sim import bands
from sim import dexel_store as ds
from sim import sweep
from sim import sweep_kernels as K
from sim.errors import InputError
from sim.gcode.moves import MoveKind, tip_positions
from sim.grid import DexelGrid
from sim.kinematics import Kinematics
from sim.rotary_plan import RotaryPlan
from sim.tolerance import DEFAULT, Tolerance
from sim.tools import Body, Tool

_LINEAR_KINDS = (int(MoveKind.RAPID), int(MoveKind.FEED))
_ARC_KINDS = (int(MoveKind.ARC_CW), int(MoveKind.ARC_CCW))
_Z_AXIS = np.array([0.0, 0.0, 1.0])


_EMPTY_I64 = np.zeros(0, np.int64)
_EMPTY_F32 = np.zeros(0, np.float32)
_EMPTY_F64 = np.zeros(0, np.float64)


@dataclass
class CutResult:
    """What a batch cut did.

    removed: float64 (n_moves,) mm^3 removed by each move.
    changed_ptr: int64 (n_moves + 1,); ``changed_rays[changed_ptr[k]:changed_ptr[k+1]]``
    are the flat ray indices move ``k`` changed (sorted, unique). Empty when changes were
    not recorded. seconds: wall time of the cut.
    changed_depth: float32 aligned with ``changed_rays``, mm: the material the move took
    off that ray from the top down (top before the move minus the new top; where the top
    did not move - a split below it - or the ray was emptied, the length removed).
    """

    removed: np.ndarray
    changed_ptr: np.ndarray
    changed_rays: np.ndarray
    seconds: float
    changed_depth: np.ndarray = field(default_factory=_EMPTY_F32.copy)

    def changed(self, k: int) -> np.ndarray:
        """Flat ray indices move ``k`` changed."""
        return self.changed_rays[self.changed_ptr[k]:self.changed_ptr[k + 1]]

    @property
    def total_removed(self) -> float:
        return float(self.removed.sum())


def _larger(size: int) -> int:
    """Next capacity of a log buffer: +50 %, +25 % once it is large (the slack is touched:
    ``ndarray.resize`` zero-fills it)."""
    return size + (size // 2 if size < (1 << 23) else size // 4)


def _grow(a: np.ndarray, size: int) -> None:
    """Enlarge ``a`` in place to ``size`` elements, keeping its contents.

    ``ndarray.resize`` reallocates, which for large blocks moves the pages instead of
    copying them, so growing never holds two copies of a log. ``a`` must own its data
    and have no views.
    """
    a.resize(size, refcheck=False)


class _Log:
    """The change log of one batch cut, filled by the kernels (see ``K.finish_move``).

    ray (int64) / depth (float32): one entry per move and distinct ray it changed;
    counts (int64 (n_moves,)): entries per move; s_top / s_len (float64): per-move
    scratch, reused move after move. Buffers grow in place (:func:`_grow`,
    :func:`_larger`): little slack, never two copies.
    """

    def __init__(self, n_moves: int, small: bool):
        cap = 1 << 11 if small else 1 << 16
        self.ray = np.empty(cap, np.int64)
        self.depth = np.empty(cap, np.float32)
        self.counts = np.zeros(n_moves, np.int64)
        self.s_top = np.empty(1 << 12)
        self.s_len = np.empty(1 << 12)
        self.n = 0   # entries closed

    def buffers(self) -> tuple:
        return (self.ray, self.depth, self.counts, self.s_top, self.s_len)

    def grow_entries(self, state) -> None:
        used, cur = int(state[3]), int(state[4])
        if used + cur >= self.ray.size:
            cap = max(_larger(self.ray.size), used + cur + 1)
            _grow(self.ray, cap)
            _grow(self.depth, cap)
        if cur >= self.s_top.size:
            self.s_top = np.concatenate([self.s_top, np.empty(self.s_top.size)])
            self.s_len = np.concatenate([self.s_len, np.empty(self.s_len.size)])

    def trim(self) -> None:
        """Give back the slack: every buffer cut to what was used."""
        for a in (self.ray, self.depth):
            _grow(a, self.n)
        self.s_top = self.s_len = _EMPTY_F64


class _Work:
    """Accumulates the pieces a batch is made of: exact segments and instance poses."""

    def __init__(self):
        self.seg_p0: list[np.ndarray] = []
        self.seg_p1: list[np.ndarray] = []
        self.seg_move: list[np.ndarray] = []
        self.seg_id: list[np.ndarray] = []
        self.pose_tip: list[np.ndarray] = []
        self.pose_axis: list[np.ndarray] = []
        self.pose_move: list[np.ndarray] = []
        self.pose_id: list[np.ndarray] = []

    def segments(self, p0, p1, move, fid):
        n = len(p0)
        self.seg_p0.append(p0)
        self.seg_p1.append(p1)
        self.seg_move.append(np.full(n, move, np.int64) if np.isscalar(move) else move)
        self.seg_id.append(np.full(n, fid, np.int32) if np.isscalar(fid) else fid)

    def poses(self, tips, axes, move, fid):
        n = len(tips)
        self.pose_tip.append(tips)
        self.pose_axis.append(axes)
        self.pose_move.append(np.full(n, move, np.int64))
        self.pose_id.append(np.full(n, fid, np.int32))

    @staticmethod
    def _cat(parts, shape_tail, dtype):
        if not parts:
            return np.zeros((0,) + shape_tail, dtype)
        return np.ascontiguousarray(np.concatenate(parts), dtype=dtype)

    def seg_arrays(self):
        return (self._cat(self.seg_p0, (3,), np.float64), self._cat(self.seg_p1, (3,), np.float64),
                self._cat(self.seg_move, (), np.int64), self._cat(self.seg_id, (), np.int32))

    def pose_arrays(self):
        return (self._cat(self.pose_tip, (3,), np.float64), self._cat(self.pose_axis, (3,), np.float64),
                self._cat(self.pose_move, (), np.int64), self._cat(self.pose_id, (), np.int32))


class Cutter:
    """Removes a tool's swept volume from a grid, move by move.

    grid: the :class:`DexelGrid` to cut (changed in place). tool: the :class:`Tool`.
    tools: optional ``{tool number: Tool}``; when given, :meth:`cut_moves` follows the
    ``tool`` column of the move table (rows whose tool is not in the dict use ``tool``).
    threads: how many threads a large batch may cut on (bands of rows, :mod:`sim.bands`);
    default :func:`sim.bands.default_threads`; 1 keeps every cut on the calling thread.
    kinematics: the machine's :class:`sim.kinematics.Kinematics` (default None: 3-axis,
    A B C ignored). origin: (6,) machine X Y Z (mm) A B C (deg) of the grid's frame
    origin, the job's reference work offset (default 0): a row's machine pose is its
    ``start``/``end`` plus ``origin`` (X Y Z as the gauge point, the row's tool length
    added back), and the tips the kinematics puts on the part are shifted back by
    ``origin[:3]`` into the grid's frame. tool_lengths: {tool number: mm} the G43 length
    of each tool, for a move table of tips (whose ``tool_length`` column is 0, as
    ``monitor.work_coords.work_moves`` makes them): a head that turns the tool swings its tip
    on the pivot-to-tip distance, which holds the tool length (default None: each row's
    ``tool_length``). Tools it does not name use their rows' column.
    """

    def __init__(self, grid: DexelGrid, tool: Tool, tol: Tolerance = DEFAULT,
                 tools: dict[int, Tool] | None = None, threads: int | None = None,
                 kinematics: Kinematics | None = None, origin=None, tool_lengths: dict[int, float] | None = None):
        if not isinstance(grid, DexelGrid):
            raise InputError(f"Cutter needs a DexelGrid, got {type(grid).__name__}")
        if not isinstance(tool, Tool):
            raise InputError(f"Cutter needs a Tool, got {type(tool).__name__}")
        if kinematics is not None and not isinstance(kinematics, Kinematics):
            raise InputError(f"Cutter kinematics must be a sim.kinematics.Kinematics, got "
                             f"{type(kinematics).__name__}")
        # a kinematics that turns nothing is the 3-axis cutter, with no per-batch test
        self.kinematics = kinematics if kinematics is not None and kinematics.rotaries else None
        self.origin = np.zeros(6) if origin is None else np.asarray(origin, np.float64).reshape(6).copy()
        self.tool_lengths = None if tool_lengths is None else {int(t): float(v) for t, v in tool_lengths.items()}
        #: rotary batches: cut the body above the height that can reach material off
        #: (:meth:`_reaching_profile`); False cuts with the whole body (the tests' reference)
        self.trim_body = True
        self.grid = grid
        self.tool = tool
        self.tol = tol
        self.tools = dict(tools or {})
        self.threads = bands.default_threads() if threads is None else max(1, int(threads))
        self._top = grid.frame.is_top  # frames are immutable; asked on every batch
        self._params: dict[int, tuple] = {}  # id(body) -> (body, kernel parameters)
        self._rotary = (RotaryPlan(grid, self.kinematics, self.origin, self._step(), tol.length, self.tool_lengths)
                        if self.kinematics is not None else None)

    # --- public API ---------------------------------------------------------------------
    def cut_moves(self, moves: np.ndarray, move_ids=None, record_changes: bool = True,
                  trace=None, stages=None, body: Body | None = None) -> CutResult:
        """Cut every row of ``moves`` (MOVE_DTYPE) in order.

        body: sweep this body (a shank, a holder) instead of each row's cutting tool
        (checks use it to take away what a body touched, so that it is counted once).

        move_ids: int (n,) face ids to write (default row index + 1; 0 is the stock).
        record_changes: False skips the changed-ray lists (saves memory on long programs).
        trace: a :class:`sim.trace.Trace` (or ``ZTrace``) of this grid, up to date: every
        row is recorded into it as its own stage while it is cut (the kernels write the
        trace's events directly; no second pass). stages: int (n,) the rows'
        stages (non-decreasing, not below the trace's last; default last + 1, + 2, ...).
        """
        t0 = time.perf_counter()
        n = len(moves)
        ids = self._ids(n, move_ids)
        removed = np.zeros(n, np.float64)
        record = bool(record_changes)
        sink = trace.sink(self.grid, n, stages, ids) if trace is not None else None
        log = _Log(n, n <= 8) if record else None
        multi = np.zeros(n, bool)
        for lo, hi, tool in self._tool_runs(moves):
            sub = moves[lo:hi]
            rows = np.arange(lo, hi)
            swept = self._body(tool) if body is None else body
            work = self._plan(sub, rows, ids[lo:hi], swept, multi)
            self._execute(work, swept, removed, probe=False, log=log, sink=sink)
        if sink is not None:
            sink.end()
        res = self._result(n, log)
        res.removed = removed * self.grid.frame.spacing**2
        res.seconds = time.perf_counter() - t0
        return res

    def cut_segment(self, p0, p1, move_id: int, axis=None, axis1=None) -> float:
        """Cut one straight move of the tip from ``p0`` to ``p1`` ((3,) mm); return mm^3 removed.

        ``axis`` / ``axis1``: tool axis at the start / end (default +Z; 5-axis when they
        differ or are tilted, swept by instances of motion).
        """
        removed = np.zeros(1)
        work = self._segment_work(p0, p1, move_id, axis, axis1, self.tool)
        self._execute(work, self.tool, removed, probe=False, log=None)
        return float(removed[0] * self.grid.frame.spacing**2)

    def cut_poses(self, tips, axes, move_id: int, body: Tool | Body | None = None) -> float:
        """Cut the tool standing at each pose (tips, axes: (n, 3) world); return mm^3 removed."""
        body = body or self.tool
        tips = np.atleast_2d(np.asarray(tips, np.float64))
        axes = np.broadcast_to(np.asarray(axes, np.float64), tips.shape)
        work = _Work()
        work.poses(tips, np.array(axes), 0, int(move_id))
        removed = np.zeros(1)
        self._execute(work, body, removed, probe=False, log=None, force_instances=True)
        return float(removed[0] * self.grid.frame.spacing**2)

    def probe_moves(self, moves: np.ndarray, body: Tool | Body | None = None) -> np.ndarray:
        """Volume (mm^3, float64 (n,)) of material each move's swept ``body`` would meet.

        The grid is not changed, and every move is measured against the grid as it is
        now (not after the earlier moves). body: default the cutting part of the tool; or
        ``tool.shank`` / ``tool.holder`` / any :class:`Body`.
        """
        body = body if body is not None else self.tool
        n = len(moves)
        out = np.zeros(n)
        multi = np.zeros(n, bool)
        ids = np.zeros(n, np.int32)
        work = self._plan(moves, np.arange(n), ids, body, multi)
        if self._exact(body):
            # single-segment moves measure in place; arcs (several chords) on scratch copies
            p0, p1, sm, sid = work.seg_arrays()
            single = ~multi[sm]
            w1 = _Work()
            w1.segments(p0[single], p1[single], sm[single], sid[single])
            self._execute(w1, body, out, probe=True, log=None)
            for k in np.nonzero(multi)[0]:
                out[k] = self._probe_scratch(moves[k:k + 1], body)[0]
        else:
            for k in range(n):
                if moves["kind"][k] in _LINEAR_KINDS + _ARC_KINDS:
                    out[k] = self._probe_scratch(moves[k:k + 1], body)[0]
        return out * self.grid.frame.spacing**2

    def probe_segment(self, p0, p1, body: Tool | Body | None = None) -> float:
        """Volume (mm^3) the body swept from tip ``p0`` to ``p1`` would meet; grid unchanged."""
        body = body if body is not None else self.tool
        work = self._segment_work(p0, p1, 0, None, None, body)
        out = np.zeros(1)
        if work.seg_p0:
            self._execute(work, body, out, probe=True, log=None)
            return float(out[0] * self.grid.frame.spacing**2)
        scratch = self.grid.copy()
        self._child(scratch)._execute(work, body, out, probe=False, log=None)
        return float(out[0] * self.grid.frame.spacing**2)

    # --- planning -----------------------------------------------------------------------
    def _ids(self, n, move_ids):
        if move_ids is None:
            return np.arange(1, n + 1, dtype=np.int32)
        ids = np.asarray(move_ids)
        if ids.shape != (n,):
            raise InputError(f"move_ids must have shape ({n},), got {ids.shape}")
        return ids.astype(np.int32)

    def _body(self, tool):
        return tool

    def _tool_runs(self, moves):
        """(lo, hi, tool) runs of consecutive rows cut with the same tool."""
        n = len(moves)
        if not self.tools or n == 0:
            yield 0, n, self.tool
            return
        col = moves["tool"]
        cuts = np.nonzero(np.diff(col))[0] + 1
        bounds = np.concatenate([[0], cuts, [n]])
        for a, b in zip(bounds[:-1], bounds[1:]):
            yield int(a), int(b), self.tools.get(int(col[a]), self.tool)

    def _exact(self, body) -> bool:
        return self._top and sweep.has_exact_sweep(body)

    def _step(self) -> float:
        return self.tol.instance_fraction * self.grid.frame.spacing

    def _plan(self, moves, rows, ids, body, multi) -> _Work:
        """Turn move rows into exact segments or instance poses, in program order.

        Order matters: each face records the first move that reached it and each move is
        credited with what it removed, so the pieces are cut row by row.
        """
        work = _Work()
        if len(moves) == 0:
            return work
        kind = moves["kind"].astype(np.int64)
        start = tip_positions(moves, "start")
        end = tip_positions(moves, "end")
        bad = ~(np.isfinite(start).all(axis=1) & np.isfinite(end).all(axis=1))
        lin = ((kind == _LINEAR_KINDS[0]) | (kind == _LINEAR_KINDS[1])) & ~bad
        arc = ((kind == _ARC_KINDS[0]) | (kind == _ARC_KINDS[1])) & ~bad
        exact = self._exact(body)
        turning = self._rotary.turning_rows(moves, lin | arc) if self._rotary else None
        if turning is not None:  # a batch with rotation is cut by instances, in row order
            exact = False
        if exact and not arc.any():  # the live monitor's few rows per poll: no per-row work
            work.segments(start[lin], end[lin], rows[lin], ids[lin])
            return work
        # the pieces of every row: (first point, last point) arrays per row
        pieces: dict[int, np.ndarray] = {}
        tilted: dict[int, np.ndarray] = {}  # row -> its instances' axes (rows with rotation)
        for k in np.nonzero(arc)[0]:
            center = np.array(moves["center"][k], np.float64)
            center[2] -= moves["tool_length"][k]
            cw = kind[k] == int(MoveKind.ARC_CW)
            plane = int(moves["plane"][k])
            turns = int(moves["turns"][k]) or 1
            if turning is not None and turning[k]:
                pieces[k], tilted[k] = self._rotary.poses(moves[k], start[k], end[k], body,
                                                          arc=(center, plane, turns, cw))
            elif exact:
                pq = sweep.PLANE_AXES[plane][:2]
                radius = max(float(np.hypot(*(start[k][list(pq)] - center[list(pq)]))), 1e-9)
                pieces[k] = sweep.arc_points(start[k], end[k], center, plane, turns, cw,
                                             max_step_angle=sweep.chord_step_angle(radius, self.tol.chord))
            else:
                pieces[k] = sweep.arc_points(start[k], end[k], center, plane, turns, cw,
                                             max_step_length=self._step())
            multi[rows[k]] = True
        straight = np.zeros(len(moves), bool)  # linear rows the axis does not turn on
        if not exact:
            straight = lin if turning is None else lin & ~turning
            for k in np.nonzero(lin & ~straight)[0]:
                pieces[k], tilted[k] = self._rotary.poses(moves[k], start[k], end[k], body)
            multi[rows[lin]] = True
            # the vertical tool's instances of every straight row at once (sweep.instances'
            # tips, bit for bit)
            line_tips, line_steps = sweep.line_instances(start[straight], end[straight], self._step())
        # sizes per row -> offsets, then fill linear rows vectorised and the rest per row
        if exact:
            size = lin.astype(np.int64)
            for k, pts in pieces.items():
                size[k] = len(pts) - 1
        else:
            size = np.zeros(len(moves), np.int64)
            size[straight] = line_steps + 1
            for k, pts in pieces.items():
                size[k] = len(pts)
        off = np.concatenate([[0], np.cumsum(size)])
        total = int(off[-1])
        owner = np.repeat(np.arange(len(moves)), size)
        if exact:
            p0 = np.empty((total, 3))
            p1 = np.empty((total, 3))
            p0[off[:-1][lin]] = start[lin]
            p1[off[:-1][lin]] = end[lin]
            for k, pts in pieces.items():
                p0[off[k]:off[k + 1]] = pts[:-1]
                p1[off[k]:off[k + 1]] = pts[1:]
            work.segments(p0, p1, rows[owner], ids[owner])
        else:
            tips = np.empty((total, 3))
            sizes = size[straight]
            tips[np.repeat(off[:-1][straight] - np.cumsum(sizes) + sizes, sizes)
                 + np.arange(int(sizes.sum()))] = line_tips
            for k, pts in pieces.items():
                tips[off[k]:off[k + 1]] = pts
            axes = np.broadcast_to(_Z_AXIS, tips.shape).copy()
            for k, ax in tilted.items():
                axes[off[k]:off[k + 1]] = ax
            # a row starts where the one before it ended: that pose again would cut nothing
            # (a pose leaves no material inside itself), so it is cut once; every row keeps
            # its last pose (each row still opens its own stage of a trace)
            keep = np.ones(total, bool)
            keep[1:-1] = ~((tips[1:-1] == tips[:-2]).all(axis=1) & (axes[1:-1] == axes[:-2]).all(axis=1)
                           & (owner[2:] == owner[1:-1]))
            work.pose_tip.append(tips[keep])
            work.pose_axis.append(axes[keep])
            work.pose_move.append(rows[owner[keep]].astype(np.int64))
            work.pose_id.append(ids[owner[keep]].astype(np.int32))
        return work

    def _child(self, grid: DexelGrid) -> "Cutter":
        """A Cutter on another grid (a scratch copy, a window) with this one's tool,
        tolerance, kinematics, origin and tool lengths."""
        return Cutter(grid, self.tool, self.tol, kinematics=self.kinematics, origin=self.origin,
                      tool_lengths=self.tool_lengths)

    def _segment_work(self, p0, p1, move_id, axis, axis1, body) -> _Work:
        p0 = np.asarray(p0, np.float64).reshape(1, 3)
        p1 = np.asarray(p1, np.float64).reshape(1, 3)
        a0 = _Z_AXIS if axis is None else np.asarray(axis, np.float64)
        a1 = a0 if axis1 is None else np.asarray(axis1, np.float64)
        work = _Work()
        vertical = np.allclose(a0 / np.linalg.norm(a0), _Z_AXIS) and np.allclose(a1 / np.linalg.norm(a1), _Z_AXIS)
        if vertical and self._exact(body):
            work.segments(p0, p1, 0, int(move_id))
        else:
            length = body.flute_length if isinstance(body, Tool) else body.top
            tips, axes = sweep.instances(p0[0], p1[0], a0, a1, length, self._step())
            work.poses(tips, axes, 0, int(move_id))
        return work

    # --- execution ----------------------------------------------------------------------
    def _execute(self, work: _Work, body, removed, probe: bool, log: _Log | None,
                 force_instances=False, sink=None) -> None:
        """Run the kernels over the planned work, appending the changes to ``log`` (if any)
        and the trace events to ``sink`` (if any)."""
        f = self.grid.frame
        p0, p1, sm, sid = work.seg_arrays()
        if len(p0) and not force_instances:
            tp = self._params.get(id(body))
            if tp is None or tp[0] is not body:
                tp = self._params[id(body)] = (body, sweep.body_params(body))
            tp = tp[1]
            self._cut_linear(p0, p1, sm, sid, tp, removed, probe, log, sink)
        tips, axes, pm, pid = work.pose_arrays()
        if len(tips):
            prof = sweep.body_profile(body)
            tips_l = np.ascontiguousarray(f.to_local(tips))
            axes_l = np.ascontiguousarray(np.stack([axes @ f.u, axes @ f.v, axes @ f.direction], axis=1))
            axes_l /= np.linalg.norm(axes_l, axis=1, keepdims=True)
            if self.kinematics is not None and self.trim_body:
                prof = self._rotary.reaching_profile(prof, tips_l, axes_l)
            rmax = float(prof[:, 1].max())
            self._cut_poses(tips_l, axes_l, pm, pid, prof, rmax, removed, probe, log, sink)

    def _cut_linear(self, p0, p1, sm, sid, tp, removed, probe: bool, log: _Log | None, sink) -> None:
        """The exact sweep of straight segments (see ``K.cut_linear_batch``): on bands of
        rows on several threads when the batch is large (:mod:`sim.bands`), else here."""
        grid = self.grid
        f = grid.frame
        eps = self.tol.length
        record = log is not None
        traced = sink is not None
        reach = bands.reach_rays(p0, p1, tp[6], f.spacing)
        events = min(int(reach.sum()), 32 * f.n_rays + len(p0) * 64)  # bounds the changes
        if traced:
            if len(sm) > 1 and np.any(sm[1:] == sm[:-1]):
                sink.need_marks()
            sink.reserve(events)
        top_bound = np.inf
        if len(p0) >= 64 and not probe:  # lets chained moves skip rays already cut
            top_bound = grid.max_top()
        if self.threads > 1 and not probe and reach.sum() >= bands.MIN_PARALLEL_RAYS:
            def plan(a, b, shares):
                return bands.plan_bands(p0[a:b], p1[a:b], tp[6], f.origin[1], f.spacing, f.nv, self.threads,
                                        shares)

            def band_cut(S, st, B, T, ts, rem, band, segs):
                a, b = segs
                return K.cut_linear_batch(S, f.origin[0], f.origin[1], f.spacing, f.nu, f.nv, p0[a:b],
                                          p1[a:b], sm[a:b], sid[a:b], tp, eps, False, record, rem,
                                          B, st, traced, T, ts, top_bound, band[0], band[1])
            bands.cut_in_bands(grid, band_cut, sm, plan, removed, log, sink, reach, self.threads)
            return
        self._loop(lambda S, st, B, T, ts: K.cut_linear_batch(
            S, f.origin[0], f.origin[1], f.spacing, f.nu, f.nv, p0, p1, sm, sid, tp, eps,
            probe, record, removed, B, st, traced, T, ts, top_bound, 0, int(f.nv)), log, sink)

    def _cut_poses(self, tips, axes, pm, pid, prof, rmax: float, removed, probe: bool,
                   log: _Log | None, sink) -> None:
        """Instances of motion (see ``K.cut_poses``; tips and axes frame-local): on bands of
        rows on several threads when there are many, else here."""
        f = self.grid.frame
        eps = self.tol.length
        record = log is not None
        traced = sink is not None
        per_pose = (2 * rmax / f.spacing + 2) ** 2
        if traced:
            sink.need_marks()
            sink.reserve(min(int(len(tips) * per_pose), 4 * f.n_rays))
        if (self.threads > 1 and not probe and len(tips) >= 16
                and len(tips) * per_pose >= bands.MIN_PARALLEL_RAYS):
            # each pose's rows: from the bottom to the top of the (tilted) body, grown by rmax
            lo = tips + prof[0, 0] * axes
            hi = tips + prof[-1, 0] * axes

            def plan(a, b, shares):
                return bands.plan_bands(lo[a:b], hi[a:b], rmax, 0.0, f.spacing, f.nv, self.threads, shares)

            def band_cut(S, st, B, T, ts, rem, band, segs):
                a, b = segs
                return K.cut_poses(S, f.spacing, f.nu, f.nv, tips[a:b], axes[a:b], pm[a:b], pid[a:b],
                                   prof, rmax, eps, False, record, rem, B, st, traced, T, ts,
                                   band[0], band[1])
            bands.cut_in_bands(self.grid, band_cut, pm, plan, removed, log, sink,
                               np.full(len(tips), per_pose), self.threads)
            return
        self._loop(lambda S, st, B, T, ts: K.cut_poses(
            S, f.spacing, f.nu, f.nv, tips, axes, pm, pid, prof, rmax, eps, probe, record,
            removed, B, st, traced, T, ts, 0, int(f.nv)), log, sink)

    def _loop(self, call, log: _Log | None, sink=None) -> None:
        """Call a batch kernel until it is done, growing the pool, the log's buffers and
        the trace's columns, and letting the trace take its keyframes."""
        state = np.zeros(K.STATE_SIZE, np.int64)
        state[1] = state[2] = -1
        if log is not None:
            state[3] = log.n
        while True:
            status = call(self.grid.S, state, K.NO_LOG if log is None else log.buffers(),
                          K.NO_TRACE if sink is None else sink.buffers(),
                          K.NO_TS if sink is None else sink.ts)
            if status == K.DONE:
                break
            if status == K.STOP_TRACE:
                sink.grow()
            elif status == K.TRACE_KEYFRAME:
                sink.keyframe()
            elif status == K.STOP_POOL:
                ds.grow_pool(self.grid.store, max(1024, self.grid.store["pool_near"].size))
            elif status == K.STOP_CHANGES:
                log.grow_entries(state)
        if log is not None:
            log.n = int(state[3])

    def _result(self, n, log: _Log | None) -> CutResult:
        """The CSR of changed rays from the kernels' log, in move order.

        The kernels close each move's entries sorted by ray with one entry per ray, and
        moves run in order, so the log is the CSR; no sort, no copy.
        """
        ptr = np.zeros(n + 1, np.int64)
        res = CutResult(np.zeros(n), ptr, _EMPTY_I64, 0.0)
        if log is None:
            return res
        log.trim()
        np.cumsum(log.counts, out=ptr[1:])
        res.changed_rays = log.ray
        res.changed_depth = log.depth
        return res

    def probe_where(self, moves: np.ndarray, body: Tool | Body | None = None):
        """Where ``body`` swept along ``moves`` would meet material: ``(res, scratch, top)``,
        the :class:`CutResult` (changes recorded, in ``scratch``'s rays) of cutting a
        scratch copy ``scratch`` of the rays the moves can reach (a window of the grid),
        and ``top`` (float64, the scratch's rays) its material tops before that cut; None
        when the moves reach no ray. The grid is not changed."""
        body = body if body is not None else self.tool
        scratch = self._reach_window(moves, body)
        if scratch is None:
            return None
        top = scratch.top().reshape(-1).astype(np.float64)
        res = self._child(scratch).cut_moves(moves, record_changes=True, body=body)
        return res, scratch, top

    def _probe_scratch(self, moves, body) -> np.ndarray:
        """Probe by cutting a scratch copy of the rays the moves can reach (length units)."""
        scratch = self._reach_window(moves, body)
        if scratch is None:
            return np.zeros(1)
        return self._child(scratch)._cut_with(moves, body)

    def _reach_window(self, moves, body) -> DexelGrid | None:
        """A scratch copy of the rays ``moves`` (one row, or rows of one turning part) can
        reach with ``body``: a window of the grid, the whole grid for a turning part; None
        when they reach no ray."""
        f = self.grid.frame
        start = tip_positions(moves, "start")
        end = tip_positions(moves, "end")
        pts = np.concatenate([start, end])
        if moves["kind"][0] in _ARC_KINDS:
            c = np.array(moves["center"][0], np.float64)
            r = float(np.linalg.norm(start[0] - np.where(np.isfinite(c), c, start[0])))
            pts = np.concatenate([pts, c[None, :] - r, c[None, :] + r])
            pts = pts[np.isfinite(pts).all(axis=1)]
        if self._rotary and self._rotary.turning_rows(moves, np.ones(len(moves), bool)) is not None:
            # a turning part: the tool reaches wherever the rotation takes it; the whole grid
            return self.grid.copy()
        prof = body.profile
        reach = float(prof[:, 1].max()) + float(prof[-1, 0])
        local = f.to_local(pts)
        lo = np.floor((local[:, :2].min(axis=0) - reach) / f.spacing).astype(int)
        hi = np.ceil((local[:, :2].max(axis=0) + reach) / f.spacing).astype(int) + 1
        i0, j0 = max(lo[0], 0), max(lo[1], 0)
        i1, j1 = min(hi[0], f.nu), min(hi[1], f.nv)
        if i1 <= i0 or j1 <= j0:
            return None
        return self.grid.window(i0, i1, j0, j1)

    def _cut_with(self, moves, body) -> np.ndarray:
        removed = np.zeros(len(moves))
        multi = np.zeros(len(moves), bool)
        work = self._plan(moves, np.arange(len(moves)), np.zeros(len(moves), np.int32), body, multi)
        self._execute(work, body, removed, probe=False, log=None)
        return removed
