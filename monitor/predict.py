"""Checks for the session, all through :class:`sim.checks.Checker` (one piece of check logic).

Everything here is in the job's *work coordinates* (:mod:`monitor.work_coords`): the
program as tool tips in the job's work system, travel limits moved into it by the work
offset in force and their findings moved back; the dexel frame covers stock and fixtures
(:mod:`monitor.workpiece`).

Two thin adapters around ``Checker``:

* :class:`Lookahead` keeps a *scratch* model, a copy of the live stock taken when the
  session anchors, and a ``Checker`` on it; program rows ahead of the spindle are cut and
  checked onto it *once each* (``Checker.cut_and_check``) as the horizon reaches them,
  a bounded amount of work per state (:attr:`Lookahead.budget_rays`) so a horizon that
  crosses many rows at once does not stall one poll. The live model is never touched.
* :class:`LiveChecks` keeps a ``Checker`` on the *live* model: the path the tool really
  travelled is turned into move rows and cut and checked with it (:meth:`LiveChecks.cut`),
  so gouges, rapids into stock, shank/holder contact, fixtures, a stopped spindle and
  limits are found on the real motion too.
"""

from __future__ import annotations

import math

import numpy as np

from monitor.sync import ProgramPath
from monitor.work_coords import finding_to_machine, limits_in_work
from monitor.workpiece import Workpiece
from sim.checks.arrays import distinct
from sim.checks.findings import Finding
from sim.gcode.moves import MOVE_DTYPE, MoveKind, Plane
from sim.grid import DexelGrid

#: removed / touched volume below this is numerical noise, mm^3
MIN_VOLUME = 1e-3
#: look-ahead work allowed per state, in swept rays (about 2-3 ms on one core)
BUDGET_RAYS = 60_000
#: fixed cost of one look-ahead row, in swept-ray equivalents
ROW_OVERHEAD_RAYS = 400


def make_checker(wp: Workpiece, stock: DexelGrid, limits: dict | None, wco):
    """A :class:`sim.checks.Checker` on ``stock`` with the workpiece's design, fixtures,
    tools and tolerance, and the machine ``limits`` moved into work coordinates."""
    from sim.checks.checker import Checker

    return Checker(stock, wp.default_tool, design=wp.design, fixtures=wp.fixtures,
                   limits=limits_in_work(limits, wco), tol=wp.tol, tools=wp.tools, min_volume=MIN_VOLUME,
                   kinematics=wp.kinematics, origin=wp.origin, tool_lengths=wp.tool_lengths)


def _checked(checker, rows: np.ndarray, ids: np.ndarray, wco):
    """``checker.cut_and_check`` with limit findings in machine coordinates; the checker's
    own history is not kept (the session keeps what it alerted)."""
    res, found = checker.cut_and_check(rows, move_ids=ids)
    checker.findings.clear()
    return res, [finding_to_machine(f, wco) for f in found]


# --- the look-ahead -----------------------------------------------------------------------------

def row_costs(moves: np.ndarray, reach: float, spacing: float) -> np.ndarray:
    """Estimated work of cutting and checking each row, float64 (n,) in swept rays: the
    row's XY box grown by ``reach`` mm over the ray area, plus a fixed cost."""
    s = np.asarray(moves["start"][:, :2], np.float64)
    e = np.asarray(moves["end"][:, :2], np.float64)
    arc = np.isin(moves["kind"], (MoveKind.ARC_CW, MoveKind.ARC_CCW))
    c = np.asarray(moves["center"][:, :2], np.float64)
    # an arc's box: its centre +- radius (an upper bound)
    r = np.where(arc, np.linalg.norm(s - c, axis=1), 0.0)
    lo = np.where(arc[:, None], c - r[:, None], np.minimum(s, e)) - reach
    hi = np.where(arc[:, None], c + r[:, None], np.maximum(s, e)) + reach
    area = np.prod(np.maximum(hi - lo, 0.0), axis=1) / spacing**2
    moving = np.isin(moves["kind"], (MoveKind.RAPID, MoveKind.FEED, MoveKind.ARC_CW, MoveKind.ARC_CCW,
                                     MoveKind.PROBE))
    return np.where(moving, area, 0.0) + ROW_OVERHEAD_RAYS


