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
def _covers(offsets, near, far, r, s):
    for k in range(offsets[r], offsets[r + 1]):
        if near[k] < s < far[k]:
            return True
    return False


@nb.njit(cache=True)
def _breakpoints(nu, nv, offsets, near, far, bp_off, bp_s, split_q, fill):
    """Sorted distinct segment ends of the (up to) four columns around each corner.

    Corner ``(ci, cj)`` (0..nu, 0..nv; flat ``cj*(nu+1) + ci``) sits at grid position
    ``(ci - 0.5, cj - 0.5)``; its quadrants are the columns SW=0 ``(ci-1, cj-1)``,
    SE=1 ``(ci, cj-1)``, NW=2 ``(ci-1, cj)``, NE=3 ``(ci, cj)``. Counting pass (``fill``
    False) writes the count per corner into ``bp_off[c + 1]``; the filling pass writes
    values from ``bp_off[c]`` and marks split vertices in ``split_q``.

    Saddles: where only two diagonal columns hold material, four walls meet on the
    corner line. The faces are paired so every edge has two: at each end of such an
    interval the faces touching quadrant ``split_q[v]`` use a copy of the vertex (pairing
    around the material where material ends there, around the empty columns where empty
    space ends), and if the two ends need different pairings a midpoint shared by all
    four walls joins them.
    """
    maxc = 0
    for r in range(nu * nv):
        maxc = max(maxc, offsets[r + 1] - offsets[r])
    buf = np.empty(8 * maxc + 1, np.float32)
    occ = np.empty(8 * maxc + 1, np.int64)
    cols = np.empty(4, np.int64)
    for cj in range(nv + 1):
        for ci in range(nu + 1):
            m = 0
            for q in range(4):
                i = ci - 1 + (q & 1)
                j = cj - 1 + (q >> 1)
                cols[q] = j * nu + i if (0 <= i < nu and 0 <= j < nv) else -1
                if cols[q] >= 0:
                    r = cols[q]
                    for k in range(offsets[r], offsets[r + 1]):
                        buf[m] = near[k]
                        buf[m + 1] = far[k]
                        m += 2
            _insertion_sort(buf, m)
            u = 0
            for k in range(m):
                if k == 0 or buf[k] != buf[k - 1]:
                    buf[u] = buf[k]
                    u += 1
            for k in range(u - 1):  # which quadrants hold material between breakpoints
                mid = 0.5 * (np.float64(buf[k]) + np.float64(buf[k + 1]))
                mask = 0
                for q in range(4):
                    if cols[q] >= 0 and _covers(offsets, near, far, cols[q], mid):
                        mask |= 1 << q
                occ[k] = mask
            c = cj * (nu + 1) + ci
            o = bp_off[c] if fill else 0
            pos = 0
            pending = -1
            for k in range(u):
                v = o + pos
                if fill:
                    bp_s[v] = buf[k]
                    if pending >= 0:
                        split_q[v] = pending
                pos += 1
                pending = -1
                if k < u - 1 and (occ[k] == 6 or occ[k] == 9):
                    d = occ[k]
                    below = occ[k - 1] if k > 0 else 0
                    above = occ[k + 1] if k + 1 < u - 1 else 0
                    bot_mat = (below & d) != d  # material of the diagonal begins here
                    top_mat = (above & d) != d  # ... or ends there
                    qb = (3 if d == 9 else 2) if bot_mat else (2 if d == 9 else 3)
                    qt = (3 if d == 9 else 2) if top_mat else (2 if d == 9 else 3)
                    if fill:
                        split_q[v] = qb
                    if bot_mat != top_mat:
                        if fill:
                            bp_s[o + pos] = np.float32(0.5 * (np.float64(buf[k]) + np.float64(buf[k + 1])))
                        pos += 1
                    pending = qt
            if not fill:
                bp_off[c + 1] = pos


@nb.njit(cache=True, inline="always")
def _pos(bp_off, bp_s, c, s):
    """Index of value ``s`` among corner ``c``'s breakpoints (it is always present)."""
    v = bp_off[c]
    while bp_s[v] < s:  # a corner holds a handful of values: a scan beats bisection
        v += 1
    return v


@nb.njit(cache=True, inline="always")
def _map(split_q, copy_of, v, mask):
    """The vertex a face touching quadrants ``mask`` (bits SW, SE, NW, NE) uses for ``v``."""
    q = split_q[v]
    if q >= 0 and (mask >> q) & 1:
        return copy_of[v]
    return v


