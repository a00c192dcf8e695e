"""A straightforward z-map cut: the baseline dexmon's batch cut is measured against.

What it computes: the top surface ``H[j, i]`` (float64 mm) of stock whose rays are the
vertical lines at ``x = x0 + i * spacing``, ``y = y0 + j * spacing`` (a top-view z-map,
one height per ray, no undercuts), starting at ``top`` and after the tool swept every
straight tip segment ``p0[k] -> p1[k]`` (tool axis +Z), floored at ``bottom``:

* ball (radius R): the ball centre runs along ``p0 + (0, 0, R) -> p1 + (0, 0, R)``; the
  swept solid is the capsule of radius R about that segment (plus the shank above it, which
  never reaches lower). A ray's new height is the lowest point of the vertical line inside
  the capsule: the lower root of the line against each end sphere and against the infinite
  cylinder about the segment where the foot of that root lies on the segment - exact.
* flat (radius R): the tip disk of radius R swept along the segment. A ray is reached
  over the parameter range ``[t0, t1]`` where its (x, y) is within R of the disk centre
  (a quadratic in t); the tip height is linear in t, so the lowest point is at ``t0`` or
  ``t1`` - exact for the swept disk; rays lying on the swept boundary (vertical walls)
  may fall either side.

Per segment it loops over the rays of the segment's bounding box grown by R and keeps the
minimum - no culling beyond the box, no tiles, one core (numba, no parallel loops). Arcs
are not swept exactly: :func:`tip_segments` splits them into chords at most 0.05 mm long
(the benchmark's programs are straight moves; only the pocket case has arcs).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from sim.gcode.moves import MoveKind, tip_positions
from sim.sweep import arc_points

_LINEAR = (int(MoveKind.RAPID), int(MoveKind.FEED))
_ARCS = (int(MoveKind.ARC_CW), int(MoveKind.ARC_CCW))


def tip_segments(moves: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Straight tip segments (p0, p1), float64 (n, 3) mm, of every motion row of ``moves``.

    RAPID and FEED rows are one segment each; arcs are split into chords <= 0.05 mm.
    """
    kind = moves["kind"]
    start = tip_positions(moves, "start")
    end = tip_positions(moves, "end")
    linear = np.isin(kind, _LINEAR)
    if not np.isin(kind, _ARCS).any():
        return np.ascontiguousarray(start[linear]), np.ascontiguousarray(end[linear])
    p0, p1 = [], []
    for k in range(len(moves)):
        if linear[k]:
            p0.append(start[k:k + 1])
            p1.append(end[k:k + 1])
        elif int(kind[k]) in _ARCS:
            centre = np.array(moves["center"][k], float)
            centre[2] -= moves["tool_length"][k]
            pts = arc_points(start[k], end[k], centre, int(moves["plane"][k]),
                             int(moves["turns"][k]) or 1, int(kind[k]) == int(MoveKind.ARC_CW),
                             max_step_length=0.05)
            p0.append(pts[:-1])
            p1.append(pts[1:])
    return np.ascontiguousarray(np.concatenate(p0)), np.ascontiguousarray(np.concatenate(p1))


@nb.njit(cache=True, fastmath=False)
def _ball_low(x, y, ax, ay, az, dx, dy, dz, R):
    """Lowest z of the vertical line (x, y) inside the capsule of radius R about the
    centre segment (ax, ay, az) + t (dx, dy, dz), t in [0, 1]; +inf if it misses."""
    low = math.inf
    R2 = R * R
    for s in range(2):  # end spheres
        cx, cy, cz = ax + s * dx, ay + s * dy, az + s * dz
        q = R2 - (x - cx) ** 2 - (y - cy) ** 2
        if q >= 0.0:
            z = cz - math.sqrt(q)
            if z < low:
                low = z
    n2 = dx * dx + dy * dy + dz * dz
    if n2 < 1e-24:
        return low
    n = math.sqrt(n2)
    ux, uy, uz = dx / n, dy / n, dz / n
    # point on the line at z = 0 relative to the segment start; e_z; both less their part along u
    wx, wy, wz = x - ax, y - ay, -az
    wu = wx * ux + wy * uy + wz * uz
    px, py, pz = wx - wu * ux, wy - wu * uy, wz - wu * uz
    ex, ey, ez = -uz * ux, -uz * uy, 1.0 - uz * uz
    A = ex * ex + ey * ey + ez * ez
    if A < 1e-12:  # vertical segment: the spheres bound it
        return low
    B = px * ex + py * ey + pz * ez
    C = px * px + py * py + pz * pz - R2
    disc = B * B - A * C
    if disc < 0.0:
        return low
    z = (-B - math.sqrt(disc)) / A
    t = wu + z * uz  # foot of the root along the segment (mm)
    if 0.0 <= t <= n and z < low:
        low = z
    return low


