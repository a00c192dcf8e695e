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
minimum - no culling beyond the box and a cheap per-ray reject (the ray's distance to the
segment projected on XY, before the exact test), no tiles, one core (numba, no parallel loops). Arcs
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
def _ball_low(x, y, ax, ay, az, dx, dy, dz, R, n, ux, uy, uz, ex, ey, ez, A, inv_A, inv_dxy2):
    """Lowest z of the vertical line (x, y) inside the capsule of radius R about the
    centre segment (ax, ay, az) + t (dx, dy, dz), t in [0, 1]; +inf if it misses.

    n: segment length; (ux, uy, uz): its unit direction (0 if n == 0); (ex, ey, ez): e_z
    less its part along u, A its squared norm, inv_A = 1 / A; inv_dxy2 = 1 / (dx^2 + dy^2),
    0 when the segment is vertical (all constant along a segment)."""
    R2 = R * R
    # cheap reject: (x, y) farther than R from the segment projected on the XY plane
    fx, fy = x - ax, y - ay
    s = min(1.0, max(0.0, (fx * dx + fy * dy) * inv_dxy2))
    gx, gy = fx - s * dx, fy - s * dy
    if gx * gx + gy * gy > R2:
        return math.inf
    if n > 0.0 and A >= 1e-12:
        # the lower root of the line against the infinite cylinder about the segment: when
        # its foot lies on the segment it is the capsule's lowest point (the capsule is
        # inside the cylinder); otherwise the lowest point lies on an end sphere
        wx, wy, wz = fx, fy, -az  # the line's point at z = 0, from the segment start
        wu = wx * ux + wy * uy + wz * uz
        px, py, pz = wx - wu * ux, wy - wu * uy, wz - wu * uz
        B = px * ex + py * ey + pz * ez
        C = px * px + py * py + pz * pz - R2
        disc = B * B - A * C
        if disc >= 0.0:
            z = (-B - math.sqrt(disc)) * inv_A
            t = wu + z * uz  # foot of the root along the segment (mm)
            if 0.0 <= t <= n:
                return z
    low = math.inf
    for e in range(2):  # end spheres
        cx, cy, cz = ax + e * dx, ay + e * dy, az + e * dz
        q = R2 - (x - cx) ** 2 - (y - cy) ** 2
        if q >= 0.0:
            z = cz - math.sqrt(q)
            if z < low:
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
        n = math.sqrt(dx * dx + dy * dy + dz * dz)
        ux = uy = uz = 0.0
        if n > 1e-12:
            ux, uy, uz = dx / n, dy / n, dz / n
        else:
            n = 0.0
        ex, ey, ez = -uz * ux, -uz * uy, 1.0 - uz * uz
        A = ex * ex + ey * ey + ez * ez
        inv_A = 1.0 / A if A >= 1e-12 else 0.0
        dxy2 = dx * dx + dy * dy
        inv_dxy2 = 1.0 / dxy2 if dxy2 > 0.0 else 0.0
        for j in range(j0, j1):
            y = y0 + j * spacing
            for i in range(i0, i1):
                x = x0 + i * spacing
                if ball:
                    z = _ball_low(x, y, ax, ay, az, dx, dy, dz, R, n, ux, uy, uz, ex, ey, ez, A,
                                  inv_A, inv_dxy2)
                else:
                    z = _flat_low(x, y, ax, ay, az, dx, dy, dz, R)
                if z < H[j, i]:
                    H[j, i] = max(z, bottom)


def cut_into(H: np.ndarray, frame, tool, moves: np.ndarray, bottom: float, dr: float = 0.0) -> None:
    """Lower the heights ``H`` (float64 ``frame.shape``, mm, in place) of the top-view
    ``frame`` by ``tool`` (kind ``ball`` or ``flat``) following ``moves``, floored at
    ``bottom``. This is what the benchmark times. ``dr`` (mm) grows the tool radius, to
    bracket rays lying on the swept boundary."""
    if tool.kind not in ("ball", "flat"):
        raise ValueError(f"zmap baseline: tool kind {tool.kind!r} unsupported (expected ball or flat)")
    p0, p1 = tip_segments(moves)
    zmap_cut(H, float(frame.origin[0]), float(frame.origin[1]), float(frame.spacing), p0, p1,
             float(tool.radius) + dr, tool.kind == "ball", float(bottom))


def cut_program(frame, tool, moves: np.ndarray, top: float, bottom: float) -> np.ndarray:
    """Heights (float64 ``frame.shape``, mm) of stock ``bottom..top`` on the top-view
    ``frame`` after ``tool`` (kind ``ball`` or ``flat``) followed ``moves``."""
    H = np.full(frame.shape, float(top))
    cut_into(H, frame, tool, moves, bottom)
    return H
