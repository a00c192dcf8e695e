"""The surface of a tri-dexel model: a closed triangle mesh with no view direction.

Dual contouring over the lattice of :mod:`sim.tridexel` (surface nets with exact edge
crossings):

* **Node occupancy.** Each node lies on three rays (one per grid); each ray reads the
  node as material when the node's ``s`` (rounded to float32, as the segment ends are
  stored) lies in one of its segments, ends included (a node on a face is inside, as
  :func:`sim.solids.box_grid` counts it). Near faces the three readings can disagree
  (float rounding, segments under the tolerance, the Z grid's exact sweep beside the
  X and Y grids' instances of motion); the node is material when **two of the three**
  rays say so. Segments are clipped to the lattice, and the lattice is padded with one
  empty layer all round, so material touching the lattice's boundary closes there.
* **Ambiguous faces.** A lattice square whose diagonal nodes hold material and whose
  other two do not (a checkerboard) would give a mesh edge of four faces; such squares
  are read as joined material (their empty nodes are taken inside), repeated until
  none is left. This only happens where material is thinner than the spacing.
* **Edge crossings** are exact: a lattice edge whose two nodes differ lies on one ray
  of the grid running along it, and its crossing is that ray's segment end in the
  edge (the material of the inside node ending, or of the far node beginning); the
  face id of that end is kept. Where the ray disagrees with the vote it has no such
  end: the crossing is put on the node it misread (the surface passes through it to
  within the rounding that made the readings differ).
* **Vertices**: one per cell (cube of 8 nodes) with a sign change. By default (``"qef"``)
  at the point nearest, in least squares, to the tangent planes of the cell's crossings
  (each crossing's normal from the slopes of the same crossing on the four neighbouring
  rays), moved from the crossings' mean only in directions those normals pin down and
  clamped to the cell: faces, edges and corners of a box come out exact wherever they
  lie, curved faces keep the mean. ``"mean"`` (the mean of the crossings, surface nets)
  is exact for faces on lattice planes but bevels edges by up to a spacing.
* **Faces**: a quad (two triangles) per sign-changing edge joining the vertices of the
  four cells round it, wound so the normal points out of the material, split along the
  diagonal whose two triangles both face out along the edge. A QEF vertex that still
  folds a triangle against its crossing's normal goes back to its cell's mean. Every
  edge of the result joins exactly two faces: the mesh is watertight and consistently
  wound.
  Known limit: a cell holding two separate pieces of surface (material at two opposite
  corners of the cube only) has one vertex, where the two pieces touch (still
  watertight; that vertex is not a manifold vertex).

Every triangle carries ``move_id``: the face id of its edge's crossing (the move that
cut that face; 0 = stock), so pictures can colour by move as with :mod:`sim.surface`.
Vertices are float32 values (what an STL holds), vertices of different cells never at
the same point, so the surface read back from an STL is watertight too.
"""

from __future__ import annotations

from pathlib import Path

import numba as nb
import numpy as np

from sim.errors import InputError
from sim.surface import _live_segments, write_stl
from sim.tridexel import TriDexel

#: lattice axis of each grid's rays (x grid runs along axis 0, ...)
_AXIS = {"x": 0, "y": 1, "z": 2}
#: lattice axes of each grid's (direction, u, v) (the sim.tridexel table)
_DUV = {"x": (0, 1, 2), "y": (1, 2, 0), "z": (2, 0, 1)}
#: the QEF's eigenvalue threshold, per crossing: directions in which the crossings'
#: normals spread less than about 16 degrees (two even groups at +-8) keep the mean (a
#: curved or flat surface), sharper ones (an edge, a corner) are solved for
_QEF_THRESHOLD = 0.02


