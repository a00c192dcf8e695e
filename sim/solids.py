"""Solids as dexel grids, by ray casting: box, cylinder, closed triangle mesh, heightfield.

Every constructor works for any :class:`~sim.frame.Frame` (rays need not be axis-aligned)
and returns a :class:`~sim.grid.DexelGrid` whose faces all carry ``face_id``.

Meshes are cast exactly by a scanline over triangles in the frame's (u, v) plane (numba):
each triangle's projected bounding box gives its candidate rays, a point-in-triangle
test with a symbolic tie rule decides hits, the plane of the triangle gives ``s``. The
tie rule acts as if every ray were shifted by the same infinitesimal amount, so a ray
through a shared edge or vertex is counted exactly once per sheet of surface and the
crossings of a closed mesh always pair up (parity). The same scanline
(:func:`cast_triangles`) casts the design in :mod:`sim.checks.error_map`, with an
inclusive mode for open sheets that keeps the rays on their outer edges.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numba as nb
import numpy as np

from sim import dexel_store as ds
from sim.errors import InputError
from sim.frame import Frame
from sim.grid import DexelGrid
from sim.tolerance import DEFAULT, Tolerance


# --- building a grid from flat per-ray segments -------------------------------------

def grid_from_segments(frame: Frame, counts: np.ndarray, near: np.ndarray, far: np.ndarray,
                       near_id: np.ndarray, far_id: np.ndarray,
                       tol: Tolerance = DEFAULT) -> DexelGrid:
    """A grid from segments listed ray after ray (the layout of ``DexelGrid.segments_of``).

    ``counts`` is (n_rays,) int, segments per flat ray ``r = j*nu + i``; ``near``/``far``
    (total,) mm and ``near_id``/``far_id`` (total,) int32 hold the segments of ray 0, then
    ray 1, ... Each ray's segments must already be sorted, disjoint and longer than
    ``tol.length``. The pool is sized exactly (no slack), so the result is compact.
    """
    counts = np.ascontiguousarray(counts, np.int64).reshape(-1)
    if counts.size != frame.n_rays:
        raise InputError(f"expected {frame.n_rays} ray counts, got {counts.size}")
    if counts.size and counts.max() > np.iinfo(np.int16).max:
        raise InputError(f"a ray holds {int(counts.max())} segments, more than the store allows")
    grid = DexelGrid(frame, tol)
    extra = np.maximum(counts - 1, 0)
    pool_size = int(extra.sum())
    st = ds.new_store(frame.n_rays, max(pool_size, 1024))
    _fill_store(ds.store_tuple(st), counts, extra,
                np.ascontiguousarray(near, np.float32), np.ascontiguousarray(far, np.float32),
                np.ascontiguousarray(near_id, np.int32), np.ascontiguousarray(far_id, np.int32))
    st["pool_top"][0] = pool_size
    grid.store = st
    return grid


@nb.njit(cache=True)
def _fill_store(S, counts, extra, near, far, nid, fid):
    m = 0
    top = 0
    for r in range(counts.size):
        c = counts[r]
        S[0][r] = c
        if c == 0:
            continue
        S[1][r] = near[m]
        S[2][r] = far[m]
        S[3][r] = nid[m]
        S[4][r] = fid[m]
        if c > 1:
            S[5][r] = top
            S[6][r] = extra[r]
            for k in range(1, c):
                S[7][top] = near[m + k]
                S[8][top] = far[m + k]
                S[9][top] = nid[m + k]
                S[10][top] = fid[m + k]
                top += 1
        m += c


# --- analytic solids -----------------------------------------------------------------

def box_grid(frame: Frame, lo, hi, face_id: int = 0, tol: Tolerance = DEFAULT) -> DexelGrid:
    """The axis-aligned box ``[lo, hi]`` (world mm, 3-vectors) on the rays of ``frame``.

    Rays exactly on a face of the box count as inside (closed box). For a top frame the
    volume is (rays inside) x spacing^2 x height.
    """
    lo = np.asarray(lo, np.float64).reshape(3)
    hi = np.asarray(hi, np.float64).reshape(3)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
        raise InputError(f"box needs lo < hi on every axis, got lo {lo.tolist()} hi {hi.tolist()}")
    p = frame.ray_points().reshape(-1, 3)
    d = frame.direction
    near = np.full(p.shape[0], -np.inf)
    far = np.full(p.shape[0], np.inf)
    for k in range(3):
        if abs(d[k]) < 1e-15:  # ray parallel to this pair of faces: inside or out
            out = (p[:, k] < lo[k]) | (p[:, k] > hi[k])
            near[out] = np.nan
            far[out] = np.nan
            continue
        t0 = (lo[k] - p[:, k]) / d[k]
        t1 = (hi[k] - p[:, k]) / d[k]
        near = np.maximum(near, np.minimum(t0, t1))
        far = np.minimum(far, np.maximum(t0, t1))
    # ray points lie on the origin plane, so the ray parameter t is the dexel s
    return DexelGrid.from_intervals(frame, near.reshape(frame.shape), far.reshape(frame.shape),
                                    face_id, tol)


def cylinder_grid(frame: Frame, base_center, axis, radius: float, height: float,
                  face_id: int = 0, tol: Tolerance = DEFAULT) -> DexelGrid:
    """A solid right circular cylinder on the rays of ``frame``.

    ``base_center`` (3,) mm is the centre of the base disc, ``axis`` (3,) its direction
    (normalised here), ``radius`` and ``height`` in mm. Rays on the mantle count as inside.
    """
    c = np.asarray(base_center, np.float64).reshape(3)
    a = np.asarray(axis, np.float64).reshape(3)
    na = float(np.linalg.norm(a))
    if not np.isfinite(na) or na == 0.0:
        raise InputError(f"cylinder axis must be a non-zero 3-vector, got {a.tolist()}")
    a = a / na
    if not (np.isfinite(radius) and radius > 0 and np.isfinite(height) and height > 0):
        raise InputError(f"cylinder needs radius > 0 and height > 0 mm, got {radius}, {height}")
    p = frame.ray_points().reshape(-1, 3)
    d = frame.direction
    w = p - c
    wa = w @ a
    da = float(d @ a)
    w_perp = w - wa[:, None] * a
    d_perp = d - da * a
    A = float(d_perp @ d_perp)
    B = 2.0 * (w_perp @ d_perp)
    C = np.einsum("ij,ij->i", w_perp, w_perp) - radius * radius
    if A < 1e-24:  # rays parallel to the axis: inside the disc or not
        near = np.where(C <= 0, -np.inf, np.nan)
        far = np.where(C <= 0, np.inf, np.nan)
    else:
        disc = B * B - 4.0 * A * C
        root = np.sqrt(np.where(disc >= 0, disc, np.nan))
        near = (-B - root) / (2.0 * A)
        far = (-B + root) / (2.0 * A)
    if abs(da) < 1e-15:  # rays across the axis: between the caps or not
        out = (wa < 0) | (wa > height)
        near = np.where(out, np.nan, near)
        far = np.where(out, np.nan, far)
    else:
        t0 = -wa / da
        t1 = (height - wa) / da
        near = np.maximum(near, np.minimum(t0, t1))
        far = np.minimum(far, np.maximum(t0, t1))
    return DexelGrid.from_intervals(frame, near.reshape(frame.shape), far.reshape(frame.shape),
                                    face_id, tol)


# --- meshes ----------------------------------------------------------------------------

@dataclass(frozen=True)
class MeshFaces:
    """Which triangle made each face of a ray-cast mesh grid, and its outward normal.

    All arrays are aligned with ``grid.segments_of(np.arange(grid.frame.n_rays))`` (the
    segments of ray 0, then ray 1, ...), shape (n_segments,) or (n_segments, 3). Valid
    for the grid as built; a later edit of the grid breaks the alignment.

    Attributes
    ----------
    near_tri, far_tri : int32 (n,)
        Triangle index in ``mesh.faces`` of the near / far face of each segment.
    near_normal, far_normal : float32 (n, 3)
        Unit outward normal of that triangle, world frame. Orientation is taken from the
        ray (a near face points against the ray direction, a far face along it), so it is
        outward even where the mesh winding is not.
    """

    near_tri: np.ndarray
    far_tri: np.ndarray
    near_normal: np.ndarray
    far_normal: np.ndarray


def load_mesh(mesh_or_path):
    """A ``trimesh.Trimesh`` from a mesh or an STL/OBJ path; returns (mesh, name for errors)."""
    import trimesh

    if isinstance(mesh_or_path, trimesh.Trimesh):
        return mesh_or_path, "mesh"
    path = Path(mesh_or_path)
    if not path.is_file():
        raise InputError("mesh file not found", where=str(path))
    try:
        mesh = trimesh.load(str(path), force="mesh")
    except Exception as exc:  # trimesh raises many types for bad files
        raise InputError(f"cannot read a triangle mesh ({type(exc).__name__}: {exc})",
                         where=str(path)) from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InputError("file holds no triangles", where=str(path))
    return mesh, str(path)


def check_closed(mesh, name: str = "mesh") -> None:
    """Raise :class:`InputError` unless every edge of ``mesh`` joins exactly two triangles."""
    import trimesh

    if mesh.is_watertight:
        return
    # a triangle soup (vertices not shared) can still be closed: judge it merged
    mesh = mesh.copy()
    mesh.merge_vertices()
    if mesh.is_watertight:
        return
    edges = mesh.edges_sorted
    open_edges = trimesh.grouping.group_rows(edges, require_count=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    over = int((counts > 2).sum())
    problems = []
    if len(open_edges):
        problems.append(f"{len(open_edges)} open edges (edges of only one triangle)")
    if over:
        problems.append(f"{over} edges shared by more than two triangles")
    if not problems:
        problems.append("edges do not pair up")
    raise InputError("mesh is not watertight: " + " and ".join(problems)
                     + "; a stock or fixture must be a closed solid: repair the mesh so that every "
                       "edge joins exactly two triangles", where=name)


def _project(frame: Frame, mesh) -> np.ndarray:
    """Triangle corners in the frame's local coordinates: (T, 3, 3) float64 (u, v, s) mm."""
    verts = np.asarray(mesh.vertices, np.float64)
    faces = np.asarray(mesh.faces, np.int64)
    if not np.all(np.isfinite(verts)):
        raise InputError("mesh has non-finite vertex coordinates")
    return np.ascontiguousarray(frame.to_local(verts)[faces])


