"""Axial engagement seen from above, and the checks on it: axial depth of cut over a
limit, and plunges with a tool that does not cut at its centre.

:class:`Engagement` follows the top surface of the stock (its kernels are in
:mod:`.engagement_kernels`); :func:`depth_of_cut_of` reads the depth of cut from what a
cut recorded. Positions are the tool tip's, machine coordinates in mm
(``sim.gcode.moves.tip_positions``).
"""

from __future__ import annotations

import numpy as np

from sim.checks.arrays import distinct, runs_of
from sim.checks.engagement_kernels import (SHAPE_BALL, SHAPE_FLAT, SHAPE_TABLE, engage, engage_changed,
                                           piece_frames, resync_top)
from sim.checks.findings import Finding, line_span
from sim.checks.motion import arc_tangents, descent_deg, is_motion, move_ids_of, path_polyline
from sim.checks.where import deepest_cut, line_entry, met_at
from sim.errors import InputError


class Engagement:
    """Follows the top surface of the stock seen from above and measures, per move, the
    axial depth of cut (thickest column of material cut at any ray, mm) and the
    material cut under the tool centre (rays within ``core`` mm of the axis path).

    A top-view measure for monitoring (multi-segment rays count from their top): it keeps
    its own height map. Standalone, :meth:`run` walks every ray under the tool; after the
    real cut (the Checker's way) it looks only at the rays the cut changed, which costs a
    fraction of the cut. Ball and flat ends use the exact lowest point of the swept sphere
    or disc (the cutter's closed forms), other tools a sampled lower envelope.
    ``top`` is the stock's heights (``DexelGrid.top()``, (nv, nu), NaN where empty); the
    frame must look along +Z.
    """

    def __init__(self, frame, top, tool, chord: float = 0.01):
        if not frame.is_top:
            raise InputError("depth-of-cut and plunge checks need a top-view grid (rays along +Z)")
        self.frame = frame
        self.top = np.array(top, np.float64).reshape(-1)
        self.tool = tool
        self.chord = chord
        R = float(tool.cutting_radius)
        self.R = R
        self.env_d = np.linspace(0.0, R, 257)
        self.env_h = np.nan_to_num(np.asarray(tool.lowest_height(self.env_d), np.float64), nan=0.0)
        self.core = max(0.75 * frame.spacing, 0.05 * R)
        ball = R - np.sqrt(np.maximum(R * R - self.env_d**2, 0.0))
        if np.all(self.env_h == 0.0):
            self.shape = SHAPE_FLAT
        elif np.allclose(self.env_h, ball, rtol=0.0, atol=1e-9):
            self.shape = SHAPE_BALL
        else:
            self.shape = SHAPE_TABLE
        # rays on the tool's boundary: the cutter's rounding may reach them where ours does not
        self.slack = 1e-6
        self._buf = None
        #: per row of the last :meth:`run`: the descent (deg below horizontal) of the path
        #: where it first cut under the tool centre, NaN where it did not, and for arcs the
        #: tip there ((n, 3) mm, NaN for lines and elsewhere) (:func:`entry_angles`)
        self.entry_deg = np.zeros(0)
        self.entry_at = np.zeros((0, 3))

    def run(self, moves: np.ndarray, cut=None, grid=None):
        """Advance through ``moves``; returns ``(doc, core_depth)``, float64 (n,) mm each.

        Without ``cut`` every ray under the tool is looked at. With ``cut`` (the
        :class:`sim.cut.CutResult` of cutting exactly these moves, changes recorded)
        only the rays each move really changed are, which costs a small fraction of the
        cut itself; with ``grid`` too (the grid that was cut) the heights of those rays
        are then taken from it, so the estimate follows the real model.
        """
        moves = np.asarray(moves)
        n = len(moves)
        doc = np.zeros(n)
        core = np.zeros(n)
        self.entry_deg = np.full(n, np.nan)
        self.entry_at = np.full((n, 3), np.nan)
        p0, p1, row = path_polyline(moves, self.chord, which="tip")
        if row.size == 0:
            return doc, core
        f = self.frame
        x0, y0 = float(f.origin[0]), float(f.origin[1])
        pf = piece_frames(np.ascontiguousarray(p0), np.ascontiguousarray(p1))
        piece_ptr = np.searchsorted(row, np.arange(n + 1)).astype(np.int64)
        entry_q, entry_top = np.full(n, -1, np.int64), np.full(n, np.nan)
        if cut is None:
            engage(self.top, x0, y0, f.spacing, f.nu, f.nv, pf, row, piece_ptr, self.shape, self.R, self.slack,
                    self.env_d, self.env_h, self.core, doc, core, entry_q, entry_top)
            self.entry_deg, self.entry_at = entry_angles(moves, p0, p1, piece_ptr, core, entry_q, entry_top)
            return doc, core
        chg_ptr = np.asarray(cut.changed_ptr, np.int64)
        chg_rays = np.asarray(cut.changed_rays, np.int64)
        if chg_ptr.size != n + 1:
            raise InputError(f"cut result covers {chg_ptr.size - 1} moves, expected {n} with changes recorded")
        arcs = bool(np.any(np.diff(piece_ptr) > 1))
        # ball and flat lines follow the cutter's own closed forms; sampled envelopes
        # and arc chords only approximate it, so those take the model's heights after
        resync = grid is not None and chg_rays.size > 0 and (self.shape == SHAPE_TABLE or arcs)
        if self._buf is None and (arcs or resync):  # per-ray scratch, only when needed
            self._buf = (np.full(f.n_rays, np.nan), np.full(f.n_rays, np.nan))
        buf = self._buf if self._buf is not None else (np.zeros(0), np.zeros(0))
        engage_changed(self.top, x0, y0, f.spacing, f.nu, f.nv, pf, piece_ptr, self.shape, self.R, self.slack,
                        self.env_d, self.env_h, self.core, chg_ptr, chg_rays, buf[0], buf[1], doc, core, entry_q,
                        entry_top)
        if resync:
            resync_top(grid.S, chg_rays, self.top, self._buf[0])
        self.entry_deg, self.entry_at = entry_angles(moves, p0, p1, piece_ptr, core, entry_q, entry_top)
        return doc, core