@nb.njit(cache=True)
def _add_votes(offsets, near, far, s_nodes, nu, axis, votes):
    """Add 1 to ``votes`` (padded (nx+2, ny+2, nz+2) uint8) at every node that one grid's
    ray reads as material: node ``s_nodes[k]`` (float32 mm, ascending) in a segment, ends
    included. ``axis`` (0 x, 1 y, 2 z) is the grid's; its ray ``r = iv*nu + iu`` holds
    the nodes as in the :mod:`sim.tridexel` table."""
    n = s_nodes.size
    for r in range(offsets.size - 1):
        iu = r % nu + 1
        iv = r // nu + 1
        k = 0
        for q in range(offsets[r], offsets[r + 1]):
            while k < n and s_nodes[k] < near[q]:
                k += 1
            while k < n and s_nodes[k] <= far[q]:
                if axis == 0:
                    votes[k + 1, iu, iv] += 1
                elif axis == 1:
                    votes[iv, k + 1, iu] += 1
                else:
                    votes[iu, iv, k + 1] += 1
                k += 1


@nb.njit(cache=True)
def _join_pass(inside):
    """One pass of :func:`_join_checkerboards`; returns how many nodes it filled."""
    nx, ny, nz = inside.shape
    filled = 0
    for i in range(nx - 1):
        for j in range(ny - 1):
            for k in range(nz - 1):
                for plane in range(3):  # the square in (x, y), (y, z), (z, x) from node (i, j, k)
                    if plane == 0:
                        i1, j1, k1, i2, j2, k2 = i + 1, j, k, i, j + 1, k
                    elif plane == 1:
                        i1, j1, k1, i2, j2, k2 = i, j + 1, k, i, j, k + 1
                    else:
                        i1, j1, k1, i2, j2, k2 = i, j, k + 1, i + 1, j, k
                    a = inside[i, j, k]
                    d = inside[i1 + i2 - i, j1 + j2 - j, k1 + k2 - k]
                    b = inside[i1, j1, k1]
                    c = inside[i2, j2, k2]
                    if a == d and b == c and a != b:
                        if a:
                            inside[i1, j1, k1] = True
                            inside[i2, j2, k2] = True
                        else:
                            inside[i, j, k] = True
                            inside[i1 + i2 - i, j1 + j2 - j, k1 + k2 - k] = True
                        filled += 2
    return filled


@nb.njit(cache=True)
def _sign_changes(inside, axis, out, leaving):
    """The edges along ``axis`` whose two nodes differ: their first node's padded index
    into ``out`` (m, 3) and whether that node is the inside one into ``leaving``; with
    empty outputs only counts. Returns the count."""
    nx, ny, nz = inside.shape
    di = 1 if axis == 0 else 0
    dj = 1 if axis == 1 else 0
    dk = 1 if axis == 2 else 0
    fill = out.shape[0] > 0
    m = 0
    for i in range(nx - di):
        for j in range(ny - dj):
            for k in range(nz - dk):
                a = inside[i, j, k]
                if a != inside[i + di, j + dj, k + dk]:
                    if fill:
                        out[m, 0] = i
                        out[m, 1] = j
                        out[m, 2] = k
                        leaving[m] = a
                    m += 1
    return m


@nb.njit(cache=True)
def _edge_crossings(offsets, near, far, nid, fid, s_pad, rays, along, leaving, out_s, out_id):
    """The crossing on each sign-changing lattice edge, from the ray running along it.

    Edge ``e`` joins padded nodes ``along[e]`` and ``along[e] + 1`` of ray ``rays[e]``
    (``s_pad``: float32 node parameters with one pad node each end). ``leaving[e]``:
    the vote reads the first node inside and the second outside. Segments are clipped
    to the lattice ``[s_pad[1], s_pad[-2]]``. Writes ``out_s`` (mm along the ray) and
    ``out_id`` (the face id of the segment end used).
    """
    lo_s = s_pad[1]
    hi_s = s_pad[s_pad.size - 2]
    for e in range(rays.size):
        r = rays[e]
        sa = s_pad[along[e]]
        sb = s_pad[along[e] + 1]
        leave = leaving[e]
        found = False
        best = np.float32(0.0)
        bid = 0
        ra = False  # the ray's own reading of the two nodes
        rb = False
        for q in range(offsets[r], offsets[r + 1]):
            n0 = max(near[q], lo_s)
            f0 = min(far[q], hi_s)
            if n0 > f0:
                continue
            if n0 <= sa <= f0:
                ra = True
            if n0 <= sb <= f0:
                rb = True
            if leave:
                if not found and sa <= f0 <= sb:  # the first end of material in the edge
                    found = True
                    best = f0
                    bid = fid[q]
            elif sa <= n0 <= sb:  # the last start of material in the edge
                found = True
                best = n0
                bid = nid[q]
        if found:
            out_s[e] = best
            out_id[e] = bid
            continue
        # the ray disagrees with the vote: the surface is at the node it misread
        if ra != leave:
            s = np.float64(sa)
        elif rb == leave:
            s = np.float64(sb)
        else:
            s = 0.5 * (np.float64(sa) + np.float64(sb))
        out_s[e] = s
        gap = np.inf  # the face id of the ray's end nearest the crossing
        bid = 0
        for q in range(offsets[r], offsets[r + 1]):
            if abs(near[q] - s) < gap:
                gap = abs(near[q] - s)
                bid = nid[q]
            if abs(far[q] - s) < gap:
                gap = abs(far[q] - s)
                bid = fid[q]
        out_id[e] = bid