@nb.njit(cache=True, inline="always")
def orient2d(ax, ay, bx, by, px, py):
    """Twice the signed area of (a, b, p): > 0 when p lies left of a->b (float64)."""
    return (bx - ax) * (py - ay) - (by - ay) * (px - ax)


@nb.njit(cache=True, inline="always")
def _orient2d_shared(ax, ay, bx, by, px, py):
    # evaluated from the lexicographically smaller end, so the two triangles sharing an
    # edge get bit-identical values of opposite sign: a ray on the edge is then claimed
    # exactly once (rounding alone would otherwise drop or double it)
    if ax < bx or (ax == bx and ay < by):
        return orient2d(ax, ay, bx, by, px, py)
    return -orient2d(bx, by, ax, ay, px, py)


@nb.njit(cache=True, inline="always")
def _owns_ties(ax, ay, bx, by, nudge_u):
    # Edge a->b of a counter-clockwise triangle (interior on its left). A ray exactly on
    # it belongs to this triangle if moving the ray by (nudge_u*eps, -nudge_u*eps^2)
    # takes it inside: for nudge_u = +1 the edges going down or (level) going left, the
    # "top-left" rule; for -1 the mirror image.
    if nudge_u > 0.0:
        return (by < ay) or (ay == by and bx < ax)
    return (by > ay) or (ay == by and bx > ax)


