"""Milling error against the design (Huang & Oliver 1994, section 3.2).

The design is ray-cast into the stock's frame: every ray keeps its sorted crossings with
the design surface and the triangle (hence the surface normal) of each. A dexel point of
the milled model (a segment face at parameter ``s`` on ray ``r``) gets a signed error:

* sign: negative (gouge) when the point lies inside the design solid, i.e. material was
  removed that belongs to the part; positive (undercut, material left) when outside;
* size: first the distance ``dv`` along the ray to the nearest crossing, times
  ``|n . d|`` of its triangle (Huang's estimate from the ray interval and the design
  normal). The crossing is a surface point, so the true distance never exceeds ``dv``:
  a point whose ``dv`` is within the tolerance of its side (t_l inside, t_h outside) is
  within it for certain and keeps the estimate. Only the others, where the verdict and
  the reported size depend on it, get the exact closest-point distance to the mesh (a
  numba search from the crossing's triangle through triangles binned in the frame plane;
  the same answer as ``trimesh.proximity``).

A closed mesh is a solid by ray parity. An open sheet (like the corpus' carpet1.stl)
is taken as a height field seen along the rays: the design is what lies below its
topmost crossing.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from sim.checks import design_kernels as K
from sim.checks.arrays import distinct
from sim.checks.findings import Finding
from sim.solids import cast_triangles
from sim.errors import InputError
from sim.frame import Frame
from sim.tolerance import DEFAULT, Tolerance

#: RGB colours of the error map (Huang & Oliver Fig. 12)
GREEN = (40, 190, 60)
TOOL_COLOR = (235, 200, 40)  # the paper's yellow tool colour
BLUE_LIGHT = (150, 200, 255)
BLUE_DARK = (10, 40, 170)
RED_LIGHT = (255, 170, 90)
RED_DARK = (170, 0, 0)


def load_mesh(mesh_or_path):
    """A trimesh.Trimesh from a mesh or an STL/OBJ path (InputError naming the file)."""
    import trimesh

    if isinstance(mesh_or_path, trimesh.Trimesh):
        return mesh_or_path
    path = Path(mesh_or_path)
    if not path.is_file():
        raise InputError("design file not found", where=str(path))
    try:
        mesh = trimesh.load(str(path), force="mesh")
    except Exception as exc:  # trimesh raises many kinds; the user needs one line
        raise InputError(f"cannot read a triangle mesh ({exc})", where=str(path)) from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InputError("no triangles in the design file", where=str(path))
    return mesh


class DesignModel:
    """The design surface seen from the rays of a frame.

    Parameters
    ----------
    frame : Frame
        The stock's frame (the design is placed in the same world coordinates).
    mesh_or_path : trimesh.Trimesh or path
        The design part. Closed: a solid by parity. Open: a height field along the rays.
    offset : (3,) mm
        Translation applied to the mesh first (e.g. a work offset).
    require_height_field : bool
        Refuse (InputError naming the file) an open mesh that some ray crosses more than
        once: only an open surface over its footprint has a meaningful "below".

    Attributes
    ----------
    ptr : int64 (n_rays + 1,)
        CSR pointer of each ray's crossings.
    hit_s : float64 (n_hits,)
        Crossing parameters, sorted per ray, mm.
    hit_tri : int32 (n_hits,)
        Triangle of each crossing.
    normals : float64 (n_tri, 3)
        Unit face normals of the mesh (world).
    closed : bool
        Watertight mesh (parity) or open sheet (height field).
    """

    def __init__(self, frame: Frame, mesh_or_path, offset=(0.0, 0.0, 0.0), name: str | None = None,
                 require_height_field: bool = True):
        mesh = load_mesh(mesh_or_path)
        self.require_height_field = require_height_field
        self.name = name or (str(mesh_or_path) if not hasattr(mesh_or_path, "faces") else "design")
        self.frame = frame
        self.mesh = mesh
        self.offset = np.asarray(offset, np.float64).reshape(3).copy()  # the mesh's placement, mm
        self.closed = bool(mesh.is_watertight)
        tri_world = np.asarray(mesh.triangles, np.float64) + np.asarray(offset, np.float64)
        self.normals = np.asarray(mesh.face_normals, np.float64)
        self.tri = np.ascontiguousarray(frame.to_local(tri_world))  # (n, 3, 3) u, v, s
        self.tri_dz = np.abs(self.normals @ frame.direction)  # |n . d| per triangle
        self.tri_lo = self.tri.min(axis=1)
        self.tri_hi = self.tri.max(axis=1)
        self._cast()
        self._bin_cache = None

    # --- ray casting --------------------------------------------------------------
    def _cast(self):
        f = self.frame
        # an open sheet keeps the rays on its outer edges (inclusive); ties on a closed
        # mesh go to the triangle on the +u side (the ray nudged by (+eps, -eps^2)), so a
        # part whose wall stands on the first ray column, like the corpus parts at X0,
        # keeps that column
        offsets, counts, hit_s, hit_tri = cast_triangles(self.tri, f.nu, f.nv, f.spacing,
                                                         inclusive=not self.closed, nudge_u=1.0)
        ptr = np.append(offsets, hit_s.size)
        if not self.closed:
            # height field: keep the topmost crossing of each ray (duplicates at shared
            # edges of an open sheet collapse into it)
            has = counts > 0
            top_k = ptr[1:] - 1
            spread = np.zeros(f.n_rays)
            spread[has] = hit_s[top_k[has]] - hit_s[ptr[:-1][has]]
            if self.require_height_field and spread.size and spread.max() > 1e-4:
                r = int(np.argmax(spread))
                x, y, _ = f.to_world(np.array([(r % f.nu) * f.spacing, (r // f.nu) * f.spacing, 0.0]))
                raise InputError(
                    "the design is an open surface (not watertight) but not a height field: the ray "
                    f"at X{x:.3f} Y{y:.3f} crosses it {int(counts[r])} times ({spread[r]:.3f} mm apart); "
                    "give a closed solid, or an open surface that each vertical ray crosses once",
                    where=self.name)
            new_ptr = np.zeros_like(ptr)
            np.cumsum(has, out=new_ptr[1:])
            hit_s = hit_s[top_k[has]]
            hit_tri = hit_tri[top_k[has]]
            ptr = new_ptr
        self.ptr, self.hit_s, self.hit_tri = ptr, hit_s, hit_tri

    def top(self) -> np.ndarray:
        """Highest design crossing of every ray, float64 (nv, nu) mm; NaN where none."""
        out = np.full(self.frame.n_rays, np.nan)
        has = self.ptr[1:] > self.ptr[:-1]
        out[has] = self.hit_s[self.ptr[1:][has] - 1]
        return out.reshape(self.frame.shape)

    def inside(self, rays: np.ndarray, s: np.ndarray) -> np.ndarray:
        """bool (n,): is the point at ``s`` on flat ray ``rays`` inside the design?"""
        dv, nz, ins, tri = self.vertical(rays, s)
        return ins

    def vertical(self, rays, s):
        """Per point: (dv mm, |n.d|, inside bool, triangle int32) of the nearest crossing
        along its ray (see :func:`design_kernels.vertical_errors`)."""
        rays = np.ascontiguousarray(rays, np.int64)
        s = np.ascontiguousarray(s, np.float64)
        n = rays.size
        dv = np.empty(n)
        nz = np.empty(n)
        ins = np.empty(n, np.bool_)
        tri = np.empty(n, np.int32)
        K.vertical_errors(rays, s, self.ptr, self.hit_s, self.hit_tri, self.tri_dz,
                          not self.closed, dv, nz, ins, tri)
        return dv, nz, ins, tri

    # --- exact near-point distance ----------------------------------------------------
    def _binned(self):
        """Triangles binned in the frame plane (built once): ``(bin_size, nbu, nbv, ptr,
        items)``. Bin size after Huang & Oliver eq. 6, ``B_max / sqrt(N)`` (N triangles,
        B_max the larger frame extent), but at least one ray spacing."""
        if self._bin_cache is not None:
            return self._bin_cache
        f = self.frame
        ext_u = (f.nu - 1) * f.spacing
        ext_v = (f.nv - 1) * f.spacing
        n_tri = max(self.tri.shape[0], 1)
        bin_size = max(max(ext_u, ext_v) / math.sqrt(n_tri), f.spacing, max(ext_u, ext_v) / 2048.0, 1e-3)
        nbu = int(ext_u // bin_size) + 1
        nbv = int(ext_v // bin_size) + 1
        counts = np.zeros(nbu * nbv, np.int64)
        K.bin_triangles(self.tri, bin_size, nbu, nbv, True, counts, counts, np.zeros(0, np.int32))
        ptr = np.zeros(nbu * nbv + 1, np.int64)
        np.cumsum(counts, out=ptr[1:])
        items = np.empty(ptr[-1], np.int32)
        counts[:] = 0
        K.bin_triangles(self.tri, bin_size, nbu, nbv, False, counts, ptr, items)
        self._bin_cache = (bin_size, nbu, nbv, ptr, items)
        return self._bin_cache

    def distance(self, local_pts: np.ndarray, radius, seed=None) -> np.ndarray:
        """Exact distance (n,) mm from points in frame-local (u, v, s) coords (n, 3) to the
        design surface, searched within ``radius`` mm (scalar or (n,)); inf beyond it.
        ``seed``: int (n,) a triangle likely to be nearest, tried first (-1 for none)."""
        pts = np.ascontiguousarray(local_pts, np.float64).reshape(-1, 3)
        n = pts.shape[0]
        radius = np.broadcast_to(np.asarray(radius, np.float64), (n,)).copy()
        seed = (np.full(n, -1, np.int32) if seed is None
                else np.ascontiguousarray(np.broadcast_to(seed, (n,)), np.int32))
        bin_size, nbu, nbv, bptr, bitems = self._binned()
        out = np.empty(n)
        K.near_distances(pts, radius, seed, self.tri, self.tri_lo, self.tri_hi, bin_size, nbu, nbv,
                         bptr, bitems, out)
        return out

    # --- the error ------------------------------------------------------------------
    def errors(self, rays, s, tol: Tolerance = DEFAULT, refine_fraction: float = 1.0,
               search: float | None = None, with_dv: bool = False, exact_outside: bool = True):
        """Signed error of dexel points ``(rays[q], s[q])``: float64 (n,) mm.

        Positive = material left (undercut), negative = gouge. Huang's estimate ``dv
        |n . d|`` is replaced by the exact near-point distance where the verdict depends
        on it: points inside the design whose ``dv`` (distance along the ray to the
        surface, never less than the true distance) exceeds ``refine_fraction * t_l``,
        and points outside it whose ``dv`` exceeds ``refine_fraction * t_h``. The exact
        distance is searched within ``search`` mm (default 1.5 x the range of interest);
        points with nothing that close keep ``dv``. Points on rays that miss the design
        get ``+inf`` (outside: material where the part has none).

        ``with_dv``: also return ``dv`` (float64 (n,) mm; inf where the ray misses).

        ``exact_outside=False``: points outside the design all keep the estimate (only the
        gouge side is refined), for callers that judge gouges only: the sign, and every
        error inside the design, are the same; the search on the material-left side is
        most of the cost when the cut surface lies just above the design.
        """
        rays = np.ascontiguousarray(rays, np.int64)
        s = np.ascontiguousarray(s, np.float64)
        search = 1.5 * tol.interest if search is None else float(search)
        bin_size, nbu, nbv, bptr, bitems = self._binned()
        err = np.empty(rays.size)
        dv = np.empty(rays.size)
        f = self.frame
        K.point_errors(rays, s, f.nu, f.spacing, self.ptr, self.hit_s, self.hit_tri, self.tri_dz,
                       not self.closed, refine_fraction * tol.gouge,
                       refine_fraction * tol.undercut if exact_outside else np.inf, search, self.tri, self.tri_lo, self.tri_hi, bin_size, nbu, nbv, bptr, bitems,
                       err, dv)
        return (err, dv) if with_dv else err


# --- colours ------------------------------------------------------------------------

def _lerp(c0, c1, t):
    c0 = np.asarray(c0, np.float64)
    c1 = np.asarray(c1, np.float64)
    return c0 + (c1 - c0) * t[..., None]


def error_colors(errors, tol: Tolerance = DEFAULT, tool_color=TOOL_COLOR, nan_color=None) -> np.ndarray:
    """RGB uint8 (..., 3) for signed errors (..., ) mm (Huang & Oliver Fig. 12).

    * ``-t_l <= e <= t_h``: green;
    * ``t_h < e <= interest``: blues, light at ``t_h`` to dark at the range of interest;
    * ``-interest <= e < -t_l``: reds, light at ``-t_l`` to dark at ``-interest``; deeper
      gouges keep the darkest red (a gouge never disappears from the map);
    * ``e > interest`` (undercut beyond the range of interest): the tool colour;
    * NaN (not assessed): ``nan_color`` (default the tool colour).
    """
    e = np.asarray(errors, np.float64)
    out = np.empty(e.shape + (3,), np.float64)
    out[...] = tool_color
    span_u = max(tol.interest - tol.undercut, 1e-12)
    span_g = max(tol.interest - tol.gouge, 1e-12)
    ok = (e >= -tol.gouge) & (e <= tol.undercut)
    out[ok] = GREEN
    und = (e > tol.undercut) & (e <= tol.interest)
    out[und] = _lerp(BLUE_LIGHT, BLUE_DARK, (e[und] - tol.undercut) / span_u)
    gou = e < -tol.gouge
    t = np.clip((-e[gou] - tol.gouge) / span_g, 0.0, 1.0)
    out[gou] = _lerp(RED_LIGHT, RED_DARK, t)
    out[np.isnan(e)] = tool_color if nan_color is None else nan_color
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


# --- per-ray error map and findings ---------------------------------------------------

class ErrorMap:
    """Per-ray worst errors of a milled model against a :class:`DesignModel`.

    ``gouge[j, i]`` is the most negative error of the ray's assessed points (NaN when
    none), ``excess[j, i]`` the most positive; ``gouge_id``/``excess_id`` the face id (move
    id) of those points, ``gouge_s``/``excess_s`` their ray parameter. ``gouge_len`` and
    ``excess_len`` hold, per ray, the distance along the ray from the worst point to the
    design surface (mm), used for volumes.
    """

    def __init__(self, frame: Frame):
        self.frame = frame
        shape = frame.n_rays
        self.gouge = np.full(shape, np.nan)
        self.excess = np.full(shape, np.nan)
        self.gouge_id = np.zeros(shape, np.int32)
        self.excess_id = np.zeros(shape, np.int32)
        self.gouge_s = np.zeros(shape)
        self.excess_s = np.zeros(shape)
        self.gouge_len = np.zeros(shape)
        self.excess_len = np.zeros(shape)

    def worst(self) -> np.ndarray:
        """Signed error of largest magnitude per ray, float64 (nv, nu) (for colouring)."""
        g = np.where(np.isnan(self.gouge), 0.0, self.gouge)
        x = np.where(np.isnan(self.excess), 0.0, self.excess)
        out = np.where(-g > x, g, x)
        out[np.isnan(self.gouge) & np.isnan(self.excess)] = np.nan
        return out.reshape(self.frame.shape)

    def update(self, grid, design: DesignModel, rays, tol: Tolerance, faces: str = "cut",
               design_rays=None, exact_excess: bool = True) -> np.ndarray:
        """Re-assess every dexel point of the given flat rays of ``grid``; return the rays
        (int64) that have an assessed point. ``faces="cut"`` assesses only faces a move
        made (id != 0, Huang's "updated dexels"); ``"all"`` every face.

        ``design_rays``: a function mapping ``grid`` ray indices to the design's (when
        ``grid`` is a window of the design's frame, as in look-ahead).

        ``exact_excess=False``: the material-left side keeps Huang's estimate
        (:meth:`DesignModel.errors` ``exact_outside``): ``gouge`` and the gouge findings
        are the same, ``excess`` is not exact (for a map that reports
        gouges only, like the one :meth:`Checker.cut_and_check` keeps)."""
        rays = distinct(np.asarray(rays, np.int64))
        if rays.size == 0:
            return rays
        dr = rays if design_rays is None else np.ascontiguousarray(design_rays(rays), np.int64)
        d, f = design, design.frame
        bin_size, nbu, nbv, bptr, bitems = d._binned()
        # one compiled pass: the rays' faces gathered, assessed and reduced per ray
        K.update_rays(grid.S, rays, dr, faces == "cut", f.nu, f.spacing, d.ptr, d.hit_s, d.hit_tri, d.tri_dz,
                      not d.closed, tol.gouge, tol.undercut if exact_excess else np.inf, 1.5 * tol.interest,
                      d.tri, d.tri_lo, d.tri_hi, bin_size, nbu, nbv, bptr, bitems, self.gouge, self.gouge_id,
                      self.gouge_s, self.gouge_len, self.excess, self.excess_id, self.excess_s, self.excess_len)
        return rays[~np.isnan(self.gouge[rays])]

    def findings(self, tol: Tolerance, move_lines=None, rays=None, undercut: bool = True,
                 min_rays: int = 1, join: float = 0.0, undercut_limit=None, volume_of=None,
                 detail_of=None) -> list[Finding]:
        """Gouge and undercut findings: one per region of rays whose worst point is past
        the tolerance (restricted to ``rays`` when given); rays closer than ``join`` mm
        (the tool radius: one cause, like the strips one too-deep raster leaves under its
        passes) are one region, else 8-connected ones. Undercut counts only within the
        range of interest (``t_h < e <= tol.interest``): material left further from the
        design (a stock margin around a smaller part, stock no pass came near) is not
        assessed, as in Huang & Oliver's error map. ``undercut_limit``: per-ray t_h
        (float64 (n_rays,) mm, e.g. the path's scallop, :mod:`.scallop`) instead of
        ``tol.undercut``.

        ``move_lines``: int array indexed by move id giving its program line (0 = stock).
        Line: the first move's line (where the region starts); worst_line: the worst
        point's. Depth: the largest error magnitude (mm). Area: rays x spacing^2
        (projected along the rays, mm^2). Volume: sum over the region's rays of the length
        along the ray beyond the design surface x spacing^2 (mm^3). Position: the worst
        point (world). Regions of fewer than ``min_rays`` rays are dropped.
        ``volume_of(kind, members)``: the volume of a region of flat rays ``members``
        (mm^3), instead of the sum above (a tri-dexel model's map, :mod:`.tri`).
        ``detail_of(kind, members)``: more of the finding's ``detail`` (a dict) for a region,
        e.g. how much of an undercut its tool cannot reach (:mod:`.reach`).
        """
        f = self.frame
        out: list[Finding] = []
        sel = None
        if rays is not None:
            sel = np.zeros(f.n_rays, bool)
            sel[np.asarray(rays, np.int64)] = True
        kinds = [("gouge", -self.gouge, self.gouge_id, self.gouge_s, self.gouge_len, tol.gouge, np.inf)]
        if undercut:
            # material left beyond the range of interest is not assessed (Huang & Oliver:
            # shown in the tool colour): stock margins outside the design's footprint, or
            # stock no pass came near, are not undercuts of the part
            limit = tol.undercut if undercut_limit is None else np.asarray(undercut_limit, np.float64)
            kinds.append(("undercut", self.excess, self.excess_id, self.excess_s, self.excess_len, limit,
                          tol.interest))
        for kind, mag, ids, ss, lens, limit, ceiling in kinds:
            m_all = np.nan_to_num(mag, nan=-1.0)
            bad = (m_all > limit) & (m_all <= ceiling)
            if sel is not None:
                bad &= sel
            if not bad.any():
                continue
            labels, n = _regions(bad.reshape(f.shape), join / f.spacing)
            labels = labels.reshape(-1)
            idx = np.nonzero(labels)[0]
            lab = labels[idx]
            o = np.argsort(lab, kind="stable")
            idx, lab = idx[o], lab[o]
            starts = np.searchsorted(lab, np.arange(1, n + 1))
            ends = np.append(starts[1:], idx.size)
            for a, b in zip(starts, ends):
                members = idx[a:b]
                if members.size < min_rays:
                    continue
                m = np.nan_to_num(mag[members], nan=-1.0, posinf=np.finfo(float).max)
                w = members[int(np.argmax(m))]
                i, j = w % f.nu, w // f.nu
                pos = f.to_world(np.array([i * f.spacing, j * f.spacing, ss[w]]))
                mids = distinct(ids[members])
                lines = ()
                line = worst_line = 0
                if move_lines is not None:
                    ml = np.asarray(move_lines)
                    ok = (mids > 0) & (mids < ml.size)
                    lines = tuple(int(x) for x in distinct(ml[mids[ok]]) if x > 0)
                    if 0 <= ids[w] < ml.size:
                        worst_line = int(ml[ids[w]])
                    made = ml[mids[ok]]
                    if (made > 0).any():  # the first move that made the region
                        line = int(made[made > 0][0])
                    line = line or worst_line
                depth = float(mag[w])
                if not math.isfinite(depth):
                    depth = float(lens[w])
                # rays where the design has no material at all measure no finite length:
                # they are counted, not summed (an infinite size helps nobody)
                ml_len = np.asarray(lens[members], np.float64)
                fin = np.isfinite(ml_len)
                if not math.isfinite(depth):
                    fm = np.where(np.isfinite(mag[members]), mag[members], -np.inf)
                    depth = float(fm.max()) if np.isfinite(fm).any() else math.nan
                mi, mj = members % f.nu, members // f.nu
                # the region's ray box: hits of later batches merge with it only when they
                # are next to it (see findings._touch), never just for being consecutive
                lo = f.to_world(np.array([mi.min() * f.spacing, mj.min() * f.spacing, 0.0]))
                hi = f.to_world(np.array([mi.max() * f.spacing, mj.max() * f.spacing, 0.0]))
                detail = {"rays": int(members.size),
                          "ray_box": (int(mi.min()), int(mj.min()), int(mi.max()), int(mj.max())),
                          # the region's XY box (world mm): frames of look-ahead windows differ
                          "box": tuple(round(float(v), 4) for v in (min(lo[0], hi[0]), min(lo[1], hi[1]),
                                                                   max(lo[0], hi[0]), max(lo[1], hi[1])))}
                if not fin.all():
                    detail["rays_outside_design"] = int((~fin).sum())
                volume = float(ml_len[fin].sum()) * f.spacing**2 if fin.any() else math.nan
                if volume_of is not None:
                    volume = volume_of(kind, members)
                if detail_of is not None:
                    detail.update(detail_of(kind, members))
                out.append(Finding(
                    kind=kind, line=line, worst_line=worst_line, lines=lines, stage=int(ids[w]), position=tuple(pos),
                    depth=depth,
                    area=members.size * f.spacing**2,
                    volume=volume,
                    stages=tuple(int(x) for x in mids if x > 0),
                    detail=detail,
                ))
        return out


def _regions(bad: np.ndarray, join_rays: float):
    """``(labels int (nv, nu), count)`` of the regions of ``bad``: 8-connected, and
    joined where they come within ``join_rays`` ray spacings of each other (each grown by
    half of it, on the crop around them)."""
    from scipy import ndimage

    eight = np.ones((3, 3), bool)
    if join_rays <= 1.0:
        return ndimage.label(bad, structure=eight)
    jj, ii = np.nonzero(bad)
    pad = int(math.ceil(join_rays)) + 1
    j0, j1 = max(jj.min() - pad, 0), min(jj.max() + pad + 1, bad.shape[0])
    i0, i1 = max(ii.min() - pad, 0), min(ii.max() + pad + 1, bad.shape[1])
    crop = bad[j0:j1, i0:i1]
    grown = ndimage.distance_transform_edt(~crop) <= 0.5 * join_rays
    lab, n = ndimage.label(grown, structure=eight)
    lab[~crop] = 0
    # renumber 1..m in the order of the labels still present
    present = np.unique(lab[lab > 0])
    remap = np.zeros(n + 1, np.int64)
    remap[present] = np.arange(1, present.size + 1)
    out = np.zeros(bad.shape, np.int64)
    out[j0:j1, i0:i1] = remap[lab]
    return out, int(present.size)