@nb.njit(cache=True)
def _nearest_end(offsets, near, far, r, leave, s, lo_s, hi_s):
    """The end of ray ``r``'s material of the same kind as a crossing at ``s`` (a far end
    where material is left, a near end where it begins; clipped to the lattice) nearest
    to ``s``: (found, its s)."""
    best = np.inf
    got = np.nan
    for q in range(offsets[r], offsets[r + 1]):
        n0 = max(near[q], lo_s)
        f0 = min(far[q], hi_s)
        if n0 > f0:
            continue
        v = np.float64(f0 if leave else n0)
        if abs(v - s) < best:
            best = abs(v - s)
            got = v
    return best < np.inf, got


@nb.njit(cache=True)
def _crossing_normals(offsets, near, far, nu, nv, lo_s, hi_s, spacing, rays, leaving, cross, out):
    """Outward unit normal at each crossing in the grid's (direction, u, v) components.

    The surface near a crossing is ``s = f(u, v)`` along the ray; its slopes come from
    the same kind of crossing on the four neighbouring rays (central differences, one
    side where a neighbour has none within two spacings, flat where neither has):
    normal = +-(1, -df/du, -df/dv), + where material ends along +s.
    """
    reach = 2.0 * spacing
    for e in range(rays.size):
        r = rays[e]
        iu = r % nu
        iv = r // nu
        s = cross[e]
        leave = leaving[e]
        slope = np.zeros(2)
        for d in range(2):
            step = 1 if d == 0 else nu
            pos = iu if d == 0 else iv
            size = nu if d == 0 else nv
            total = 0.0
            span = 0.0
            for side in (-1, 1):
                if 0 <= pos + side < size:
                    ok, v = _nearest_end(offsets, near, far, r + side * step, leave, s, lo_s, hi_s)
                    if ok and abs(v - s) <= reach:
                        total += v - s if side > 0 else s - v
                        span += spacing
            if span > 0:
                slope[d] = total / span
        sign = 1.0 if leave else -1.0
        norm = np.sqrt(1.0 + slope[0] ** 2 + slope[1] ** 2)
        out[e, 0] = sign / norm
        out[e, 1] = -sign * slope[0] / norm
        out[e, 2] = -sign * slope[1] / norm


def _node_coords(model: TriDexel, axis: int) -> np.ndarray:
    """Node coordinates along ``axis`` (float64 mm), with one pad node at each end."""
    n = model.shape[axis]
    return model.lo[axis] + model.spacing * (np.arange(n + 2) - 1.0)


def _occupancy(model: TriDexel, segments: dict) -> np.ndarray:
    """Padded node occupancy, bool (nx+2, ny+2, nz+2): the two-of-three vote (module doc)."""
    nx, ny, nz = model.shape
    votes = np.zeros((nx + 2, ny + 2, nz + 2), np.uint8)
    for a, g in model.grids.items():
        offsets, near, far, _, _ = segments[a]
        s_nodes = _node_coords(model, _AXIS[a])[1:-1].astype(np.float32)
        _add_votes(offsets, near, far, s_nodes, g.frame.nu, _AXIS[a], votes)
    inside = votes >= 2
    _join_checkerboards(inside)
    return inside