@nb.njit(cache=True)
def _scan(tri, nu, nv, spacing, inclusive, nudge_u, count_only, counts, offsets, hit_s, hit_tri):
    """Count (``count_only``) or record every ray/triangle crossing.

    ``tri`` (T, 3, 3) float64 local (u, v, s) mm; ray (i, j) is at (i*spacing, j*spacing).
    ``counts`` (n_rays,) int64 is incremented; when recording, ``offsets`` (n_rays,) is
    each ray's first slot and ``counts`` must start at zero. See :func:`cast_triangles`.
    """
    for t in range(tri.shape[0]):
        ax = tri[t, 0, 0]
        ay = tri[t, 0, 1]
        bx = tri[t, 1, 0]
        by = tri[t, 1, 1]
        cx = tri[t, 2, 0]
        cy = tri[t, 2, 1]
        az = tri[t, 0, 2]
        bz = tri[t, 1, 2]
        cz = tri[t, 2, 2]
        area = orient2d(ax, ay, bx, by, cx, cy)
        if area == 0.0:
            continue  # edge-on to the rays: the neighbouring faces carry the crossing
        if area < 0.0:  # make it counter-clockwise
            bx, cx = cx, bx
            by, cy = cy, by
            bz, cz = cz, bz
            area = -area
        i0 = max(int(np.ceil(min(ax, bx, cx) / spacing - 1e-9)), 0)
        i1 = min(int(np.floor(max(ax, bx, cx) / spacing + 1e-9)), nu - 1)
        j0 = max(int(np.ceil(min(ay, by, cy) / spacing - 1e-9)), 0)
        j1 = min(int(np.floor(max(ay, by, cy) / spacing + 1e-9)), nv - 1)
        if i0 > i1 or j0 > j1:
            continue
        own0 = _owns_ties(bx, by, cx, cy, nudge_u)
        own1 = _owns_ties(cx, cy, ax, ay, nudge_u)
        own2 = _owns_ties(ax, ay, bx, by, nudge_u)
        eps = 1e-9 * area if inclusive else 0.0
        for j in range(j0, j1 + 1):
            py = j * spacing
            # candidate rays on this row: the triangle's span at v = py, widened by one
            # ray each side so rounding never hides a hit (the exact test decides)
            ua = np.inf
            ub = -np.inf
            for k in range(3):
                pu = tri[t, k, 0]
                pv = tri[t, k, 1]
                qu = tri[t, (k + 1) % 3, 0]
                qv = tri[t, (k + 1) % 3, 1]
                if min(pv, qv) <= py <= max(pv, qv):
                    if pv == qv:
                        ua = min(ua, pu, qu)
                        ub = max(ub, pu, qu)
                    else:
                        u = pu + (py - pv) * (qu - pu) / (qv - pv)
                        ua = min(ua, u)
                        ub = max(ub, u)
            if ua > ub:
                ia, ib = i0, i1  # a row within the slack of a corner: test the whole box
            else:
                ia = max(i0, int(np.ceil(ua / spacing)) - 1)
                ib = min(i1, int(np.floor(ub / spacing)) + 1)
            for i in range(ia, ib + 1):
                px = i * spacing
                w0 = _orient2d_shared(bx, by, cx, cy, px, py)
                w1 = _orient2d_shared(cx, cy, ax, ay, px, py)
                w2 = _orient2d_shared(ax, ay, bx, by, px, py)
                if inclusive:
                    if w0 < -eps or w1 < -eps or w2 < -eps:
                        continue
                else:
                    if w0 < 0.0 or w1 < 0.0 or w2 < 0.0:
                        continue
                    if (w0 == 0.0 and not own0) or (w1 == 0.0 and not own1) or (w2 == 0.0 and not own2):
                        continue
                r = j * nu + i
                if not count_only:
                    k = offsets[r] + counts[r]
                    hit_s[k] = (w0 * az + w1 * bz + w2 * cz) / area
                    hit_tri[k] = t
                counts[r] += 1


