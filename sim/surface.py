"""Triangle surfaces of dexel models: a closed "voxel-column" surface and a top heightfield.

Each ray of a grid stands for a column of cross-section spacing x spacing centred on the
ray; a segment ``[near, far]`` is a box in that column. :func:`surface_mesh` emits the
boundary of the union of all those boxes: a near and a far cap per segment, and side
walls wherever two neighbouring columns differ. Wall edges are split at every segment
end of the columns around each vertical corner line, so there are no T-junctions: the
result is watertight, consistently wound (outward) and its volume equals
``grid.volume()`` exactly (up to float rounding).

Every triangle carries ``face_attributes["move_id"]`` (int32): the id of the dexel face
it shows (caps), or the latest id among the faces bounding it (walls), so a renderer can
colour by the move that made each surface.
"""

from __future__ import annotations

from pathlib import Path

import numba as nb
import numpy as np

from sim.errors import InputError
from sim.grid import DexelGrid


def _live_segments(grid: DexelGrid):
    """All segments in ray order with empty ones (near >= far after float32) dropped."""
    n_rays = grid.frame.n_rays
    near, far, nid, fid, counts = grid.segments_of(np.arange(n_rays))
    keep = far > near
    if not keep.all():
        ray = np.repeat(np.arange(n_rays), counts)
        counts = np.bincount(ray[keep], minlength=n_rays).astype(np.int64)
        near, far, nid, fid = near[keep], far[keep], nid[keep], fid[keep]
    offsets = np.zeros(n_rays + 1, np.int64)
    np.cumsum(counts, out=offsets[1:])
    return offsets, near, far, nid, fid


@nb.njit(cache=True)
def _insertion_sort(buf, m):
    for a in range(1, m):
        x = buf[a]
        b = a - 1
        while b >= 0 and buf[b] > x:
            buf[b + 1] = buf[b]
            b -= 1
        buf[b + 1] = x


@nb.njit(cache=True)
def _breakpoints(nu, nv, offsets, near, far, bp_off, bp_s, fill):
    """Sorted distinct segment ends of the (up to) four columns around each corner.

    Corner ``(ci, cj)`` (0..nu, 0..nv; flat ``cj*(nu+1) + ci``) sits at grid position
    ``(ci - 0.5, cj - 0.5)``. Counting pass (``fill`` False) writes the count per corner
    into ``bp_off[c + 1]``; the filling pass writes values from ``bp_off[c]``.
    """
    maxc = 0
    for r in range(nu * nv):
        maxc = max(maxc, offsets[r + 1] - offsets[r])
    buf = np.empty(8 * maxc + 1, np.float32)
    for cj in range(nv + 1):
        for ci in range(nu + 1):
            m = 0
            for j in range(cj - 1, cj + 1):
                if j < 0 or j >= nv:
                    continue
                for i in range(ci - 1, ci + 1):
                    if i < 0 or i >= nu:
                        continue
                    r = j * nu + i
                    for k in range(offsets[r], offsets[r + 1]):
                        buf[m] = near[k]
                        buf[m + 1] = far[k]
                        m += 2
            _insertion_sort(buf, m)
            c = cj * (nu + 1) + ci
            u = 0
            o = bp_off[c] if fill else 0
            for k in range(m):
                if k == 0 or buf[k] != buf[k - 1]:
                    if fill:
                        bp_s[o + u] = buf[k]
                    u += 1
            if not fill:
                bp_off[c + 1] = u


@nb.njit(cache=True, inline="always")
def _vid(bp_off, bp_s, c, s):
    """Vertex index of value ``s`` on corner ``c`` (it is always present)."""
    lo = bp_off[c]
    hi = bp_off[c + 1]
    return lo + np.searchsorted(bp_s[lo:hi], s)


@nb.njit(cache=True, inline="always")
def _emit(tris, ids, t, fill, a, b, c, face_id):
    if fill:
        tris[t, 0] = a
        tris[t, 1] = b
        tris[t, 2] = c
        ids[t] = face_id
    return t + 1


@nb.njit(cache=True)
def _strip(bp_off, bp_s, cp, cq, a, b, flip, face_id, tris, ids, t, fill):
    """Triangulate the wall piece [a, b] between corner lines P (cp) and Q (cq).

    Both vertical edges are split at their corners' breakpoints; the triangles zig-zag
    between the two chains, wound so the normal points from P->Q x (+s) (flip reverses).
    """
    p = _vid(bp_off, bp_s, cp, a)
    p_end = _vid(bp_off, bp_s, cp, b)
    q = _vid(bp_off, bp_s, cq, a)
    q_end = _vid(bp_off, bp_s, cq, b)
    while p < p_end or q < q_end:
        if q < q_end and (p == p_end or bp_s[q + 1] <= bp_s[p + 1]):
            if flip:
                t = _emit(tris, ids, t, fill, p, q + 1, q, face_id)
            else:
                t = _emit(tris, ids, t, fill, p, q, q + 1, face_id)
            q += 1
        else:
            if flip:
                t = _emit(tris, ids, t, fill, p, p + 1, q, face_id)
            else:
                t = _emit(tris, ids, t, fill, p, q, p + 1, face_id)
            p += 1
    return t