def _join_checkerboards(inside: np.ndarray) -> None:
    """Take inside the empty nodes of every lattice square whose diagonal nodes alone
    hold material (in place, repeated until none is left; only ever adds material, so
    it ends)."""
    while _join_pass(inside):
        pass


# the four cells round an edge along each axis, counter-clockwise seen from +axis, as
# offsets of the cell's first node from the edge's first node (padded indices)
_RING = {
    0: ((0, -1, -1), (0, 0, -1), (0, 0, 0), (0, -1, 0)),   # (y, z) plane
    1: ((-1, 0, -1), (-1, 0, 0), (0, 0, 0), (0, 0, -1)),   # (z, x) plane
    2: ((-1, -1, 0), (0, -1, 0), (0, 0, 0), (-1, 0, 0)),   # (x, y) plane
}


def _axis_edges(model: TriDexel, inside: np.ndarray, a: str, segments: dict):
    """The sign-changing edges along grid ``a``'s axis: (crossing points (m, 3) world mm,
    face ids (m,), cells (m, 4) flat padded-cell indices wound outward, outward unit
    normals (m, 3), +1 where the material is left along +axis else -1 (m,))."""
    ax = _AXIS[a]
    nx, ny, nz = model.shape
    m = _sign_changes(inside, ax, np.empty((0, 3), np.int64), np.empty(0, np.bool_))
    first = np.empty((m, 3), np.int64)
    leaving = np.empty(m, np.bool_)
    _sign_changes(inside, ax, first, leaving)
    pi, pj, pk = first.T
    # the ray along the edge, flat index r = iv * nu + iu on its grid (sim.tridexel table)
    if a == "x":
        rays, along = (pk - 1) * ny + (pj - 1), pi
    elif a == "y":
        rays, along = (pi - 1) * nz + (pk - 1), pj
    else:
        rays, along = (pj - 1) * nx + (pi - 1), pk
    offsets, near, far, nid, fid = segments[a]
    s_pad = _node_coords(model, ax).astype(np.float32)
    cross = np.empty(pi.size)
    ids = np.empty(pi.size, np.int32)
    _edge_crossings(offsets, near, far, nid, fid, s_pad, rays, along, leaving, cross, ids)
    g = model.grids[a].frame
    local = np.empty((pi.size, 3))
    _crossing_normals(offsets, near, far, g.nu, g.nv, s_pad[1], s_pad[-2], model.spacing, rays, leaving,
                      cross, local)
    normals = np.empty_like(local)
    normals[:, list(_DUV[a])] = local
    idx = (pi, pj, pk)
    points = np.stack([_node_coords(model, d)[idx[d]] for d in range(3)], axis=1)
    points[:, ax] = cross
    cj, ck = ny + 1, nz + 1  # cells per padded axis: nx+1, ny+1, nz+1
    cells = np.stack([((pi + o[0]) * cj + (pj + o[1])) * ck + (pk + o[2]) for o in _RING[ax]], axis=1)
    cells[~leaving] = cells[~leaving, ::-1]  # material above the edge: the normal points down
    return points, ids, cells, normals, np.where(leaving, 1.0, -1.0)


@nb.njit(cache=True, inline="always")
def _rotate(a, v, p, q):
    """One Jacobi rotation zeroing ``a[p, q]`` of the symmetric 3x3 ``a`` (in place),
    accumulated into the eigenvectors ``v`` (columns)."""
    if a[p, q] == 0.0:
        return
    theta = (a[q, q] - a[p, p]) / (2.0 * a[p, q])
    t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1.0))
    c = 1.0 / np.sqrt(t * t + 1.0)
    s = t * c
    for k in range(3):
        akp, akq = a[k, p], a[k, q]
        a[k, p], a[k, q] = c * akp - s * akq, s * akp + c * akq
    for k in range(3):
        apk, aqk = a[p, k], a[q, k]
        a[p, k], a[q, k] = c * apk - s * aqk, s * apk + c * aqk
    for k in range(3):
        vkp, vkq = v[k, p], v[k, q]
        v[k, p], v[k, q] = c * vkp - s * vkq, s * vkp + c * vkq


