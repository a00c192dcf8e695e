"""How a :class:`~sim.cut.Cutter` cuts rows a rotary axis turns (4th and 5th axes).

Such rows are cut by instances of motion (Huang & Oliver eq. 3-5) placed on the turning
part by the machine's :class:`~sim.kinematics.Kinematics`: every machine axis moves
linearly (along the arc for X Y Z of an arc), as GRBL and LinuxCNC's joint moves do, as
few instances as keep every point of the tool within the step of where it was. The body is
cut off above the height at which no instance can reach the material (a tilted or turned
tool's long flutes and shank sweep a wide footprint of rays holding nothing at their
height): the same cut, a smaller body.
"""

from __future__ import annotations

import math

import numpy as np

from sim import sweep
from sim.grid import DexelGrid
from sim.kinematics import ROTARY_COLUMN, Kinematics, instance_poses

#: points on each rim circle of the tool where :meth:`RotaryPlan._fewest_instances` measures
_RIM = 16
_UNIT_OF = {"A": np.array([1.0, 0.0, 0.0]), "B": np.array([0.0, 1.0, 0.0]), "C": np.array([0.0, 0.0, 1.0])}


def _within_radius(tips, axes, point, direction, radius: float, enter, leave):
    """``(enter, leave)`` narrowed to the heights h at which ``tips + h * axes`` ((k, 3))
    lies within ``radius`` of the line through ``point`` along unit ``direction``."""
    w = tips - point
    w = w - (w @ direction)[:, None] * direction
    k = axes - (axes @ direction)[:, None] * direction
    a = np.einsum("ij,ij->i", k, k)
    b = 2.0 * np.einsum("ij,ij->i", w, k)
    c = np.einsum("ij,ij->i", w, w) - radius * radius
    disc = b * b - 4.0 * a * c
    along = a < 1e-18  # the tool along the line: all heights or none
    with np.errstate(divide="ignore", invalid="ignore"):
        root = np.sqrt(np.maximum(disc, 0.0))
        h0 = (-b - root) / (2.0 * a)
        h1 = (-b + root) / (2.0 * a)
    enter = np.where(along, enter, np.maximum(enter, h0))
    leave = np.where(along, np.where(c <= 0, leave, -np.inf), np.minimum(leave, h1))
    leave = np.where(~along & (disc < 0), -np.inf, leave)
    return enter, leave


def placing_lengths(moves: np.ndarray, tool_lengths: dict[int, float] | None) -> np.ndarray:
    """float64 (n,) the tool length (mm) the kinematics places each row's tool by, from the
    gauge point to the tip along the tool axis: the rows' ``tool_length`` column, unless
    ``tool_lengths`` ({tool number: mm}) names the row's tool (a table of tips, whose
    column is 0)."""
    lengths = np.asarray(moves["tool_length"], np.float64).copy()
    for tool_no, length in (tool_lengths or {}).items():
        lengths[moves["tool"] == tool_no] = length
    return lengths


