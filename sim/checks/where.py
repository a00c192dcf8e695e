"""Where a move met material, from what the cut recorded (a :class:`~sim.cut.CutResult`
with its changed rays and depths): the point a finding's ``position`` names.

A finding's position is where the tool met what it should not, not where its move ended
(a holder rubbing a clamp early in a long move, a rapid clipping the stock's edge). The
cut knows which rays each move changed and how deep; the grid after the batch and those
depths give the material each move met.
"""

from __future__ import annotations

import numpy as np

#: mm: depths of cut this close count as equally deep (the log keeps them as float32)
DEPTH_TIE = 1e-4


def tip_at(moves: np.ndarray, k: int, which: str = "end") -> np.ndarray:
    """Tip (3,) mm of row ``k`` at its ``which`` end: the G43 length taken off Z."""
    tip = np.array(moves[which][k, :3], np.float64)
    tip[2] -= moves["tool_length"][k]
    return tip


def top_met(cut, grid, k: int, lowest: float, at=None) -> tuple[np.ndarray, np.ndarray]:
    """``(rays, top)``: the rays move ``k`` of a batch changed (``at``: only those at these
    positions of its list) and each one's material top (s along the ray, mm) as it was
    when the move began.

    ``cut`` is the batch's CutResult (depths kept), ``grid`` the model after the whole
    batch: later moves of the batch may have cut the same rays deeper, so the top now is
    not what move ``k`` met. Each move's depth on a ray is its top before minus its top
    after, so the top before move ``k`` is the top now plus the depths of ``k`` and of
    every later move on that ray. A ray emptied by then has no top: there the material
    began at most ``k``'s depth above ``lowest`` (s of the move's lowest tip)."""
    ptr = cut.changed_ptr
    lo, hi = ptr[k], ptr[k + 1]
    at = np.arange(hi - lo) if at is None else np.asarray(at, np.int64)
    rays = cut.changed_rays[lo:hi][at]
    if not cut.changed_depth.size:
        return rays, grid.top_of(rays)
    later = cut.changed_rays[lo:]
    depth = np.asarray(cut.changed_depth[lo:], np.float64)
    # rays are sorted within each move (so the subset is): find each later entry among them
    q = np.minimum(np.searchsorted(rays, later), rays.size - 1)
    mine = rays[q] == later
    below = np.bincount(q[mine], weights=depth[mine], minlength=rays.size)
    top = grid.top_of(rays)
    return rays, np.where(np.isfinite(top), top + below, lowest + depth[at])


def _lowest_s(moves, k) -> float:
    """s of row ``k``'s lowest tip on a top-view grid (:attr:`Frame.is_top`: s is Z)."""
    z = moves["tool_length"][k]
    return float(min(moves["start"][k, 2], moves["end"][k, 2]) - z)


def first_contact(moves: np.ndarray, k: int, cut, grid, top=None) -> np.ndarray | None:
    """World point (3,) where move ``k`` first met material, or None when it changed no ray:
    of the rays it changed, the material top it met (``top``, float64 per ray of ``grid``
    before the move; default rebuilt by :func:`top_met`) that comes first along the move;
    among rays as far along (a grid row), the one nearest its line."""
    lo, hi = cut.changed_ptr[k], cut.changed_ptr[k + 1]
    if hi <= lo or not grid.frame.is_top:
        return None
    f = grid.frame
    if top is None:
        rays, met = top_met(cut, grid, k, _lowest_s(moves, k))
    else:
        rays = cut.changed_rays[lo:hi]
        met = top[rays]
    i, j = rays % f.nu, rays // f.nu
    pts = f.to_world(np.stack([i * f.spacing, j * f.spacing, met], axis=1))
    start, end = tip_at(moves, k, "start"), tip_at(moves, k, "end")
    d = end - start
    n = np.linalg.norm(d)
    if n == 0:
        return pts[int(np.argmax(pts[:, 2]))]
    rel = pts - start
    along = rel @ (d / n)
    across = np.linalg.norm(rel - along[:, None] * (d / n), axis=1)
    return pts[int(np.lexsort((across, np.round(along / (0.5 * f.spacing))))[0])]