@nb.njit(cache=True)
def _place(vert_of, points, normals, n_v, threshold, qef, out, out_mean):
    """Vertices into ``out`` (n_v, 3): the mean of each cell's crossings (also into
    ``out_mean``), moved (``qef``) by the pseudo-inverse of ``A = sum n n^T``
    (eigenvalues over ``threshold`` x the crossing count; Jacobi's method) applied to
    the planes' residuals at the mean."""
    count = np.zeros(n_v)
    acc = np.zeros((n_v, 12))  # sum c (3), sum n n^T (xx xy xz yy yz zz), sum n (n . c) (3)
    for e in range(vert_of.shape[0]):
        c0, c1, c2 = points[e, 0], points[e, 1], points[e, 2]
        n0, n1, n2 = normals[e, 0], normals[e, 1], normals[e, 2]
        nc = n0 * c0 + n1 * c1 + n2 * c2
        for k in range(4):
            w = vert_of[e, k]
            count[w] += 1.0
            row = acc[w]
            row[0] += c0
            row[1] += c1
            row[2] += c2
            row[3] += n0 * n0
            row[4] += n0 * n1
            row[5] += n0 * n2
            row[6] += n1 * n1
            row[7] += n1 * n2
            row[8] += n2 * n2
            row[9] += n0 * nc
            row[10] += n1 * nc
            row[11] += n2 * nc
    a = np.empty((3, 3))
    v = np.empty((3, 3))
    m = np.empty(3)
    r = np.empty(3)
    for w in range(n_v):
        row = acc[w]
        for d in range(3):
            m[d] = row[d] / count[w]
            out[w, d] = m[d]
            out_mean[w, d] = m[d]
        if not qef:
            continue
        a[0, 0], a[0, 1], a[0, 2] = row[3], row[4], row[5]
        a[1, 0], a[1, 1], a[1, 2] = row[4], row[6], row[7]
        a[2, 0], a[2, 1], a[2, 2] = row[5], row[7], row[8]
        for d in range(3):
            r[d] = row[9 + d] - (a[d, 0] * m[0] + a[d, 1] * m[1] + a[d, 2] * m[2])
        for i in range(3):
            for j in range(3):
                v[i, j] = 1.0 if i == j else 0.0
        for sweep in range(12):  # 3x3: a handful of sweeps reach float precision
            if a[0, 1] ** 2 + a[0, 2] ** 2 + a[1, 2] ** 2 <= 1e-24 * count[w] ** 2:
                break
            _rotate(a, v, 0, 1)
            _rotate(a, v, 0, 2)
            _rotate(a, v, 1, 2)
        for k in range(3):
            lam = a[k, k]
            if lam > threshold * count[w]:
                coef = (v[0, k] * r[0] + v[1, k] * r[1] + v[2, k] * r[2]) / lam
                for d in range(3):
                    out[w, d] += coef * v[d, k]


def _place_vertices(model: TriDexel, cell_of_vertex, vert_of, points, normals, placement: str):
    """One vertex per cell: (vertices, means), float64 (n_v, 3) world mm each.
    ``cell_of_vertex`` (n_v,): each vertex's flat padded cell; ``vert_of`` (m, 4): the
    vertices round each crossing.

    ``"mean"``: the mean of the cell's crossings. ``"qef"``: the point nearest, in least
    squares, to the tangent planes of its crossings (normals from
    :func:`_crossing_normals`), moved from the mean only in the directions the normals
    pin down (:data:`_QEF_THRESHOLD`), then clamped to the cell (so the mesh cannot
    fold across cells).
    """
    if placement not in ("qef", "mean"):
        raise ValueError(f"placement must be 'mean' or 'qef', got {placement!r}")
    verts = np.empty((cell_of_vertex.size, 3))
    mean = np.empty_like(verts)
    _place(vert_of, points, normals, cell_of_vertex.size, _QEF_THRESHOLD, placement == "qef", verts, mean)
    if placement == "mean":
        return verts, mean
    low = _cell_low(model, cell_of_vertex)
    return np.clip(verts, low, low + model.spacing, out=verts), mean