@nb.njit(cache=True)
def _wall(offsets, near, far, nid, fid, rl, rr, cp, cq, side_flip, bp_off, bp_s, tris, ids,
          t, fill):
    """Walls between column ``rl`` and ``rr`` (-1 = outside the grid): where one holds
    material and the other not. ``side_flip`` picks the winding for material on ``rl``.
    """
    kl = offsets[rl] if rl >= 0 else 0
    el = offsets[rl + 1] if rl >= 0 else 0
    kr = offsets[rr] if rr >= 0 else 0
    er = offsets[rr + 1] if rr >= 0 else 0
    nl = 2 * (el - kl)
    nr = 2 * (er - kr)
    bl = 0  # boundary counters: even = next is a near face
    br = 0
    in_l = False
    in_r = False
    state = 0  # 0 none, 1 only l, 2 only r
    start = 0.0
    start_id = 0
    while bl < nl or br < nr:
        sl = np.inf
        sr = np.inf
        idl = 0
        idr = 0
        if bl < nl:
            h = kl + (bl >> 1)
            sl = near[h] if (bl & 1) == 0 else far[h]
            idl = nid[h] if (bl & 1) == 0 else fid[h]
        if br < nr:
            h = kr + (br >> 1)
            sr = near[h] if (br & 1) == 0 else far[h]
            idr = nid[h] if (br & 1) == 0 else fid[h]
        s = min(sl, sr)
        face_id = 0
        if sl == s:
            in_l = (bl & 1) == 0
            bl += 1
            face_id = idl
        if sr == s:
            in_r = (br & 1) == 0
            br += 1
            face_id = max(face_id, idr)
        new = 0
        if in_l and not in_r:
            new = 1
        elif in_r and not in_l:
            new = 2
        if new != state:
            if state != 0:
                flip = side_flip if state == 1 else not side_flip
                t = _strip(bp_off, bp_s, cp, cq, start, s, flip, max(start_id, face_id),
                           tris, ids, t, fill)
            state = new
            start = s
            start_id = face_id
    return t


@nb.njit(cache=True)
def _triangles(nu, nv, offsets, near, far, nid, fid, bp_off, bp_s, tris, ids, fill):
    """Count (``fill`` False) or write all cap and wall triangles; returns the count."""
    t = 0
    w = nu + 1
    for j in range(nv):
        for i in range(nu):
            r = j * nu + i
            c00 = j * w + i
            c10 = c00 + 1
            c01 = c00 + w
            c11 = c01 + 1
            for k in range(offsets[r], offsets[r + 1]):
                f = far[k]
                a = _vid(bp_off, bp_s, c00, f)
                b = _vid(bp_off, bp_s, c10, f)
                c = _vid(bp_off, bp_s, c11, f)
                d = _vid(bp_off, bp_s, c01, f)
                t = _emit(tris, ids, t, fill, a, b, c, fid[k])  # far cap faces +s
                t = _emit(tris, ids, t, fill, a, c, d, fid[k])
                n = near[k]
                a = _vid(bp_off, bp_s, c00, n)
                b = _vid(bp_off, bp_s, c10, n)
                c = _vid(bp_off, bp_s, c11, n)
                d = _vid(bp_off, bp_s, c01, n)
                t = _emit(tris, ids, t, fill, a, c, b, nid[k])  # near cap faces -s
                t = _emit(tris, ids, t, fill, a, d, c, nid[k])
    # walls across u: between columns (i, j) and (i+1, j), on corner line i+1
    for j in range(nv):
        for i in range(-1, nu):
            rl = j * nu + i if i >= 0 else -1
            rr = j * nu + i + 1 if i + 1 < nu else -1
            cp = j * w + i + 1
            t = _wall(offsets, near, far, nid, fid, rl, rr, cp, cp + w, False, bp_off, bp_s,
                      tris, ids, t, fill)
    # walls across v: between columns (i, j) and (i, j+1), on corner line j+1
    for j in range(-1, nv):
        for i in range(nu):
            rl = j * nu + i if j >= 0 else -1
            rr = (j + 1) * nu + i if j + 1 < nv else -1
            cp = (j + 1) * w + i
            t = _wall(offsets, near, far, nid, fid, rl, rr, cp, cp + 1, True, bp_off, bp_s,
                      tris, ids, t, fill)
    return t