@nb.njit(cache=True, inline="always")
def _emit(tris, ids, t, fill, a, b, c, face_id):
    if fill:
        tris[t, 0] = a
        tris[t, 1] = b
        tris[t, 2] = c
        ids[t] = face_id
    return t + 1


# quadrant bits at a corner: SW=1, SE=2, NW=4, NE=8
_SW, _SE, _NW, _NE = 1, 2, 4, 8


@nb.njit(cache=True)
def _triangles(nu, nv, offsets, near, far, nid, fid, V, tris, ids, fill):
    """Count (``fill`` False) or write all cap and wall triangles.

    Returns (triangles, touches): touches counts places where one column's material ends
    exactly where its neighbour's begins (edges of four faces, fixed afterwards).
    """
    bp_off, bp_s, split_q, copy_of = V
    t = 0
    touches = 0
    w = nu + 1
    for j in range(nv):
        for i in range(nu):
            r = j * nu + i
            c00 = j * w + i  # this column is the NE quadrant of c00, NW of c10, ...
            c10 = c00 + 1
            c01 = c00 + w
            c11 = c01 + 1
            for k in range(offsets[r], offsets[r + 1]):
                if not fill:
                    t += 4
                    continue
                s = far[k]  # far cap faces +s
                a = _map(split_q, copy_of, _pos(bp_off, bp_s, c00, s), _NE)
                b = _map(split_q, copy_of, _pos(bp_off, bp_s, c10, s), _NW)
                c = _map(split_q, copy_of, _pos(bp_off, bp_s, c11, s), _SW)
                d = _map(split_q, copy_of, _pos(bp_off, bp_s, c01, s), _SE)
                t = _emit(tris, ids, t, fill, a, b, c, fid[k])
                t = _emit(tris, ids, t, fill, a, c, d, fid[k])
                s = near[k]  # near cap faces -s
                a = _map(split_q, copy_of, _pos(bp_off, bp_s, c00, s), _NE)
                b = _map(split_q, copy_of, _pos(bp_off, bp_s, c10, s), _NW)
                c = _map(split_q, copy_of, _pos(bp_off, bp_s, c11, s), _SW)
                d = _map(split_q, copy_of, _pos(bp_off, bp_s, c01, s), _SE)
                t = _emit(tris, ids, t, fill, a, c, b, nid[k])
                t = _emit(tris, ids, t, fill, a, d, c, nid[k])
    # Walls, one loop over both families so the body exists once (a call per wall with
    # this many array arguments would cost more than the wall). Wall ``wi`` separates
    # column ``rl`` from ``rr`` (-1 = outside the grid) and runs from corner line P to Q.
    # Across u (between (i, j) and (i+1, j)): P = corner (i+1, j), Q = (i+1, j+1); the
    # triangles (P, Q, Q+) face +u. Across v (between (i, j) and (i, j+1)): P = (i, j+1),
    # Q = (i+1, j+1); the same order faces -v. Where only one column holds material the
    # wall is triangulated as a strip zig-zagging between P's and Q's breakpoints.
    n_uw = nv * (nu + 1)
    for wi in range(n_uw + (nv + 1) * nu):
        if wi < n_uw:
            j = wi // (nu + 1)
            i = wi % (nu + 1) - 1
            rl = j * nu + i if i >= 0 else -1
            rr = j * nu + i + 1 if i + 1 < nu else -1
            cp = j * w + i + 1
            cq = cp + w
            mp = _NW | _NE
            mq = _SW | _SE
            side_flip = False
        else:
            j = (wi - n_uw) // nu - 1
            i = (wi - n_uw) % nu
            rl = j * nu + i if j >= 0 else -1
            rr = (j + 1) * nu + i if j + 1 < nv else -1
            cp = (j + 1) * w + i
            cq = cp + 1
            mp = _SE | _NE
            mq = _SW | _NW
            side_flip = True
        kl = offsets[rl] if rl >= 0 else 0
        nl = 2 * (offsets[rl + 1] - kl) if rl >= 0 else 0
        kr = offsets[rr] if rr >= 0 else 0
        nr = 2 * (offsets[rr + 1] - kr) if rr >= 0 else 0
        bl = 0  # boundary counters: even = next is a near face
        br = 0
        in_l = False
        in_r = False
        state = 0  # 0 none, 1 only l, 2 only r
        start = np.float32(0.0)
        start_id = 0
        while bl < nl or br < nr:
            sl = np.float32(np.inf)
            sr = np.float32(np.inf)
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
                if state != 0 and new != 0:
                    touches += 1
                if state != 0:  # the piece [start, s] ends: emit its strip
                    flip = side_flip if state == 1 else not side_flip
                    wid = max(start_id, face_id)  # the latest move among its bounding faces
                    p = _pos(bp_off, bp_s, cp, start)
                    p_end = _pos(bp_off, bp_s, cp, s)
                    q = _pos(bp_off, bp_s, cq, start)
                    q_end = _pos(bp_off, bp_s, cq, s)
                    if not fill:
                        t += (p_end - p) + (q_end - q)
                    while fill and (p < p_end or q < q_end):
                        vp = _map(split_q, copy_of, p, mp)
                        vq = _map(split_q, copy_of, q, mq)
                        if q < q_end and (p == p_end or bp_s[q + 1] <= bp_s[p + 1]):
                            vn = _map(split_q, copy_of, q + 1, mq)
                            q += 1
                        else:
                            vn = _map(split_q, copy_of, p + 1, mp)
                            p += 1
                        if flip:
                            t = _emit(tris, ids, t, fill, vp, vn, vq, wid)
                        else:
                            t = _emit(tris, ids, t, fill, vp, vq, vn, wid)
                state = new
                start = s
                start_id = face_id
    return t, touches