def rotary_row_costs(wp: Workpiece, moves: np.ndarray, reach: float) -> np.ndarray:
    """Extra work of rows a rotary turns, float64 (n,) swept rays: their instances of
    motion (:meth:`sim.kinematics.Kinematics.instance_counts` of the machine poses, the
    tallest tool) times the rays under one tool (0 for rows that do not turn)."""
    out = np.zeros(len(moves))
    turning = np.any(moves["start"][:, 3:] != moves["end"][:, 3:], axis=1) | \
        np.any(moves["start"][:, 3:] != 0.0, axis=1)
    if not turning.any():
        return out
    height = max(float(t.profile[-1, 0]) for t in [*wp.tools.values(), wp.default_tool])
    origin = np.zeros(6) if wp.origin is None else np.asarray(wp.origin, np.float64)
    step = wp.tol.instance_fraction * wp.frame.spacing
    lengths = np.zeros(len(moves))
    for tool, length in (wp.tool_lengths or {}).items():
        lengths[moves["tool"] == tool] = length
    count = wp.kinematics.instance_counts(moves["start"][turning] + origin, moves["end"][turning] + origin,
                                          lengths[turning], height, reach, step)
    out[turning] = (count + 1) * (2.0 * reach / wp.frame.spacing + 2.0) ** 2
    return out


class Lookahead:
    """Cut and check the program ahead of the spindle on a scratch copy of the live stock.

    Parameters
    ----------
    wp : Workpiece
    moves : MOVE_DTYPE (n,) in work coordinates (:func:`work_moves`)
    path : ProgramPath of the same table (program time per row)
    horizon_s, horizon_mm : how far ahead to look (program seconds; and/or mm of path)
    limits : {axis: (lo, hi)} machine travel limits (optional), checked with ``wco``
    budget_rays : work allowed per :meth:`advance` (swept rays, :func:`row_costs`); at
        least one row is always done, so the scratch model keeps moving
    """

    def __init__(self, wp: Workpiece, moves: np.ndarray, path: ProgramPath, horizon_s: float = 5.0,
                 horizon_mm: float | None = None, limits: dict | None = None, budget_rays: float = BUDGET_RAYS):
        self.wp = wp
        self.moves = moves
        self.path = path
        self.horizon_s = float(horizon_s)
        self.horizon_mm = horizon_mm
        self.limits = {k.upper(): v for k, v in (limits or {}).items()}
        self.budget_rays = float(budget_rays)
        reach = max([t.radius for t in wp.tools.values()] + [wp.default_tool.radius])
        costs = row_costs(moves, reach, wp.frame.spacing)
        if wp.kinematics is not None:
            costs = costs + rotary_row_costs(wp, moves, reach)
        self.cost_cum = np.concatenate([[0.0], np.cumsum(costs)])
        self.checker = None
        self.next_row = 0
        self.wco = np.zeros(6)
        self.rows_checked = 0
        #: program s the rows waiting to be predicted reach back from the horizon end
        #: after the last :meth:`advance` (0: caught up)
        self.backlog_s = 0.0
        # the furthest horizon end of the advances since the anchor, before / after the
        # last advance: a row that starts before ``_end_before`` was inside the horizon
        # earlier and waited (program s)
        self._end_seen = -math.inf
        self._end_before = -math.inf

    @property
    def model(self) -> DexelGrid | None:
        """The scratch model (the live stock at the anchor, cut by the rows predicted since)."""
        return None if self.checker is None else self.checker.grid

    def anchor(self, live: DexelGrid, row: int, wco=None, behind: bool = False) -> None:
        """Restart the scratch model from the live one, predicting from ``row`` on.

        ``behind``: the spindle overtook the look-ahead; the rows ahead were inside the
        horizon already, so findings on them count as predicted late (:meth:`late_s`)."""
        if not behind:
            self._end_seen = -math.inf
        if wco is not None:
            self.wco = np.asarray(wco, np.float64)
        c = self.checker
        if c is None or c.engagement is not None:  # engagement keeps its own top snapshot
            self.checker = make_checker(self.wp, live.copy(), self.limits, self.wco)
        else:
            # re-anchoring after a jump: refill the scratch model in place and keep the
            # checker (its design casts, error map and bounds stay valid: the live model
            # only loses material, and findings only read the rays each batch updates)
            _copy_into(c.grid, live)
            c.forget_contacts()
            c.limits = limits_in_work(self.limits, self.wco)
        self.next_row = int(row)

    def set_wco(self, wco) -> None:
        """The work offset changed: later rows are checked against limits moved with it."""
        self.wco = np.asarray(wco, np.float64)
        if self.checker is not None:
            self.checker.limits = limits_in_work(self.limits, self.wco)

    def horizon_end(self, progress: float) -> float:
        """Program time up to which rows are predicted."""
        end = progress + self.horizon_s
        if self.horizon_mm is not None:
            end = min(end, self.path.progress_at_length(self.path.length_at(progress) + self.horizon_mm))
        return end

    def target_row(self, progress: float) -> int:
        """One past the last row that starts before the horizon end."""
        hi = int(np.searchsorted(self.path.row_t0, self.horizon_end(progress), side="left"))
        return min(hi, len(self.moves))

    def behind(self, progress: float) -> int:
        """Rows inside the horizon not predicted yet (0 when caught up)."""
        return max(self.target_row(progress) - self.next_row, 0)

    def advance(self, progress: float, budget_rays: float | None = None) -> list[Finding]:
        """Predict the next rows that start before the horizon end, as many as the budget
        allows (at least one); return their findings."""
        if self.checker is None:
            raise RuntimeError("Lookahead.anchor() first")
        end = self.horizon_end(progress)
        self._end_before, self._end_seen = self._end_seen, max(self._end_seen, end)
        target = self.target_row(progress)
        lo = self.next_row
        if target <= lo:
            self.backlog_s = 0.0
            return []
        budget = self.budget_rays if budget_rays is None else float(budget_rays)
        cap = int(np.searchsorted(self.cost_cum, self.cost_cum[lo] + budget, side="right")) - 1
        hi = min(target, max(cap, lo + 1))
        self.next_row = hi
        self.backlog_s = max(end - float(self.path.row_t0[hi]), 0.0) if hi < target else 0.0
        return self.check_rows(lo, hi)

    def late_s(self, finding: Finding, progress: float) -> float:
        """Program s of lead the finding lost waiting in the backlog: its row was inside
        the horizon at an earlier :meth:`advance` (or before the spindle overtook the
        look-ahead) but predicted only now; 0 when it was predicted at its first chance."""
        row = int(min(finding.stages or (finding.stage,))) - 1
        if row < 0 or row >= self.path.row_t0.size:
            return 0.0
        t0 = float(self.path.row_t0[row])
        if t0 >= self._end_before:
            return 0.0
        return max(self.horizon_end(progress) - t0, 0.0)

    def check_rows(self, lo: int, hi: int) -> list[Finding]:
        """Cut and check rows ``lo..hi-1`` on the scratch model (``Checker.cut_and_check``)."""
        self.rows_checked += hi - lo
        ids = np.arange(lo + 1, hi + 1, dtype=np.int64)
        _, found = _checked(self.checker, self.moves[lo:hi], ids, self.wco)
        return found