@nb.njit(cache=True)
def sort_hits(offsets, counts, hit_s, hit_tri):
    """Sort each ray's hits by ``s`` in place, equal ``s`` kept in their order.

    Ray ``r``'s hits are ``hit_s[offsets[r]:offsets[r]+counts[r]]`` (float64, mm) with
    their triangles ``hit_tri[...]`` (int32); offsets/counts (n_rays,) int64. Insertion
    sort: rays hold few hits. Shared with :mod:`sim.checks.error_map`'s design cast.
    """
    for r in range(counts.size):
        o = offsets[r]
        for a in range(o + 1, o + counts[r]):
            s = hit_s[a]
            t = hit_tri[a]
            b = a - 1
            while b >= o and hit_s[b] > s:
                hit_s[b + 1] = hit_s[b]
                hit_tri[b + 1] = hit_tri[b]
                b -= 1
            hit_s[b + 1] = s
            hit_tri[b + 1] = t


@nb.njit(cache=True)
def _pair_hits(offsets, counts, hit_s, hit_tri, eps, seg_counts, near, far, ntri, ftri):
    """Pair sorted hits into segments (parity); drop pieces <= eps, merge gaps <= eps.

    Writes per ray into the slots ``offsets[r]...`` of the outputs (at most counts/2
    segments each); returns the number of rays with an odd hit count (last hit dropped).
    """
    odd = 0
    for r in range(counts.size):
        o = offsets[r]
        c = counts[r]
        if c % 2 == 1:
            odd += 1
            c -= 1
        m = 0
        for k in range(0, c, 2):
            a = hit_s[o + k]
            b = hit_s[o + k + 1]
            if b - a <= eps:
                continue
            if m > 0 and a - far[o + m - 1] <= eps:
                far[o + m - 1] = b
                ftri[o + m - 1] = hit_tri[o + k + 1]
                continue
            near[o + m] = a
            far[o + m] = b
            ntri[o + m] = hit_tri[o + k]
            ftri[o + m] = hit_tri[o + k + 1]
            m += 1
        seg_counts[r] = m
    return odd