def _cell_low(model: TriDexel, cells: np.ndarray) -> np.ndarray:
    """The first corner (world mm, (n, 3)) of each flat padded cell."""
    nx, ny, nz = model.shape
    first = np.stack(np.unravel_index(cells, (nx + 1, ny + 1, nz + 1)), axis=1)
    return model.lo + model.spacing * (first - 1.0)  # padded index 0 is one spacing before lo


def _separate(model: TriDexel, verts: np.ndarray, cell_of_vertex: np.ndarray) -> None:
    """Round the vertices to float32 (what an STL holds) and move those of different
    cells that then sit at the same point (the surface through a node, a QEF clamped
    onto the line two cells share, float32 dexel ends beside float64 nodes) a
    thousandth of a spacing towards their cells' centres (in place). The mesh is closed
    either way, but an STL keeps no vertex indices: readers merge vertices by position,
    and merged they would join four faces on an edge."""
    verts[:] = verts.astype(np.float32)
    # "the same point": within a hundred-thousandth of a spacing (readers merge at their
    # own tolerance, trimesh's 1e-8 mm absolute: float32 keeps 1e-16 apart from -1e-16)
    key = np.rint(verts / (1e-5 * model.spacing))
    order = np.lexsort(key.T[::-1])
    ordered = key[order]
    same = np.all(ordered[1:] == ordered[:-1], axis=1)
    if not same.any():
        return
    group = np.zeros(len(verts), bool)
    group[1:] |= same
    group[:-1] |= same
    w = order[group]
    centre = _cell_low(model, cell_of_vertex[w]) + model.spacing / 2
    verts[w] = (verts[w] + 1e-3 * (centre - verts[w])).astype(np.float32)


@nb.njit(cache=True, inline="always")
def _facing(verts, a, b, c, ax):
    """Component ``ax`` of the area vector ``(b - a) x (c - a)`` of triangle a b c."""
    i1 = (ax + 1) % 3
    i2 = (ax + 2) % 3
    return ((verts[b, i1] - verts[a, i1]) * (verts[c, i2] - verts[a, i2])
            - (verts[b, i2] - verts[a, i2]) * (verts[c, i1] - verts[a, i1]))


@nb.njit(cache=True)
def _split_quads(verts, quads, axis, sign, faces):
    """Two triangles per quad into ``faces`` (2m, 3): quad ``q``'s first triangle at row
    ``q``, its second at ``m + q``.

    Each quad's vertices lie one in each quadrant round its edge (``axis``), in turn, so
    seen along the edge the quad is a simple polygon round it and one of its diagonals
    at least is inside it: the quad is split along a diagonal whose two triangles both
    face out of the material (``sign`` x ``axis``). Splitting along the other one could
    fold a triangle back where a vertex sits deep in a corner of its cell.
    """
    m = quads.shape[0]
    for q in range(m):
        v0, v1, v2, v3 = quads[q, 0], quads[q, 1], quads[q, 2], quads[q, 3]
        ax = axis[q]
        sg = sign[q]
        first_ok = min(sg * _facing(verts, v0, v1, v2, ax), sg * _facing(verts, v0, v2, v3, ax)) > 0
        other_ok = min(sg * _facing(verts, v0, v1, v3, ax), sg * _facing(verts, v1, v2, v3, ax)) > 0
        if other_ok and not first_ok:
            faces[q, 0], faces[q, 1], faces[q, 2] = v0, v1, v3
            faces[m + q, 0], faces[m + q, 1], faces[m + q, 2] = v1, v2, v3
        else:
            faces[q, 0], faces[q, 1], faces[q, 2] = v0, v1, v2
            faces[m + q, 0], faces[m + q, 1], faces[m + q, 2] = v0, v2, v3


@nb.njit(cache=True)
def _unfold_pass(verts, mean, faces, normals):
    """Move back to their cell's mean the vertices of every triangle facing against its
    crossing's normal (``normals`` (m, 3); triangle ``t`` is crossing ``t % m``'s) and
    not already there; returns how many moved."""
    m = normals.shape[0]
    moved = 0
    for t in range(faces.shape[0]):
        a, b, c = faces[t, 0], faces[t, 1], faces[t, 2]
        e = t % m
        dot = 0.0
        for ax in range(3):
            dot += _facing(verts, a, b, c, ax) * normals[e, ax]
        if dot < 0:
            for w in (a, b, c):
                if verts[w, 0] != mean[w, 0] or verts[w, 1] != mean[w, 1] or verts[w, 2] != mean[w, 2]:
                    verts[w, 0], verts[w, 1], verts[w, 2] = mean[w, 0], mean[w, 1], mean[w, 2]
                    moved += 1
    return moved