def surface_arrays(grid: DexelGrid):
    """The closed column surface as arrays.

    Returns ``(vertices, faces, move_id)``: float64 (n_v, 3) world mm, int64 (n_f, 3)
    vertex indices wound outward, int32 (n_f,) face ids.
    """
    fr = grid.frame
    nu, nv = fr.nu, fr.nv
    offsets, near, far, nid, fid = _live_segments(grid)
    n_corners = (nu + 1) * (nv + 1)
    bp_off = np.zeros(n_corners + 1, np.int64)
    empty_s = np.empty(0, np.float32)
    _breakpoints(nu, nv, offsets, near, far, bp_off, empty_s, False)
    np.cumsum(bp_off, out=bp_off)
    bp_s = np.empty(int(bp_off[-1]), np.float32)
    _breakpoints(nu, nv, offsets, near, far, bp_off, bp_s, True)
    no_tris = np.empty((0, 3), np.int64)
    no_ids = np.empty(0, np.int32)
    n_tris = _triangles(nu, nv, offsets, near, far, nid, fid, bp_off, bp_s, no_tris, no_ids, False)
    tris = np.empty((n_tris, 3), np.int64)
    ids = np.empty(n_tris, np.int32)
    _triangles(nu, nv, offsets, near, far, nid, fid, bp_off, bp_s, tris, ids, True)
    corner = np.repeat(np.arange(n_corners), np.diff(bp_off))
    ci = (corner % (nu + 1)).astype(np.float64) - 0.5
    cj = (corner // (nu + 1)).astype(np.float64) - 0.5
    local = np.stack([ci * fr.spacing, cj * fr.spacing, bp_s.astype(np.float64)], axis=1)
    return fr.to_world(local), tris, ids


def surface_mesh(grid: DexelGrid):
    """The closed, outward-wound column surface of ``grid`` as a ``trimesh.Trimesh``.

    Watertight whenever no two neighbouring columns touch only along an edge (material
    of one column ending exactly where the neighbour's begins, an edge shared by four
    faces). ``mesh.volume == grid.volume()``; ``mesh.face_attributes["move_id"]`` holds
    the face ids. Vertices in world mm.
    """
    import trimesh

    verts, faces, ids = surface_arrays(grid)
    return trimesh.Trimesh(vertices=verts, faces=faces, face_attributes={"move_id": ids},
                           process=False, validate=False)


def heightfield_mesh(grid: DexelGrid):
    """The top surface only: a triangle per half-cell between neighbouring ray tops.

    Vertices sit at the ray points lifted to each ray's top (largest ``s``); cells whose
    four rays all hold material get two triangles, facing +direction. Cheaper and smoother
    than :func:`surface_mesh` for top-view display; not closed. Per-face
    ``move_id`` = the latest far-face id among the cell's four tops.
    """
    import trimesh

    fr = grid.frame
    top = grid.top().astype(np.float64)
    n_rays = fr.n_rays
    _, _, _, fid, counts = grid.segments_of(np.arange(n_rays))
    top_id = np.zeros(n_rays, np.int32)
    has = counts > 0
    last = np.cumsum(counts) - 1
    top_id[has] = fid[last[has]]
    top_id = top_id.reshape(fr.shape)
    i = np.arange(fr.nu) * fr.spacing
    j = np.arange(fr.nv) * fr.spacing
    local = np.stack(np.broadcast_arrays(i[None, :], j[:, None], top), axis=-1)
    verts = fr.to_world(local).reshape(-1, 3)
    ok = np.isfinite(top)
    cell = ok[:-1, :-1] & ok[:-1, 1:] & ok[1:, :-1] & ok[1:, 1:]
    jj, ii = np.nonzero(cell)
    a = jj * fr.nu + ii
    b = a + 1
    d = a + fr.nu
    c = d + 1
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)
    cid = np.maximum(np.maximum(top_id[:-1, :-1], top_id[:-1, 1:]),
                     np.maximum(top_id[1:, :-1], top_id[1:, 1:]))[jj, ii]
    ids = np.concatenate([cid, cid]).astype(np.int32)
    used = np.zeros(len(verts), bool)
    used[faces.ravel()] = True
    remap = np.cumsum(used) - 1
    return trimesh.Trimesh(vertices=verts[used], faces=remap[faces],
                           face_attributes={"move_id": ids}, process=False, validate=False)


def export_stl(grid: DexelGrid, path) -> Path:
    """Write the closed surface of ``grid`` as a binary STL (mm); returns the path."""
    path = Path(path)
    if not path.parent.is_dir():
        raise InputError("directory does not exist", where=str(path.parent))
    mesh = surface_mesh(grid)
    if len(mesh.faces) == 0:
        raise InputError("the model holds no material; nothing to export", where=str(path))
    mesh.export(str(path), file_type="stl")
    return path