@nb.njit(cache=True)
def _compact(offsets, seg_counts, near, far, ntri, ftri, out_n, out_f, out_nt, out_ft):
    m = 0
    for r in range(seg_counts.size):
        o = offsets[r]
        for k in range(seg_counts[r]):
            out_n[m] = near[o + k]
            out_f[m] = far[o + k]
            out_nt[m] = ntri[o + k]
            out_ft[m] = ftri[o + k]
            m += 1


def pack_segments(offsets: np.ndarray, counts: np.ndarray, near: np.ndarray, far: np.ndarray,
                  near_id: np.ndarray, far_id: np.ndarray):
    """Segments held in per-ray slots, listed ray after ray as :func:`grid_from_segments`
    takes them.

    Ray ``r``'s segments sit at ``offsets[r] ... offsets[r] + counts[r] - 1`` of
    ``near``/``far`` (mm, any float dtype) and ``near_id``/``far_id`` (int); offsets and
    counts are (n_rays,) int64. Returns ``(near, far, near_id, far_id)``: (n,) float32,
    float32, int32, int32 with ``n = counts.sum()``.
    """
    n = int(counts.sum())
    out = (np.empty(n, np.float32), np.empty(n, np.float32), np.empty(n, np.int32), np.empty(n, np.int32))
    _compact(offsets, counts, near, far, near_id, far_id, *out)
    return out


def cast_triangles(tri: np.ndarray, nu: int, nv: int, spacing: float, inclusive: bool = False,
                   nudge_u: float = -1.0):
    """Every crossing of the rays ``(i, j)`` with triangles given in local coordinates.

    ``tri`` (T, 3, 3) float64: corners as (u, v, s) mm in a frame's local coordinates; ray
    ``(i, j)``, ``0 <= i < nu``, ``0 <= j < nv``, is the line ``u = i*spacing``,
    ``v = j*spacing``. Triangles seen edge-on are skipped.

    ``inclusive`` False: a ray exactly on an edge or corner is claimed by exactly one
    triangle, as if it were moved by ``(nudge_u*eps, -nudge_u*eps^2)`` (``nudge_u`` +1 or
    -1, the same for every triangle), so the crossings of a closed mesh pair up. True: a
    ray on an edge, or within ``1e-9`` x the triangle's doubled area of it, counts for
    every triangle it touches. For open sheets: rays on the sheet's outer edges are kept
    and those on its inner edges are counted twice (collapse them after).

    Returns ``(offsets, counts, s, tri_index)``: ray ``r = j*nu + i`` has crossings
    ``s[offsets[r]:offsets[r]+counts[r]]`` (float64 mm, ascending) made by triangles
    ``tri_index[...]`` (int32); offsets/counts are (nu*nv,) int64.
    """
    tri = np.ascontiguousarray(tri, np.float64)
    nudge_u = 1.0 if nudge_u > 0 else -1.0
    n_rays = nu * nv
    counts = np.zeros(n_rays, np.int64)
    _scan(tri, nu, nv, spacing, inclusive, nudge_u, True, counts, counts,
          np.empty(0, np.float64), np.empty(0, np.int32))
    offsets = np.zeros(n_rays, np.int64)
    np.cumsum(counts[:-1], out=offsets[1:])
    total = int(counts.sum())
    hit_s = np.empty(total, np.float64)
    hit_tri = np.empty(total, np.int32)
    counts[:] = 0
    _scan(tri, nu, nv, spacing, inclusive, nudge_u, False, counts, offsets, hit_s, hit_tri)
    sort_hits(offsets, counts, hit_s, hit_tri)
    return offsets, counts, hit_s, hit_tri


def ray_hits(frame: Frame, mesh, inclusive: bool = False):
    """Every crossing of the frame's rays with the mesh triangles, sorted along each ray.

    Returns ``(offsets, counts, s, tri)``: ray ``r``'s crossings are
    ``s[offsets[r]:offsets[r]+counts[r]]`` (float64, mm, ascending) made by triangles
    ``tri[...]`` (int32 indices into ``mesh.faces``). offsets/counts are (n_rays,) int64.
    ``inclusive``: see :func:`cast_triangles` (ties otherwise go as if the ray moved by
    ``(-eps, eps^2)``).
    """
    return cast_triangles(_project(frame, mesh), frame.nu, frame.nv, frame.spacing, inclusive, -1.0)