class RotaryPlan:
    """The rotary part of a cutter: ``grid`` (the model, in the part's frame),
    ``kinematics`` (with at least one rotary), ``origin`` (6,) the machine pose of the
    grid's frame origin, ``step`` (mm) the most any point of the tool may move between
    instances, ``eps`` (mm) the model's length tolerance. ``tool_lengths`` ({tool number:
    mm} or None): the G43 length a turning head places each tool by, in place of the
    rows' ``tool_length`` column (see :class:`~sim.cut.Cutter`)."""

    def __init__(self, grid: DexelGrid, kinematics: Kinematics, origin: np.ndarray, step: float, eps: float,
                 tool_lengths: dict[int, float] | None = None):
        self.grid = grid
        self.kinematics = kinematics
        self.origin = origin
        self.step = step
        self.eps = eps
        self.tool_lengths = tool_lengths
        self._rot_cols = np.array([ROTARY_COLUMN[r] for r in kinematics.rotaries])

    def turning_rows(self, moves, moving) -> np.ndarray | None:
        """Which ``moving`` rows a rotary of the kinematics turns (not all 0 at both ends,
        machine angles: the row's plus ``origin``), bool (n,); None when none does (or
        there is no kinematics), so a 3-axis batch pays one test at most."""
        if self._rot_cols.size == 0:
            return None
        o = self.origin[self._rot_cols]
        a0 = moves["start"][:, self._rot_cols] + o
        a1 = moves["end"][:, self._rot_cols] + o
        turning = moving & ((a0 != 0.0).any(axis=1) | (a1 != 0.0).any(axis=1))
        return turning if turning.any() else None

    def poses(self, row, tip0, tip1, body, arc=None) -> tuple[np.ndarray, np.ndarray]:
        """Instances of motion of one row with rotation: tips and axes ((k, 3) each) in the
        grid's frame. ``tip0``/``tip1`` (3,) mm are the row's tips as the table gives them
        (its X Y Z less its tool length); ``arc``: (centre (3,) tip coords, plane, turns,
        clockwise) for an arc row. Every machine axis moves linearly (along the arc for
        X Y Z of an arc), as GRBL and LinuxCNC's joint moves do; the count bounds how far
        any point of ``body`` (its profile's radius x height) moves between two."""
        kin = self.kinematics
        L = self.placing_length(row)
        lift = np.array([0.0, 0.0, L])
        a = np.concatenate([tip0 + lift, row["start"][3:]]) + self.origin
        b = np.concatenate([tip1 + lift, row["end"][3:]]) + self.origin
        prof = body.profile
        height, radius = float(prof[-1, 0]), float(prof[:, 1].max())
        count = int(kin.instance_counts(a, b, L, height, radius, self.step)[0])
        if arc is None:
            if count > 1:
                count = self._fewest_instances(instance_poses(a, b, count), L, height, radius)
            poses = instance_poses(a, b, count)
        else:
            center, plane, turns, cw = arc
            pts = sweep.arc_points(tip0, tip1, center, plane, turns, cw, max_step_length=self.step)
            if len(pts) - 1 < count:  # the rotaries need finer steps than the arc's path
                pts = sweep.arc_points(tip0, tip1, center, plane, turns, cw,
                                       max_step_length=self.step * (len(pts) - 1) / count)
            f = np.linspace(0.0, 1.0, len(pts))[:, None]
            poses = np.empty((len(pts), 6))
            poses[:, :3] = pts + lift + self.origin[:3]
            poses[:, 3:] = a[3:] + f * (b[3:] - a[3:])
        tips, axes = kin.forward(poses, L)
        return tips - self.origin[:3], axes

    def placing_length(self, row) -> float:
        """The tool length (mm) the kinematics places ``row``'s tool by (see
        :func:`placing_lengths`)."""
        return float(placing_lengths(np.asarray(row).reshape(1), self.tool_lengths)[0])

    def _material_box(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(lo, hi) (3,) frame-local mm of the material now in the grid (ray feet of the
        rays holding any, from the lowest near to the highest far); None when empty."""
        f = self.grid.frame
        counts = self.grid.counts
        rows = np.nonzero(counts.any(axis=1))[0]
        if rows.size == 0:
            return None
        cols = np.nonzero(counts.any(axis=0))[0]
        held = self.grid.store["count"] > 0
        lo = np.array([cols[0] * f.spacing, rows[0] * f.spacing, float(self.grid.store["near"][held].min())])
        hi = np.array([cols[-1] * f.spacing, rows[-1] * f.spacing, self.grid.max_top()])
        return lo, hi

    def _axis_line(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(point, unit direction) frame-local of the innermost table axis (the part sits
        on it: fixed on the part), or None (no table axis)."""
        if not self.kinematics.table:
            return None
        ax = self.kinematics.table[-1]
        f = self.grid.frame
        point = f.to_local(np.asarray(ax.point, np.float64) - self.origin[:3])
        d = _UNIT_OF[ax.letter]
        return point, np.array([d @ f.u, d @ f.v, d @ f.direction])

    def _material_radius(self, point: np.ndarray, direction: np.ndarray) -> float:
        """Largest distance (mm) of the material from the line (frame-local): at a ray's
        first near or last far (distance from a line is convex along a ray)."""
        f = self.grid.frame
        held = np.nonzero(self.grid.store["count"] > 0)[0]
        if held.size == 0:
            return 0.0
        j, i = np.divmod(held, f.nu)
        feet = np.stack([i * f.spacing, j * f.spacing, np.zeros(held.size)], axis=1)
        top = self.grid.top().reshape(-1)[held].astype(np.float64)
        near = self.grid.store["near"][held].astype(np.float64)
        out = 0.0
        for s in (near, top):
            q = feet.copy()
            q[:, 2] = s
            w = q - point
            out = max(out, float(np.linalg.norm(w - (w @ direction)[:, None] * direction, axis=1).max()))
        return out

    def reaching_profile(self, prof: np.ndarray, tips: np.ndarray, axes: np.ndarray) -> np.ndarray:
        """``prof`` cut at the height along the tool above which no instance (frame-local
        ``tips``/``axes`` (k, 3)) can reach the material's box: the same cut, a smaller
        body (a tilted or turned tool's long flutes and shank sweep a wide footprint of
        rays that hold nothing at their height). At least the profile's first segment."""
        box = self._material_box()
        bot, top = float(prof[0, 0]), float(prof[-1, 0])
        if box is None:
            h = bot
        else:
            grow = float(prof[:, 1].max()) + 2 * self.grid.frame.spacing + self.eps
            lo, hi = box[0] - grow, box[1] + grow
            # per instance, the heights h at which tip + h * axis is inside the grown box
            enter = np.full(len(tips), bot)
            leave = np.full(len(tips), top)
            for c in range(3):
                a, p = axes[:, c], tips[:, c]
                flat = np.abs(a) < 1e-12
                with np.errstate(divide="ignore", invalid="ignore"):
                    h0, h1 = (lo[c] - p) / a, (hi[c] - p) / a
                outside = flat & ((p < lo[c]) | (p > hi[c]))
                enter = np.where(flat, enter, np.maximum(enter, np.minimum(h0, h1)))
                leave = np.where(flat, leave, np.minimum(leave, np.maximum(h0, h1)))
                leave = np.where(outside, -np.inf, leave)
            # a turning part: its material stays within a radius of the part's own
            # (innermost) table axis, a line fixed on the part: the heights inside it
            line = self._axis_line()
            if line is not None:
                enter, leave = _within_radius(tips, axes, *line, self._material_radius(*line) + grow,
                                              enter, leave)
            reach = leave[leave >= enter]
            h = float(reach.max()) if reach.size else bot
        # never below a sliver of the first segment: the kernels want a body
        h = max(h, bot + min(self.grid.frame.spacing, float(prof[1, 0]) - bot))
        if h >= top:
            return prof
        # the body below h exactly: the vertices under it and the profile's point at h
        k = int(np.searchsorted(prof[:, 0], h, side="right"))  # prof[k-1, 0] <= h < prof[k, 0]
        (h0, r0), (h1, r1) = prof[k - 1], prof[k]
        r = r0 + (h - h0) / (h1 - h0) * (r1 - r0)
        return np.ascontiguousarray(np.vstack([prof[:k], [[h, r]]]))

    def _fewest_instances(self, dense: np.ndarray, L: float, height: float, radius: float) -> int:
        """The fewest equal steps of the move through machine poses ``dense`` ((k+1, 6),
        equal steps within the bound of :meth:`Kinematics.instance_counts`) that keep
        every point of the tool (the ``radius`` x ``height`` cylinder) within ``step`` of
        where it was.

        The bound adds the gauge point's travel and each rotation's separately; on a
        5-axis move whose linear axes follow the rotation (the tip nearly still) the tool
        moves far less. A rigid motion moves a point by an affine function of it, so the
        largest move over the cylinder is on its two rim circles (sampled 16 times, the
        rest of the circle within (2 / cos(pi/16) - 1) of the samples' largest: the
        circumscribed 16-gon holds the circle, and the image of its vertices is bounded
        so); the move between two instances is at most the sum of the dense steps
        between them."""
        step = self.step
        ang = np.arange(_RIM) * (2 * np.pi / _RIM)
        rim = np.stack([radius * np.cos(ang), radius * np.sin(ang), np.zeros(_RIM)], axis=1)
        local = np.concatenate([rim, rim + [0.0, 0.0, height]])
        pts = self.kinematics.tool_points(dense, L, local)
        moved = np.linalg.norm(np.diff(pts, axis=0), axis=2).max(axis=1) * (2.0 / math.cos(math.pi / _RIM) - 1.0)
        cum = np.concatenate([[0.0], np.cumsum(moved)])
        k = len(moved)
        count = max(1, int(math.ceil(cum[-1] / step)))
        while count < k:
            # each sparse step's dense steps, rounded outward
            edges = np.arange(count + 1) * (k / count)
            lo, hi = np.floor(edges[:-1]).astype(np.int64), np.ceil(edges[1:]).astype(np.int64)
            worst = float((cum[np.minimum(hi, k)] - cum[lo]).max())
            if worst <= step:
                return count
            count = min(k, int(math.ceil(count * worst / step)) + 1)
        return k