def surface_arrays(grid: DexelGrid):
    """The closed column surface as arrays.

    Returns ``(vertices, faces, move_id)``: float64 (n_v, 3) world mm, int64 (n_f, 3)
    vertex indices wound outward, int32 (n_f,) face ids. Saddle corners get duplicate
    vertices (same position) so that every edge joins exactly two faces.
    """
    fr = grid.frame
    nu, nv = fr.nu, fr.nv
    offsets, near, far, nid, fid = _live_segments(grid)
    n_corners = (nu + 1) * (nv + 1)
    bp_off = np.zeros(n_corners + 1, np.int64)
    no_s = np.empty(0, np.float32)
    no_q = np.empty(0, np.int8)
    _breakpoints(nu, nv, offsets, near, far, bp_off, no_s, no_q, False)
    np.cumsum(bp_off, out=bp_off)
    n_v = int(bp_off[-1])
    bp_s = np.empty(n_v, np.float32)
    split_q = np.full(n_v, -1, np.int8)
    _breakpoints(nu, nv, offsets, near, far, bp_off, bp_s, split_q, True)
    split = np.nonzero(split_q >= 0)[0]
    copy_of = np.full(n_v, -1, np.int64)
    copy_of[split] = n_v + np.arange(split.size)
    V = (bp_off, bp_s, split_q, copy_of)
    no_tris = np.empty((0, 3), np.int64)
    no_ids = np.empty(0, np.int32)
    n_tris, touches = _triangles(nu, nv, offsets, near, far, nid, fid, V, no_tris, no_ids, False)
    tris = np.empty((n_tris, 3), np.int64)
    ids = np.empty(n_tris, np.int32)
    _triangles(nu, nv, offsets, near, far, nid, fid, V, tris, ids, True)
    corner = np.repeat(np.arange(n_corners), np.diff(bp_off))
    corner = np.concatenate([corner, corner[split]])
    s = np.concatenate([bp_s, bp_s[split]]).astype(np.float64)
    # corner feet on the origin plane (few), then each vertex = its foot + s * direction
    ci = (np.arange(nu + 1) - 0.5) * fr.spacing
    cj = (np.arange(nv + 1) - 0.5) * fr.spacing
    feet = (fr.origin + ci[None, :, None] * fr.u + cj[:, None, None] * fr.v).reshape(-1, 3)
    verts = feet[corner]
    verts += s[:, None] * fr.direction
    if touches:
        verts, tris = _split_touching_edges(verts, tris)
    return verts, tris, ids