@nb.njit(cache=True, fastmath=False)
def _flat_low(x, y, ax, ay, az, dx, dy, dz, R):
    """Lowest tip z at which the disk of radius R, centre (ax, ay, az) + t (dx, dy, dz),
    t in [0, 1], covers (x, y); +inf if it never does."""
    fx, fy = x - ax, y - ay
    A = dx * dx + dy * dy
    if A < 1e-18:  # plunge or retract: the disk does not move sideways
        if fx * fx + fy * fy <= R * R:
            return min(az, az + dz)
        return math.inf
    B = -(fx * dx + fy * dy)
    C = fx * fx + fy * fy - R * R
    disc = B * B - A * C
    if disc < 0.0:
        return math.inf
    sq = math.sqrt(disc)
    t0 = (-B - sq) / A
    t1 = (-B + sq) / A
    if t0 > 1.0 or t1 < 0.0:
        return math.inf
    t0 = max(t0, 0.0)
    t1 = min(t1, 1.0)
    return min(az + t0 * dz, az + t1 * dz)


@nb.njit(cache=True, fastmath=False)
def zmap_cut(H, x0, y0, spacing, p0, p1, R, ball, bottom):
    """Lower ``H`` (float64 (nv, nu), mm, in place) by the tool swept along each tip
    segment ``p0[k] -> p1[k]`` (float64 (n, 3) mm): ball when ``ball`` else flat, radius
    ``R`` mm; no height goes below ``bottom``."""
    nv, nu = H.shape
    lift = R if ball else 0.0
    for k in range(p0.shape[0]):
        ax, ay, az = p0[k, 0], p0[k, 1], p0[k, 2] + lift
        dx, dy, dz = p1[k, 0] - p0[k, 0], p1[k, 1] - p0[k, 1], p1[k, 2] - p0[k, 2]
        i0 = max(0, int(math.floor((min(ax, ax + dx) - R - x0) / spacing)))
        i1 = min(nu, int(math.ceil((max(ax, ax + dx) + R - x0) / spacing)) + 1)
        j0 = max(0, int(math.floor((min(ay, ay + dy) - R - y0) / spacing)))
        j1 = min(nv, int(math.ceil((max(ay, ay + dy) + R - y0) / spacing)) + 1)
        for j in range(j0, j1):
            y = y0 + j * spacing
            for i in range(i0, i1):
                x = x0 + i * spacing
                if ball:
                    z = _ball_low(x, y, ax, ay, az, dx, dy, dz, R)
                else:
                    z = _flat_low(x, y, ax, ay, az, dx, dy, dz, R)
                if z < H[j, i]:
                    H[j, i] = max(z, bottom)


def cut_into(H: np.ndarray, frame, tool, moves: np.ndarray, bottom: float) -> None:
    """Lower the heights ``H`` (float64 ``frame.shape``, mm, in place) of the top-view
    ``frame`` by ``tool`` (kind ``ball`` or ``flat``) following ``moves``, floored at
    ``bottom``. This is what the benchmark times."""
    if tool.kind not in ("ball", "flat"):
        raise ValueError(f"zmap baseline: tool kind {tool.kind!r} unsupported (expected ball or flat)")
    p0, p1 = tip_segments(moves)
    zmap_cut(H, float(frame.origin[0]), float(frame.origin[1]), float(frame.spacing), p0, p1,
             float(tool.radius), tool.kind == "ball", float(bottom))


def cut_program(frame, tool, moves: np.ndarray, top: float, bottom: float) -> np.ndarray:
    """Heights (float64 ``frame.shape``, mm) of stock ``bottom..top`` on the top-view
    ``frame`` after ``tool`` (kind ``ball`` or ``flat``) followed ``moves``."""
    H = np.full(frame.shape, float(top))
    cut_into(H, frame, tool, moves, bottom)
    return H
