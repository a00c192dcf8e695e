"""The one entry point the monitor calls: cut and check, look ahead, assess a whole model."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sim.checks import collisions, motion
from sim.checks.arrays import distinct
from sim.checks.engagement import Engagement, depth_of_cut, depth_of_cut_of, plunges
from sim.checks.error_map import DesignModel, ErrorMap
from sim.checks.findings import Finding, merge_findings
from sim.checks.spindle import spindle_off_from, spindle_stopped_cutting
from sim.checks.travel import travel_limits
from sim.checks.tri import TriErrorMap, TriModelCutter, is_tri, top_bound, tri_designs, z_part
from sim.cut import CutResult, Cutter
from sim.errors import InputError
from sim.gcode.moves import MoveKind
from sim.grid import DexelGrid
from sim.tolerance import DEFAULT, Tolerance
from sim.tools import Tool
from sim.tridexel import TriDexel


class Checker:
    """Cuts moves into a stock model and reports what went wrong.

    Parameters
    ----------
    stock : DexelGrid or TriDexel
        The live model (cut in place by :meth:`cut_and_check`): one grid, or a
        tri-dexel model (:mod:`sim.tridexel`; cut, probed and assessed on its three
        grids, see :mod:`.tri`; the findings are the same kinds with the same fields).
    tool : Tool
        The tool in the spindle (``tools`` maps tool numbers to tools for programs
        with tool changes; rows use ``tools[row["tool"]]`` when present).
    design : DesignModel, trimesh.Trimesh or path, optional
        The part to compare with (gouge during cutting, gouge and undercut after).
    fixtures : iterable of :class:`collisions.Fixture`
    limits : dict axis -> (min, max) machine coords, optional
    tol : Tolerance
        ``gouge`` = t_l, ``undercut`` = t_h, ``interest`` = range of interest (mm).
    max_depth_of_cut : float, optional
        Axial depth of cut limit (mm); the depth-of-cut check runs only when given.
    max_ramp_deg : float
        Entries steeper than this are plunges (for tools that do not cut at the centre).
    min_volume : float, optional
        Contacts and removals smaller than this (mm^3) are noise; default a tenth of a
        grid column one spacing high.
    undercut_from_path : bool
        The undercut tolerance is at least the scallop a ball leaves at the path's
        stepover (:mod:`.scallop`), so that a clean finishing raster raises no scallop
        crests as undercut. False when the user asked for an undercut tolerance.
    exact_excess_while_cutting : bool
        The error map kept by :meth:`cut_and_check` also holds the exact size of the
        material left. Off by default: cutting reports gouges only (their sizes stay
        exact) and :meth:`assess_model` assesses the material left afresh, while the exact
        search on that side is most of the check's cost when the cut surface lies just
        above the design (a finishing pass).
    kinematics, origin : optional
        The machine's :class:`sim.kinematics.Kinematics` and the grid origin's machine
        pose (6,), passed to every :class:`Cutter` (rows with rotation are cut on the
        turned part). Fixtures carry their own (:class:`collisions.Fixture`: on the rotary
        table they turn with the part).
    tool_lengths : optional
        {tool number: mm} the G43 length a turning head places each tool by, for move
        tables of tips (see :class:`Cutter`).
    """

    def __init__(self, stock: DexelGrid, tool: Tool, design=None, fixtures=(), limits=None,
                 tol: Tolerance = DEFAULT, tools: dict | None = None, max_depth_of_cut: float | None = None,
                 max_ramp_deg: float = 10.0, min_volume: float | None = None, undercut_from_path: bool = True,
                 exact_excess_while_cutting: bool = False, kinematics=None, origin=None, tool_lengths=None):
        if not isinstance(stock, (DexelGrid, TriDexel)):
            raise InputError(f"Checker needs a DexelGrid or TriDexel stock, got {type(stock).__name__}")
        self.grid = stock
        self.frame = z_part(stock).frame  # a tri-dexel model's findings are told on its Z grid
        self.tool = tool
        self.tools = dict(tools or {})
        self.tol = tol
        self.kinematics = kinematics
        self.origin = origin
        self.tool_lengths = tool_lengths
        self.min_volume = (0.1 * self.frame.spacing**3) if min_volume is None else float(min_volume)
        self.cutter = self._cutter(stock)
        if design is not None and not isinstance(design, DesignModel):
            design = DesignModel(self.frame, design)
        self.design = design
        #: {axis: DesignModel} of a tri-dexel model (the design cast on each grid)
        self._designs = tri_designs(stock, design) if is_tri(stock) and design is not None else None
        self.error_map = self._new_error_map(self.frame) if design is not None else None
        self.fixtures = list(fixtures)
        self.limits = dict(limits) if limits else None
        self.max_depth_of_cut = max_depth_of_cut
        self.max_ramp_deg = max_ramp_deg
        if is_tri(stock):
            self._top_bound = top_bound(stock)
        else:
            self._top_bound = collisions.max_top(stock) if self.frame.is_top else np.inf
        # the depth of cut comes from the cut's own log (CutResult.changed_depth); the
        # engagement's height map is kept only for plunges of non-centre-cutting tools
        needs_engagement = any(not t.center_cutting for t in [tool, *self.tools.values()])
        self.engagement = (Engagement(self.frame, z_part(stock).top(), tool, chord=tol.chord)
                           if needs_engagement and self.frame.is_top else None)
        self.undercut_from_path = bool(undercut_from_path)
        self.exact_excess_while_cutting = bool(exact_excess_while_cutting)
        #: (scallop.Raster, Tool) the undercut tolerance followed (set by assess_model)
        self.undercut_basis = None
        self._lines = np.zeros(1, np.int64)  # move id -> program line
        self._tips = np.full((1, 6), np.nan)  # move id -> programmed tip at start, end (mm)
        self._tool_nums = np.zeros(1, np.int64)  # move id -> tool number
        self._feed = np.zeros(1, bool)  # move id -> a feed (G1) row
        self._move_t0 = None  # move id - 1 -> machine time at its start (s), when told
        self._spindle_off = None  # the spindle at the last batch's end (spindle_off_from)
        self._fixture_left: dict = {}  # fixture index -> {part: what it has not touched yet}
        self._touched: dict = {}  # contact kind -> Cutter on the model less what that body touched
        self._bodies: dict = {}
        self.findings: list[Finding] = []

    def _cutter(self, grid):
        """A Cutter on ``grid`` (a :class:`TriModelCutter` on a tri-dexel model) with
        this checker's tools, tolerance and kinematics."""
        if is_tri(grid):
            return TriModelCutter(grid, self.tool, self.tol, tools=self.tools or None, kinematics=self.kinematics,
                                  origin=self.origin, tool_lengths=self.tool_lengths, floor=self.min_volume)
        return Cutter(grid, self.tool, self.tol, tools=self.tools or None, kinematics=self.kinematics,
                      origin=self.origin, tool_lengths=self.tool_lengths)

    def _new_error_map(self, frame):
        """An empty error map on ``frame`` (all three grids' on a tri-dexel model)."""
        if self._designs is not None:
            return TriErrorMap(self._designs, self.grid.lo, self.grid.spacing)
        return ErrorMap(frame)

    # --- bookkeeping --------------------------------------------------------------------
    def _remember_lines(self, moves, ids):
        """Keep each move's line, programmed tip, tool and kind by move id."""
        if len(ids) == 0:
            return
        top = int(ids.max())
        if top >= self._lines.size:
            size = max(top + 1, 2 * self._lines.size)
            self._lines = _grown(self._lines, size, 0)
            self._tips = _grown(self._tips, size, np.nan)
            self._tool_nums = _grown(self._tool_nums, size, 0)
            self._feed = _grown(self._feed, size, False)
        self._lines[ids] = moves["line"]
        length = np.asarray(moves["tool_length"], np.float64)
        self._tips[ids, :3] = moves["start"][:, :3]
        self._tips[ids, 3:] = moves["end"][:, :3]
        self._tips[ids, 2] -= length
        self._tips[ids, 5] -= length
        self._tool_nums[ids] = moves["tool"]
        self._feed[ids] = motion.is_motion(moves) & (moves["kind"] != int(MoveKind.RAPID))

    def set_move_times(self, t0) -> None:
        """Machine time (s from the program start) at which each move starts, float (n,)
        indexed by move id - 1 (``sim.gcode.timing.cycle_time``'s per-row seconds summed):
        findings then tell when they happen (``Finding.time_s``)."""
        self._move_t0 = np.asarray(t0, np.float64).reshape(-1)

    def annotate(self, findings) -> list[Finding]:
        """``findings`` with the programmed tip of their worst move (its end, the
        controlled point's table coordinates less the tool length) and the machine time
        it starts, where known and not already set."""
        out = []
        for f in findings:
            k = int(f.stage)
            changes = {}
            if 0 < k < self._tips.shape[0] and not np.isfinite(f.programmed).all() and np.isfinite(
                    self._tips[k, 3:]).all():
                changes["programmed"] = tuple(float(v) for v in self._tips[k, 3:])
            t0 = self._move_t0
            if t0 is not None and 0 < k <= t0.size and not np.isfinite(f.time_s):
                changes["time_s"] = float(t0[k - 1])
            out.append(replace(f, **changes) if changes else f)
        return out

    def _tool_of_rows(self, moves) -> list[tuple[Tool, np.ndarray]]:
        if not self.tools:
            return [(self.tool, np.arange(len(moves)))]
        out = []
        col = moves["tool"]
        for num in distinct(col):
            out.append((self.tools.get(int(num), self.tool), np.nonzero(col == num)[0]))
        return out

    # --- cutting ------------------------------------------------------------------------
    def cut_and_check(self, moves: np.ndarray, move_ids=None) -> tuple[CutResult, list[Finding]]:
        """Cut ``moves`` into the live model and check them.

        Returns the cut result and the findings of this batch (merged). Everything found
        is also kept in :attr:`findings`.
        """
        moves = np.asarray(moves)
        ids = motion.move_ids_of(moves, move_ids)
        self._remember_lines(moves, ids)
        found = self._check_batch(self.grid, self.cutter, moves, ids, self.error_map, self.engagement,
                                  design_rays=None, top_bound=self._top_bound, spindle_off=self._spindle_off,
                                  fixture_left=self._fixture_left, touched=self._touched)
        span = spindle_off_from(moves, ids, self._spindle_off)
        if len(moves):
            self._spindle_off = tuple(int(v) for v in span[-1])
        res, batch = found
        self.findings.extend(batch)
        return res, batch

    def check_program(self, moves: np.ndarray, move_ids=None, batch: int = 2048) -> np.ndarray:
        """Cut and check a whole program, ``batch`` rows at a time; returns float64 (n,)
        mm^3 removed by each row.

        Same findings as one :meth:`cut_and_check` of everything (kept in
        :attr:`findings`), but the changed-ray log of only one batch is alive at a time,
        so memory stays bounded on long programs.
        """
        moves = np.asarray(moves)
        ids = motion.move_ids_of(moves, move_ids)
        removed = np.zeros(len(moves))
        for a in range(0, len(moves), max(int(batch), 1)):
            b = min(a + max(int(batch), 1), len(moves))
            res, _ = self.cut_and_check(moves[a:b], ids[a:b])
            removed[a:b] = res.removed
        return removed

    def forget_contacts(self) -> None:
        """Forget what bodies touched (the model was replaced: a look-ahead re-anchored)."""
        self._touched = {}

    def _check_batch(self, grid, cutter, moves, ids, error_map, engagement, design_rays, top_bound,
                     spindle_off=None, fixture_left=None, touched=None):
        """Cut and check one batch. ``spindle_off``: the spindle as the batch starts
        (the last pair :func:`spindle_off_from` gave the batch before); ``fixture_left``: {fixture index: {part: untouched fixture}} and
        ``touched``: {contact kind: cutter on the model less what that body touched}, kept
        across batches (fresh ones: volumes of this batch only)."""
        touched = {} if touched is None else touched
        out: list[Finding] = []
        fixture_left = {} if fixture_left is None else fixture_left
        if self.limits:
            out += travel_limits(moves, self.limits, ids)
        for k, fx in enumerate(self.fixtures):
            for tool, rows in self._tool_of_rows(moves):
                out += fx.check(moves[rows], tool, ids[rows], self.min_volume, left=fixture_left.setdefault(k, {}))
        # non-cutting bodies: probe before the cut; only candidates are verified in order
        pre = self._body_candidates(grid, cutter, moves, top_bound)
        snapshot = grid.copy() if pre else None
        res = cutter.cut_moves(moves, move_ids=ids.astype(np.int32))
        # a tri-dexel model's top view (depth of cut, plunges, where a rapid entered): its Z grid
        zres, zgrid = z_part(res), z_part(grid)
        if self.max_depth_of_cut is not None:
            doc = depth_of_cut_of(zres)
            out += depth_of_cut(moves, doc, self.max_depth_of_cut, ids, cut=zres, grid=zgrid)
        if engagement is not None:
            # after the cut: only the rays each move changed can have lost material
            _, core = engagement.run(moves, cut=zres, grid=zgrid)
            for tool, rows in self._tool_of_rows(moves):
                out += plunges(moves, core, tool, self.max_ramp_deg, move_ids=ids, rows=rows,
                               entry_deg=engagement.entry_deg, entry_at=engagement.entry_at, cut=zres,
                               grid=zgrid, near=engagement.core)
        removed = res.removed
        turned = collisions.turned_rows(moves, self.kinematics, self.origin)
        if turned.any():  # cusps of earlier instances shaved by a later pass are no contact
            step = self.tol.instance_fraction * zgrid.frame.spacing
            removed = np.where(collisions.instance_slivers(zres, turned, step), 0.0, removed)
        out += collisions.rapid_into_stock(moves, removed, ids, self.min_volume, cut=zres, grid=zgrid)
        out += spindle_stopped_cutting(moves, removed, ids, self.min_volume, carry=spindle_off, cut=zres,
                                       grid=zgrid)
        if pre:
            out += self._replay_contacts(snapshot, moves, ids, pre, touched)
        else:
            for mine in touched.values():  # they follow the flutes too
                mine.cut_moves(moves, move_ids=ids.astype(np.int32), record_changes=False)
        if isinstance(error_map, TriErrorMap):
            rays = error_map.update(grid, {a: r.changed_rays for a, r in res.by_axis.items()}, self.tol,
                                    exact_excess=self.exact_excess_while_cutting)
            if rays.size and error_map.last_worst < -self.tol.gouge:
                out += error_map.findings(self.tol, self._lines, rays=rays, undercut=False, join=self.reach())
        elif error_map is not None and res.changed_rays.size:
            rays = error_map.update(grid, self.design, res.changed_rays, self.tol, design_rays=design_rays,
                                    exact_excess=self.exact_excess_while_cutting)
            if rays.size and np.nanmin(error_map.gouge[rays]) < -self.tol.gouge:
                out += error_map.findings(self.tol, self._lines, rays=rays, undercut=False, join=self.reach())
        return res, self.annotate(merge_findings(out))

    def reach(self) -> float:
        """Largest cutting radius of the tools (mm): error regions closer than this are one."""
        return max([self.tool.cutting_radius] + [t.cutting_radius for t in self.tools.values()])

    def _contact_bodies(self, tool):
        """:func:`collisions.contact_bodies` of ``tool``, made once per tool."""
        got = self._bodies.get(id(tool))
        if got is None or got[0] is not tool:
            got = (tool, collisions.contact_bodies(tool))
            self._bodies[id(tool)] = got
        return got[1]

    def _body_candidates(self, grid, cutter, moves, top_bound):
        """{row: [(kind, body)]} of rows whose non-cutting bodies meet material now."""
        cand: dict[int, list] = {}
        for tool, rows in self._tool_of_rows(moves):
            for kind, body in self._contact_bodies(tool):
                sel = rows[collisions.reachable(moves[rows], body.bottom, top_bound, self.kinematics, self.origin,
                                                body=body, step=self.frame.spacing,
                                                tool_lengths=self.tool_lengths)]
                if sel.size == 0:
                    continue
                vol = cutter.probe_moves(moves[sel], body=body)
                for k in sel[vol > self.min_volume]:
                    cand.setdefault(int(k), []).append((kind, body))
        return cand

    def _replay_contacts(self, snapshot, moves, ids, cand, touched) -> list[Finding]:
        """A body meets material at move k if the material is still there when the flutes
        of move k have passed: replay the batch on the snapshot through each candidate and
        probe the candidate's body then (so a shank following its flutes down a hole they
        cut is clear, while a holder landing on the stock is not). Bodies leading the
        flutes (moving up into material above the tool) are not seen this way."""
        scratch = self._cutter(snapshot)
        # the same replay with what each body touched taken away (``touched``, made at its
        # first contact and kept across batches): a move's volume is what its body touches
        # first, so the volumes of one contact's moves add up to the union of what they touched
        out: list[Finding] = []
        done = 0
        for k in sorted(cand):
            if k + 1 > done:
                for cutter in [scratch, *touched.values()]:
                    cutter.cut_moves(moves[done:k + 1], move_ids=ids[done:k + 1].astype(np.int32),
                                     record_changes=False)
                done = k + 1
            for kind, body in cand[k]:
                present = scratch.probe_moves(moves[k:k + 1], body=body)
                vol = present
                if present[0] > self.min_volume:
                    mine = touched.get(kind)
                    if mine is None:
                        mine = touched[kind] = self._cutter(scratch.grid.copy())
                    vol = mine.cut_moves(moves[k:k + 1], record_changes=False, body=body).removed
                out += collisions.body_findings(moves[k:k + 1], kind, vol, ids[k:k + 1], self.min_volume,
                                                present=present, cutter=scratch, body=body)
        for mine in touched.values():  # the rest of the batch's flutes
            mine.cut_moves(moves[done:], move_ids=ids[done:].astype(np.int32), record_changes=False)
        return out

    # --- look-ahead -------------------------------------------------------------------------
    def predict(self, moves: np.ndarray, move_ids=None) -> list[Finding]:
        """Check ``moves`` on a scratch window of the live model (never changed).

        The window covers the moves' XY extent grown by the largest tool/body radius.
        Returns the merged findings (not added to :attr:`findings`).
        """
        moves = np.asarray(moves)
        ids = motion.move_ids_of(moves, move_ids)
        self._remember_lines(moves, ids)
        if len(moves) == 0:
            return []
        f = self.frame
        if not f.is_top or self.cutter.kinematics is not None or is_tri(self.grid):
            # whole-model scratch copy for frames we cannot window by XY (or a turning
            # part, or a tri-dexel model)
            scratch = self.grid.copy()
            i0 = j0 = 0
        else:
            p0, p1, _ = motion.path_polyline(moves, self.tol.chord * 10, which="tip")
            if p0.shape[0] == 0:
                scratch = None
            pts = np.concatenate([p0, p1]) if p0.shape[0] else np.zeros((0, 3))
            reach = max([self.tool.diameter] + [b.max_radius for _, b in self._contact_bodies(self.tool)]
                        + [t.diameter for t in self.tools.values()]) + 2 * f.spacing
            if pts.shape[0] == 0:
                return merge_findings(travel_limits(moves, self.limits, ids) if self.limits else [])
            i0 = int(np.floor((pts[:, 0].min() - reach - f.origin[0]) / f.spacing))
            i1 = int(np.ceil((pts[:, 0].max() + reach - f.origin[0]) / f.spacing)) + 1
            j0 = int(np.floor((pts[:, 1].min() - reach - f.origin[1]) / f.spacing))
            j1 = int(np.ceil((pts[:, 1].max() + reach - f.origin[1]) / f.spacing)) + 1
            i0, j0 = max(i0, 0), max(j0, 0)
            i1, j1 = min(i1, f.nu), min(j1, f.nv)
            if i1 <= i0 or j1 <= j0:  # entirely off the stock: only the machine checks apply
                out = travel_limits(moves, self.limits, ids) if self.limits else []
                for fx in self.fixtures:
                    out += fx.check(moves, self.tool, ids, self.min_volume)
                return merge_findings(out)
            scratch = self.grid.window(i0, i1, j0, j1)
        sf = z_part(scratch).frame
        nu_full = f.nu

        def to_full(r, _i0=i0, _j0=j0, _nu=sf.nu):
            return (r // _nu + _j0) * nu_full + (r % _nu + _i0)

        cutter = self._cutter(scratch)
        emap = self._new_error_map(sf) if self.design is not None else None
        eng = None
        if self.engagement is not None and sf.is_top:
            eng = Engagement(sf, z_part(scratch).top(), self.tool, chord=self.tol.chord)
        _, found = self._check_batch(scratch, cutter, moves, ids, emap, eng,
                                     design_rays=to_full if isinstance(emap, ErrorMap) else None,
                                     top_bound=self._top_bound)
        return found

    # --- after the run ----------------------------------------------------------------------
    def assess_model(self, faces: str = "cut", undercut: bool = True, min_rays: int = 1) -> list[Finding]:
        """Whole-model error assessment (Huang & Oliver's post-process): every assessed
        dexel point of the model against the design; gouge and undercut regions.

        Returns [] without a design.
        """
        if self.design is None:
            return []
        self.error_map = self._new_error_map(self.frame)
        if isinstance(self.error_map, TriErrorMap):
            self.error_map.update_all(self.grid, self.tol, faces=faces)
        else:
            self.error_map.update(self.grid, self.design, np.arange(self.frame.n_rays), self.tol, faces=faces)
        allowance = self.undercut_allowance() if undercut else None
        return self.annotate(self.error_map.findings(self.tol, self._lines, undercut=undercut, min_rays=min_rays,
                                                     join=self.reach(), undercut_limit=allowance,
                                                     detail_of=self._reach_detail() if undercut else None))

    def _reach_detail(self):
        """For the whole-model assessment of a 3-axis Z grid: a function giving an undercut
        region's ``unreachable_share`` (:func:`reach.unreachable_share`: how much of its
        material the finishing tool cannot reach without a gouge) and that tool, or None."""
        from sim.checks import reach

        tool = self._finishing_tool()[0]
        if (tool is None or self.kinematics is not None or isinstance(self.error_map, TriErrorMap)
                or not self.frame.is_top):
            return None
        tops = []   # (design, model) heights, read at the first undercut region

        def detail_of(kind, members):
            if kind != "undercut":
                return {}
            if not tops:
                tops.extend((self.design.top(), self.grid.top().astype(np.float64)))
            share = reach.unreachable_share(*tops, members, tool, self.frame.spacing, self.tol.undercut)
            if share is None:
                return {}
            return {"unreachable_share": round(share, 3), "finishing_tool": tool.describe()}
        return detail_of

    def _finishing_tool(self):
        """The tool that cut the longest feed path (it finishes the part) and a bool mask of
        the moves it cut (indexed by move id), or (None, None) without feed moves."""
        n = self._lines.size
        feed = self._feed[:n] & np.isfinite(self._tips[:n]).all(axis=1)
        if not feed.any():
            return None, None
        nums = self._tool_nums[:n][feed]
        lengths = np.linalg.norm(self._tips[:n][feed, 3:5] - self._tips[:n][feed, :2], axis=1)
        best = {}
        for num, ln in zip(nums.tolist(), lengths.tolist()):
            best[num] = best.get(num, 0.0) + ln
        num = max(best, key=best.get)
        sel = feed.copy()
        sel[feed] = nums == num
        return self.tools.get(int(num), self.tool), sel

    def undercut_allowance(self):
        """Per-ray undercut tolerance (float64 (n_rays,) mm) from the path, or None: the
        scallop the path's ball leaves at its stepover on the design's local slope
        (:func:`scallop.allowance`), never below ``tol.undercut``. None when the user asked
        for an undercut tolerance, or the path is no ball raster."""
        if not self.undercut_from_path or self.design is None:
            return None
        from sim.checks import scallop

        tool, sel = self._finishing_tool()
        if tool is None:
            return None
        raster = scallop.raster_of(self._tips[:sel.size][sel])
        if raster is None:
            return None
        got = scallop.allowance(self.design, tool, raster, self.tol.undercut)
        if got is not None:
            self.undercut_basis = (raster, tool)
        return got

    def all_findings(self) -> list[Finding]:
        """Everything found while cutting, merged."""
        return merge_findings(self.findings)


def _grown(a: np.ndarray, size: int, fill) -> np.ndarray:
    """``a`` grown along its first axis to ``size`` rows, new rows ``fill``."""
    out = np.full((size,) + a.shape[1:], fill, a.dtype)
    out[: a.shape[0]] = a
    return out