def _split_touching_edges(verts: np.ndarray, tris: np.ndarray):
    """Make edges shared by four faces manifold by giving each side its own vertices.

    Where one column's material ends exactly where a neighbour's begins, two solids
    touch along an edge. Around that edge the faces are paired so each pair bounds one
    solid's wedge; then at each end vertex the incident faces are grouped into fans
    joined through their shared edges, and every fan after the first gets a copy of the
    vertex (same position). Rare, so done in numpy on the affected vertices only.
    """
    edges = np.sort(np.stack([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]], axis=1)
                    .reshape(-1, 2), axis=1)
    key = edges[:, 0] * (len(verts) + 1) + edges[:, 1]
    order = np.argsort(key, kind="stable")
    ks = key[order]
    starts = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    sizes = np.diff(np.r_[starts, ks.size])
    bad = starts[sizes == 4]
    if bad.size == 0:
        return verts, tris
    pair_of = {}  # (face, edge key) -> partner face across a four-face edge
    for b in bad:
        faces4 = order[b:b + 4] // 3
        e = edges[order[b]]
        pa, pb = verts[e[0]], verts[e[1]]
        axis = (pb - pa) / np.linalg.norm(pb - pa)
        ref = None
        angles = []
        inward = []
        for f in faces4:
            third = [v for v in tris[f] if v not in e][0]
            w = verts[third] - pa
            w -= axis * (w @ axis)
            w /= np.linalg.norm(w)
            if ref is None:
                ref = w
            angles.append(np.arctan2(np.cross(ref, w) @ axis, ref @ w))
            a, b2, c = verts[tris[f]]
            normal = np.cross(b2 - a, c - a)
            inward.append(normal @ np.cross(axis, w) < 0)  # wedge CCW of f is material
        k = np.argsort(angles)
        ring = faces4[k]
        solid_after = np.asarray(inward)[k]
        first = 0 if solid_after[0] else 1
        for p in (first, first + 2):
            f, g = ring[p % 4], ring[(p + 1) % 4]
            pair_of[(f, ks[b])] = g
            pair_of[(g, ks[b])] = f
    touched = np.unique(edges[order[np.concatenate([b + np.arange(4) for b in bad])]])
    tris = tris.copy()
    extra = []
    near_faces = np.flatnonzero(np.isin(tris, touched).any(axis=1))
    faces_at = {}
    for f in near_faces:
        for w in tris[f]:
            faces_at.setdefault(int(w), []).append(int(f))
    for v in touched:
        fans = faces_at[int(v)]
        parent = {int(f): int(f) for f in fans}

        def find(x):
            while parent[x] != x:
                parent[x] = parent[parent[x]]
                x = parent[x]
            return x

        by_edge = {}
        for f in fans:
            for w in tris[f]:
                if w != v:
                    by_edge.setdefault((min(v, w), max(v, w)), []).append(int(f))
        for (lo, hi), fs in by_edge.items():
            k = lo * (len(verts) + 1) + hi
            if len(fs) == 2:
                parent[find(fs[0])] = find(fs[1])
            elif len(fs) == 4:
                for f in fs:
                    parent[find(f)] = find(int(pair_of[(f, k)]))
        roots = {}
        for f in fans:
            roots.setdefault(find(int(f)), []).append(int(f))
        for group in list(roots.values())[1:]:
            new = len(verts) + len(extra)
            extra.append(v)
            for f in group:
                tris[f][tris[f] == v] = new
    if extra:
        verts = np.concatenate([verts, verts[np.asarray(extra)]])
    return verts, tris


def surface_mesh(grid: DexelGrid):
    """The closed, outward-wound column surface of ``grid`` as a ``trimesh.Trimesh``.

    Watertight and consistently wound: saddle corners and columns touching along an edge
    (material of one column ending exactly where the neighbour's begins) get duplicate
    vertices so every edge joins exactly two faces. Known gap: a corner that is both a
    saddle and a touching place (exactly equal ends across three columns, seen only in
    synthetic integer models) can keep an edge of four faces. ``mesh.volume ==
    grid.volume()`` always;
    ``mesh.face_attributes["move_id"]`` holds the face ids. Vertices in world mm.
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
    return write_stl(lambda: surface_mesh(grid), path)


def write_stl(make_mesh, path) -> Path:
    """Write the mesh ``make_mesh()`` gives (a ``trimesh.Trimesh``, mm) as a binary STL at
    ``path``; a missing folder or an empty mesh is an error naming the path (the folder is
    checked before the mesh is made)."""
    path = Path(path)
    if not path.parent.is_dir():
        raise InputError("directory does not exist", where=str(path.parent))
    mesh = make_mesh()
    if len(mesh.faces) == 0:
        raise InputError("the model holds no material; nothing to export", where=str(path))
    mesh.export(str(path), file_type="stl")
    return path