def _unfold(verts, mean, vert_of, normals, axis, sign, rounds: int = 3):
    """The triangles (:func:`_split_quads`), with the vertices of every triangle that
    faces against its crossing's normal moved back to their cell's mean (a QEF vertex
    pulled towards a sharp feature its neighbours do not share can fold a face over;
    the means do not), a few rounds. Changes ``verts`` in place; returns the faces."""
    faces = np.empty((2 * len(vert_of), 3), np.int64)
    _split_quads(verts, vert_of, axis, sign, faces)
    for _ in range(rounds):
        if not _unfold_pass(verts, mean, faces, normals):
            break
        _split_quads(verts, vert_of, axis, sign, faces)
    return faces


def tridexel_arrays(model: TriDexel, placement: str = "qef"):
    """The closed surface of ``model`` as arrays (see the module docstring);
    ``placement`` of the vertices: ``"qef"`` or ``"mean"`` (:func:`_place_vertices`).

    Returns ``(vertices, faces, move_id)``: float64 (n_v, 3) world mm (float32 values,
    no two of them within 1e-5 spacing: see :func:`_separate`), int64 (n_f, 3) vertex
    indices wound outward, int32 (n_f,) face ids. Memory: about 7 bytes per lattice
    node (votes, occupancy, cell map) beside the surface's own arrays.
    """
    if not isinstance(model, TriDexel):
        raise InputError(f"tridexel_mesh needs a TriDexel, got {type(model).__name__}")
    segments = {a: _live_segments(g) for a, g in model.grids.items()}
    inside = _occupancy(model, segments)
    parts = [_axis_edges(model, inside, a, segments) for a in ("x", "y", "z")]
    normals = np.concatenate([p[3] for p in parts])
    points = np.concatenate([p[0] for p in parts])
    ids = np.concatenate([p[1] for p in parts])
    cells = np.concatenate([p[2] for p in parts])
    if cells.size == 0:  # no material
        return np.empty((0, 3)), np.empty((0, 3), np.int64), np.empty(0, np.int32)
    # one vertex per cell that has a crossing, numbered in cell order (a dense map: the
    # cells are a byte each, cheaper than sorting the surface's cell list)
    used = np.zeros(int(np.prod(np.array(model.shape) + 1)), np.bool_)
    used[cells.ravel()] = True
    number = np.cumsum(used, dtype=np.int32 if used.size < 2**31 else np.int64) - 1
    vert_of = number[cells]
    cell_of_vertex = np.flatnonzero(used)
    verts, mean = _place_vertices(model, cell_of_vertex, vert_of, points, normals, placement)
    axis = np.concatenate([np.full(len(p[0]), _AXIS[a], np.int64) for a, p in zip("xyz", parts)])
    sign = np.concatenate([p[4] for p in parts])
    faces = _unfold(verts, mean, vert_of, normals, axis, sign)
    _separate(model, verts, cell_of_vertex)
    return verts, faces, np.concatenate([ids, ids])


def tridexel_mesh(model: TriDexel, placement: str = "qef"):
    """The closed, outward-wound surface of ``model`` as a ``trimesh.Trimesh`` (world mm),
    with ``face_attributes["move_id"]`` (int32) per triangle (``placement``: see
    :func:`tridexel_arrays`)."""
    import trimesh

    verts, faces, ids = tridexel_arrays(model, placement)
    return trimesh.Trimesh(vertices=verts, faces=faces, face_attributes={"move_id": ids},
                           process=False, validate=False)


def export_stl(model: TriDexel, path) -> Path:
    """Write the closed surface of ``model`` as a binary STL (mm); returns the path."""
    return write_stl(lambda: tridexel_mesh(model), path)