def _copy_into(dst: DexelGrid, src: DexelGrid) -> None:
    """Make ``dst`` hold ``src``'s material (same frame), reusing ``dst``'s arrays where
    they have the size (no page faults for a million rays)."""
    for k, v in src.store.items():
        d = dst.store.get(k)
        if isinstance(v, np.ndarray) and isinstance(d, np.ndarray) and d.shape == v.shape and d.dtype == v.dtype:
            np.copyto(d, v)
        else:
            dst.store[k] = v.copy() if isinstance(v, np.ndarray) else v


# --- the live checks ---------------------------------------------------------------------------

class LiveChecks:
    """Cut the path the tool really travelled into the live model and check it.

    Parameters
    ----------
    wp : Workpiece (its ``stock`` is the live model, cut in place)
    moves : MOVE_DTYPE (n,) the program in work coordinates (gives each travelled piece
        its row's kind, line, tool and feed)
    limits : machine travel limits {axis: (lo, hi)} (optional)
    max_pieces : capacity of the reusable row buffer (more pieces are cut in batches)
    """

    def __init__(self, wp: Workpiece, moves: np.ndarray, limits: dict | None = None, wco=None,
                 max_pieces: int = 64):
        self.wp = wp
        self.moves = moves
        self.limits = {k.upper(): v for k, v in (limits or {}).items()}
        self.wco = np.zeros(6) if wco is None else np.asarray(wco, np.float64)
        self.checker = make_checker(wp, wp.stock, self.limits, self.wco)
        # per program row, what a travelled piece takes from it (small arrays: indexing
        # them per state is cheaper than copying whole MOVE_DTYPE rows)
        self._line = np.ascontiguousarray(moves["line"])
        self._kind = np.where(moves["kind"] == MoveKind.RAPID, MoveKind.RAPID, MoveKind.FEED).astype(
            moves.dtype["kind"])
        self._feed = np.ascontiguousarray(moves["feed"])
        self._tool = np.ascontiguousarray(moves["tool"])
        self._spindle = np.ascontiguousarray(moves["spindle"])
        self._sdir = np.ascontiguousarray(moves["spindle_dir"])
        # per row, how often the program switched the spindle (running <-> stopped) up to
        # it: the same count at two rows means the program leaves the spindle as it is
        # between them (as sim.checks.spindle reads a row: stopped when its direction or
        # speed is 0)
        stopped = (self._sdir == 0) | (self._spindle <= 0)
        self._switches = np.concatenate([[0], np.cumsum(stopped[1:] != stopped[:-1])])
        self._rot0 = np.ascontiguousarray(moves["start"][:, 3:])
        self._rot1 = np.ascontiguousarray(moves["end"][:, 3:])
        self._buf = np.zeros(max_pieces, MOVE_DTYPE)
        self._buf["plane"] = Plane.XY
        self._ids = np.zeros(max_pieces, np.int64)

    def set_wco(self, wco) -> None:
        w = np.asarray(wco, np.float64)
        if not np.array_equal(w, self.wco):
            self.wco = w
            self.checker.limits = limits_in_work(self.limits, w)

    def cut(self, points: np.ndarray, rows: np.ndarray, spindle_rpm: float | None = None,
            arrived_row: int | None = None, polled_rows=()):
        """Cut the polyline ``points`` (k+1, 3) mm (work tip), piece ``q`` belonging to
        program row ``rows[q]`` (int, (k,)); return ``(removed mm^3, changed rays int64
        sorted and distinct, findings)``. ``points`` (k+1, 6) adds the work A B C (deg) at
        each point (a rotary job: the pieces turn as the machine did); with 3 columns each
        piece takes its row's programmed angles.

        ``spindle_rpm``: the speed the controller reports (None: take the program's);
        it holds for the path only where the program leaves the spindle as it is from
        the rows of the polls at its ends (``polled_rows``, the program rows the
        controller was at) over every row in between.
        ``arrived_row``: the row of the piece that ended at ``points[0]`` (the last one
        cut before), if known.

        Where the row changes (between two pieces, or from ``arrived_row`` to the first),
        the tool's pose at that point is cut first as the arriving row's own
        (:func:`arrival_poses`): that row brought the tool there, so whatever its pose
        touches is that row's doing, not the next one's.
        """
        if spindle_rpm is not None and self._program_switches_spindle(rows, arrived_row, *polled_rows):
            # the controller's speed is what the polls at the two ends of the path saw; the
            # program switched the spindle between them (a coarse poll over its M3 and M5,
            # say), so how it ran there is not what either end saw: each row takes the
            # program's (else a path from before M3 to after M5 was all "spindle stopped")
            spindle_rpm = None
        points, rows = arrival_poses(points, rows, arrived_row)
        removed = 0.0
        changed = []
        found: list[Finding] = []
        k = len(points) - 1
        step = self._buf.size
        for a in range(0, k, step):
            b = min(a + step, k)
            m = self._fill(points[a:b + 1], rows[a:b], spindle_rpm)
            res, f = _checked(self.checker, m, self._ids[:b - a], self.wco)
            removed += float(res.removed.sum())
            if res.changed_rays.size:
                changed.append(res.changed_rays)
            found += f
        # sorted: the trace record takes them as they are (np.unique would hash them first)
        rays = distinct(np.concatenate(changed)).astype(np.int64, copy=False) if changed else np.zeros(0, np.int64)
        return removed, rays, found

    def _program_switches_spindle(self, rows: np.ndarray, *more) -> bool:
        """Whether the program starts or stops the spindle anywhere from the first to the
        last of ``rows`` and the rows in ``more`` (None: unknown, left out)."""
        rows = np.asarray(rows)
        lo, hi = int(rows.min()), int(rows.max())
        for r in more:
            if r is not None and 0 <= r < self._switches.size:
                lo, hi = min(lo, int(r)), max(hi, int(r))
        return bool(self._switches[hi] != self._switches[lo])

    def _fill(self, pts: np.ndarray, rows: np.ndarray, spindle_rpm) -> np.ndarray:
        """The travelled pieces as move rows in the reusable buffer (a view, k rows)."""
        k = len(rows)
        m = self._buf[:k]
        m["line"] = self._line[rows]
        m["kind"] = self._kind[rows]
        start, end = m["start"], m["end"]
        if pts.shape[1] == 6:
            start[:] = pts[:-1]
            end[:] = pts[1:]
        else:
            start[:, :3] = pts[:-1]
            end[:, :3] = pts[1:]
            start[:, 3:] = self._rot0[rows]
            end[:, 3:] = self._rot1[rows]
        m["feed"] = self._feed[rows]
        m["tool"] = self._tool[rows]
        if spindle_rpm is None:
            m["spindle"] = self._spindle[rows]
            m["spindle_dir"] = self._sdir[rows]
        else:
            m["spindle"] = abs(float(spindle_rpm))
            if spindle_rpm == 0:
                m["spindle_dir"] = 0
            else:
                d = self._sdir[rows]
                m["spindle_dir"] = np.where(d != 0, d, 1 if spindle_rpm > 0 else -1)
        self._ids[:k] = rows + 1
        return m