def _outward(mesh, frame: Frame, tri: np.ndarray, sign: float) -> np.ndarray:
    """Normals of triangles ``tri`` flipped so that ``sign * (n . direction) >= 0``."""
    n = np.asarray(mesh.face_normals, np.float64)[tri]
    dots = n @ frame.direction
    n[sign * dots < 0] *= -1.0
    return n.astype(np.float32)


def mesh_grid(frame: Frame, mesh_or_path, face_id: int = 0, tol: Tolerance = DEFAULT,
              return_normals: bool = False):
    """The solid bounded by a closed triangle mesh, on the rays of ``frame``.

    ``mesh_or_path`` is a ``trimesh.Trimesh`` or an STL/OBJ file (mm). A mesh that is not
    watertight raises :class:`InputError` naming the file and the problem. Each ray's
    crossings are paired in order (entry, exit, entry, ...), so meshes with holes and
    undercuts give several segments per ray.

    Returns the grid, or ``(grid, MeshFaces)`` with ``return_normals=True`` (the design
    normal of every dexel face, for error assessment).
    """
    mesh, name = load_mesh(mesh_or_path)
    check_closed(mesh, name)
    offsets, counts, hit_s, hit_tri = ray_hits(frame, mesh)
    total = hit_s.size
    seg_counts = np.zeros(frame.n_rays, np.int64)
    near = np.empty(total, np.float64)
    far = np.empty(total, np.float64)
    ntri = np.empty(total, np.int32)
    ftri = np.empty(total, np.int32)
    odd = _pair_hits(offsets, counts, hit_s, hit_tri, tol.length, seg_counts, near, far, ntri, ftri)
    if odd:
        warnings.warn(f"{name}: {odd} rays crossed the surface an odd number of times "
                      "(self-intersecting or nearly degenerate triangles); their last crossing "
                      "was ignored", RuntimeWarning, stacklevel=2)
    out_n, out_f, out_nt, out_ft = pack_segments(offsets, seg_counts, near, far, ntri, ftri)
    ids = np.full(out_n.size, face_id, np.int32)
    grid = grid_from_segments(frame, seg_counts, out_n, out_f, ids, ids, tol)
    if not return_normals:
        return grid
    faces = MeshFaces(out_nt, out_ft, _outward(mesh, frame, out_nt, -1.0),
                      _outward(mesh, frame, out_ft, 1.0))
    return grid, faces


def heightfield_grid(frame: Frame, mesh_or_path, floor: float, face_id: int = 0,
                     tol: Tolerance = DEFAULT, return_normals: bool = False):
    """Material from ``s = floor`` up to the last crossing of each ray with a surface.

    For open design surfaces (a carpet, a relief) that are a function over the frame's
    (u, v) plane: each ray keeps one segment ``[floor, highest crossing]``; rays that miss
    the surface, or cross it at or below ``floor``, stay empty. The mesh need not be
    closed. With ``return_normals=True`` also returns :class:`MeshFaces` (the near face
    is the floor: its triangle index is -1 and its normal is minus the ray direction).
    """
    mesh, _ = load_mesh(mesh_or_path)
    offsets, counts, hit_s, hit_tri = ray_hits(frame, mesh)
    has = counts > 0
    last = offsets + counts - 1
    top = np.full(frame.n_rays, np.nan)
    tri = np.full(frame.n_rays, -1, np.int32)
    top[has] = hit_s[last[has]]
    tri[has] = hit_tri[last[has]]
    ok = has & (top - floor > tol.length)
    n_seg = int(ok.sum())
    grid = grid_from_segments(frame, ok.astype(np.int64), np.full(n_seg, floor, np.float32),
                              top[ok].astype(np.float32), np.full(n_seg, face_id, np.int32),
                              np.full(n_seg, face_id, np.int32), tol)
    if not return_normals:
        return grid
    ft = tri[ok]
    faces = MeshFaces(np.full(n_seg, -1, np.int32), ft,
                      np.tile((-frame.direction).astype(np.float32), (n_seg, 1)),
                      _outward(mesh, frame, ft, 1.0))
    return grid, faces