def deepest_cut(moves: np.ndarray, k: int, cut, grid) -> np.ndarray | None:
    """World point (3,) of the deepest cut move ``k`` made (the floor it left on the ray
    it took the most material off from the top), or None when it changed no ray."""
    lo, hi = cut.changed_ptr[k], cut.changed_ptr[k + 1]
    f = grid.frame
    if hi <= lo or not cut.changed_depth.size or not f.is_top:
        return None
    depth = np.asarray(cut.changed_depth[lo:hi], np.float64)
    # a flat end cuts a whole disc (a slot a whole band) as deep: of the deepest rays,
    # the one in their middle, under the tool rather than on its rim
    deepest = np.flatnonzero(depth >= depth.max() - DEPTH_TIE)
    rays = cut.changed_rays[lo:hi][deepest]
    ij = np.stack([rays % f.nu, rays // f.nu], axis=1).astype(np.float64)
    w = int(deepest[int(np.argmin(((ij - ij.mean(axis=0)) ** 2).sum(axis=1)))])
    (r,), (met,) = top_met(cut, grid, k, _lowest_s(moves, k), at=[w])
    # a top-view frame: u = +X, v = +Y, s = Z
    return f.origin + np.array([r % f.nu * f.spacing, r // f.nu * f.spacing, met - depth[w]])


def contact_point(cutter, moves: np.ndarray, k: int, body=None) -> np.ndarray | None:
    """World point (3,) where ``body`` (default the cutter's tool) swept along row ``k``
    first meets the material of ``cutter``'s grid, which is not changed (a scratch copy
    of the rays it reaches is cut: :meth:`sim.cut.Cutter.probe_where`); None when it
    meets none."""
    got = cutter.probe_where(moves[k:k + 1], body)
    if got is None:
        return None
    res, scratch, top = got
    return first_contact(moves[k:k + 1], 0, res, scratch, top=top)


def line_entry(moves: np.ndarray, k: int, cut, grid, near: float) -> np.ndarray | None:
    """World point (3,) where straight row ``k``'s tip enters the material under it: the
    point of the move at the height of the highest top it met (:func:`top_met`) on the
    rays it changed within ``near`` mm of its XY path (its start when it does not go down
    to it); None when it changed no such ray."""
    lo, hi = cut.changed_ptr[k], cut.changed_ptr[k + 1]
    if hi <= lo or not grid.frame.is_top:
        return None
    f = grid.frame
    rays, met = top_met(cut, grid, k, _lowest_s(moves, k))
    xy = f.to_world(np.stack([rays % f.nu * f.spacing, rays // f.nu * f.spacing, met], axis=1))
    start, end = tip_at(moves, k, "start"), tip_at(moves, k, "end")
    d = (end - start)[:2]
    run2 = float(d @ d)
    t = np.clip(((xy[:, :2] - start[:2]) @ d) / run2, 0.0, 1.0) if run2 > 0 else np.zeros(len(xy))
    dist = np.linalg.norm(xy[:, :2] - (start[:2] + t[:, None] * d), axis=1)
    close = dist <= near
    if not close.any():
        return None
    top = float(xy[close, 2].max())
    drop = start[2] - end[2]
    s = min(max((start[2] - top) / drop, 0.0), 1.0) if drop > 0 else 0.0
    return start + s * (end - start)


def met_at(moves, k, where, cut, grid) -> np.ndarray:
    """``where(moves, k, cut, grid)`` (one of the points above) when the cut is known and
    the move changed a ray, else row ``k``'s end tip."""
    met = where(moves, k, cut, grid) if cut is not None and grid is not None else None
    return tip_at(moves, k) if met is None else met