def arrival_poses(points: np.ndarray, rows: np.ndarray, arrived_row: int | None = None):
    """The travelled polyline with a zero-length piece at every change of program row,
    owned by the row that arrived there: ``(points (k'+1, 3), rows (k',) int64)``.

    ``points`` (k+1, 3) mm, piece ``q`` = ``points[q] -> points[q+1]`` of row ``rows[q]``
    (k,); ``arrived_row``: the row whose piece ended at ``points[0]`` (None: unknown).

    Why: the swept volume of a move includes the tool at its end, but the kernel decides
    a ray at exactly the tool radius from that end with arithmetic relative to the move's
    *start*, while the next move (a straight retract from that point) decides it relative
    to the point itself. The two can disagree in the last bit. Rays at exactly the radius
    are common (round program coordinates on a 0.5 mm grid: the rays at a slot's end and
    walls), and each is a whole column of material handed to the next row: a retract
    after a feed then reads as a rapid into stock. Cutting the arrival pose with the next
    piece's own arithmetic (a zero-length move from the same point) makes the two agree.
    """
    points = np.asarray(points, np.float64)
    rows = np.asarray(rows, np.int64)
    if rows.size == 0:
        return points, rows
    before = np.empty_like(rows)
    before[0] = rows[0] if arrived_row is None else int(arrived_row)
    before[1:] = rows[:-1]
    turn = np.nonzero(before != rows)[0]
    if turn.size == 0:
        return points, rows
    return np.insert(points, turn, points[turn], axis=0), np.insert(rows, turn, before[turn])