def entry_angles(moves, p0, p1, piece_ptr, core, entry_q, entry_top) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the descent (deg below horizontal) of the tip's path where it enters
    material under the tool centre, NaN where it cut nothing there; and for arcs the tip
    at that point ((n, 3) mm, NaN for lines).

    A line has one direction. An arc turns: its chord says nothing of how it enters (a
    full-turn helix has none, a dive and climb back a level one), so it is the tangent
    of the arc at the point where the piece ``entry_q`` that first cut under the centre
    crosses the top it cut there (``entry_top``, mm): the helix's pitch over its length
    for a helix, the circle's own slope for an arc in a vertical plane."""
    n = len(moves)
    out = np.full(n, np.nan)
    at = np.full((n, 3), np.nan)
    count = np.diff(piece_ptr)
    line = np.flatnonzero((count == 1) & (core > 0.0))
    out[line] = descent_deg(p1[piece_ptr[line]] - p0[piece_ptr[line]])
    arc = np.flatnonzero((count > 1) & (entry_q >= 0))
    if arc.size:
        q = entry_q[arc]
        z0, z1 = p0[q, 2], p1[q, 2]
        # the crossing of the entered top on the piece, by its tip's height (the start for a
        # piece that does not go down: it entered sideways)
        drop = z0 - z1
        within = np.clip(np.divide(z0 - entry_top[arc], drop, out=np.zeros(arc.size), where=drop > 0), 0.0, 1.0)
        t = (q - piece_ptr[arc] + within) / count[arc]
        out[arc] = descent_deg(arc_tangents(moves[arc], t))
        at[arc] = p0[q] + within[:, None] * (p1[q] - p0[q])
    return out, at


def depth_of_cut_of(cut) -> np.ndarray:
    """Axial depth of cut of each move, float64 (n,) mm, from a :class:`sim.cut.CutResult`
    with changes recorded: the largest ``changed_depth`` over the rays the move changed
    (how far it lowered a ray's material top, or the length it took off a ray where the
    top stayed - a cut below an overhang - or that it emptied); 0 where nothing changed.
    """
    ptr = np.asarray(cut.changed_ptr, np.int64)
    depth = np.asarray(cut.changed_depth)
    doc = np.zeros(ptr.size - 1)
    if depth.size == 0:
        return doc
    if depth.size != int(ptr[-1]):
        raise InputError(f"cut result holds {depth.size} depths for {int(ptr[-1])} changed rays")
    hit = np.nonzero(ptr[1:] > ptr[:-1])[0]
    # segments of consecutive non-empty moves tile the entries: reduceat over their starts
    doc[hit] = np.maximum.reduceat(depth, ptr[hit])
    return doc


def depth_of_cut(moves: np.ndarray, doc, limit: float, move_ids=None, cut=None, grid=None) -> list[Finding]:
    """Moves whose axial depth of cut ``doc`` (float64 (n,) mm) is over ``limit`` mm: one
    finding per run of consecutive offending moves, at the deepest (what
    :func:`merge_findings` makes of one finding per move). Position: with ``cut`` (the
    batch's CutResult) and ``grid`` (the model after it), the floor of the deepest cut of
    the deepest move (:func:`sim.checks.where.deepest_cut`); else that move's end."""
    moves = np.asarray(moves)
    ids = move_ids_of(moves, move_ids)
    doc = np.asarray(doc, np.float64)
    bad = np.nonzero(doc > limit)[0]
    out = []
    for run in runs_of(ids[bad]):
        ks = bad[run]
        k = int(ks[int(np.argmax(doc[ks]))])
        tip = met_at(moves, k, deepest_cut, cut, grid)
        lines = distinct(moves["line"][ks]).tolist()
        msg = f"depth of cut {float(doc[k]):.3f} mm over the {limit:g} mm limit at line {int(moves['line'][k])}"
        if ks.size > 1:
            msg += f" ({line_span(lines)}, {ks.size} moves)"
        out.append(Finding(kind="depth_of_cut", line=int(moves["line"][ks[0]]), worst_line=int(moves["line"][k]),
                           lines=tuple(lines), stage=int(ids[k]),
                           stages=tuple(ids[ks].tolist()), position=tuple(tip), depth=float(doc[k]),
                           message=msg, detail={"limit": limit}))
    return out


def plunges(moves: np.ndarray, core_depth, tool, max_ramp_deg: float = 10.0, min_depth: float = 0.01,
            move_ids=None, entry_deg=None, entry_at=None, cut=None, grid=None, near: float = 0.0,
            rows=None) -> list[Finding]:
    """Entries into material steeper than ``max_ramp_deg`` (degrees below horizontal)
    that cut under the tool centre (``core_depth`` > ``min_depth`` mm), for a tool that
    does not cut at its centre (``tool.center_cutting`` False); none otherwise.
    ``entry_deg`` (n,): each row's descent where it entered material
    (:attr:`Engagement.entry_deg` of the run that measured ``core_depth``); where it is
    not given or NaN, the move's chord (right for lines only). Position: where the tip
    entered material: an arc's ``entry_at`` ((n, 3), :attr:`Engagement.entry_at`); a
    line's, with ``cut`` (the batch's CutResult) and ``grid`` (the model after it), at the
    highest top it met within ``near`` mm of its path (:func:`sim.checks.where.line_entry`);
    else the move's end. ``rows``: the rows of ``moves`` to check (default all; those
    ``tool`` cut)."""
    if getattr(tool, "center_cutting", True):
        return []
    moves = np.asarray(moves)
    ids = move_ids_of(moves, move_ids)
    s = np.array(moves["start"][:, :3], np.float64)
    e = np.array(moves["end"][:, :3], np.float64)
    chord = descent_deg(e - s)
    angle = chord if entry_deg is None else np.where(np.isnan(entry_deg), chord, entry_deg)
    bad = np.nonzero((np.asarray(core_depth) > min_depth) & (angle > max_ramp_deg) & is_motion(moves))[0]
    if rows is not None:
        bad = bad[np.isin(bad, rows)]
    out = []
    for k in bad:
        tip = entry_at[k] if entry_at is not None else np.full(3, np.nan)
        if not np.isfinite(tip).all():
            tip = met_at(moves, k, lambda m, k_, c, g: line_entry(m, k_, c, g, near), cut, grid)
        out.append(Finding(kind="non_center_cutting_plunge", line=int(moves["line"][k]), stage=int(ids[k]),
                           position=tuple(tip), depth=float(core_depth[k]),
                           message=(f"plunge at {angle[k]:.0f} deg into material with a tool that does not "
                                    f"cut at its centre, line {int(moves['line'][k])}"),
                           detail={"angle_deg": float(angle[k])}))
    return out