# --- findings as JSON records ---------------------------------------------------------------

def lead_time(finding: Finding, path: ProgramPath, progress: float, feed_override: float = 100.0) -> float:
    """Predicted seconds until the spindle reaches the finding's move (0 if already there).

    Program time from the current progress to the start of the first offending row, scaled
    by the feed override (a 200 % override halves it).
    """
    stages = finding.stages or (finding.stage,)
    row = int(min(stages)) - 1
    if row < 0 or row >= path.row_t0.size:
        return 0.0
    scale = 100.0 / feed_override if feed_override and feed_override > 0 else 1.0
    return max(float(path.row_t0[row]) - float(progress), 0.0) * scale


def finding_record(f: Finding, lead: float, t: float | None = None, predicted: bool = True,
                   stage: int | None = None, path: ProgramPath | None = None, moves=None) -> dict:
    """The JSON object of one finding: ``Finding.to_json()`` + ``lead_time_s``, ``predicted``
    and ``status`` (``"predicted"`` ahead of the spindle, ``"happened"`` on the real motion)
    (+ ``t``).

    With ``path`` its ``time_s`` is the program time at which its worst move starts
    (the move table's timing); with ``moves`` (the program in work coordinates) its
    ``programmed`` point is where that move was programmed to take the tip (the live
    checks cut the travelled path, whose pieces end elsewhere).

    The checker's ``stage`` is a move id (row + 1): it is told as ``move``, so that
    ``stage`` means one thing in a run, the live stage (the model after the n-th recorded
    cut, 0 = the stock), given only where the finding happened (``stage``)."""
    d = f.to_json()
    d["move"] = int(d.pop("stage", 0) or 0)
    row = d["move"] - 1
    if path is not None and 0 <= row < path.row_t0.size:
        d["time_s"] = round(float(path.row_t0[row]), 3)
    if moves is not None and 0 <= row < len(moves):
        tip = np.array(moves["end"][row, :3], np.float64)
        tip[2] -= float(moves["tool_length"][row])
        d["programmed"] = [round(float(v), 4) for v in tip]
    if stage is not None:
        d["stage"] = int(stage)
    d["lead_time_s"] = round(float(lead), 3) if math.isfinite(lead) else None
    d["predicted"] = bool(predicted)
    d["status"] = "predicted" if predicted else "happened"
    if t is not None:
        d["t"] = float(t)
    return d
