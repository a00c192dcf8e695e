"""The checks on a tri-dexel model (:class:`sim.tridexel.TriDexel`): what the Checker cuts,
probes and assesses when its stock is held by three grids instead of one.

* Cutting and probing (:class:`TriModelCutter`): every move is cut into, and every
  non-cutting body probed against, all three grids. A body meets material when any grid
  says so: the X and Y grids hold the walls parallel to Z that the Z rays step over (a
  thin rib, the side of a slot a tilted tool made), so the holder of a tilted tool that
  passes through such a wall is seen. A move's volume is the Z grid's estimate where
  the Z grid sees it (exact along Z, so the same as a single grid's), else the larger
  of the X and Y grids' (:func:`one_volume`).
* Gouge and undercut (:class:`TriErrorMap`): the design is cast on each grid's frame
  (X and Y only for a closed design: an open sheet is a height field seen along Z) and
  each grid's dexel points get their signed error along their own ray, exactly as on a
  single grid (:class:`sim.checks.error_map.ErrorMap`). The worst point of every ray is
  then placed in its *column* of the lattice (the Z ray through the node nearest to it),
  and the regions are labelled on the columns, so a gouge has one finding (with the
  same fields as a single grid's, its ``ray_box`` in Z-ray indices) whichever grids saw
  it; ``detail["grid"]`` names the grid whose ray held the worst point.

The Z grid stays the model's top view: the depth of cut, the plunge check and the entry
point of a rapid are read from it.
"""

from __future__ import annotations

import math

import numpy as np

from sim.checks.arrays import distinct
from sim.checks.error_map import DesignModel, ErrorMap
from sim.tridexel import AXES, TriCutter, TriDexel


def is_tri(model) -> bool:
    """True for a tri-dexel model (or a cutter / cut result of one)."""
    return isinstance(model, (TriDexel, TriModelCutter, TriCutResult))


def z_part(model):
    """The Z grid of a tri-dexel model, the Z cut of a :class:`TriCutResult`; anything
    else as it is (a single grid, its cut)."""
    if isinstance(model, TriDexel):
        return model.grids["z"]
    if isinstance(model, TriCutResult):
        return model.by_axis["z"]
    return model


def top_bound(model: TriDexel) -> float:
    """Highest material point of the model (world z, mm), -inf when empty: the higher of
    the Z grid's top and the highest lattice row the X and Y grids hold material on (a
    sliver the Z rays step over)."""
    from sim.checks.collisions import max_top

    top = max_top(model.grids["z"])
    for a in ("x", "y"):
        g = model.grids[a]
        held = (g.counts > 0).reshape(g.frame.shape)  # (nv, nu)
        # the x grid's rays run (k, j): z is its v index; the y grid's (i, k): z is its u index
        rows = np.nonzero(held.any(axis=1) if a == "x" else held.any(axis=0))[0]
        if rows.size:
            top = max(top, model.lo[2] + model.spacing * (int(rows[-1]) + 1))
    return top


def one_volume(per_grid: np.ndarray, floor: float) -> np.ndarray:
    """One volume (mm^3, (n,)) from three grids' estimates ``per_grid`` (n, 3) in
    :data:`AXES` order: the Z grid's where it is over ``floor`` mm^3, else the larger of
    the X and Y grids' (a wall the Z rays step over). Over ``floor`` exactly where some
    grid's estimate is."""
    z = per_grid[:, 2]
    return np.where(z > floor, z, np.maximum(per_grid[:, 0], per_grid[:, 1]))


class TriCutResult:
    """What a batch cut did to a tri-dexel model: ``by_axis`` {axis: CutResult};
    ``removed`` float64 (n,) mm^3 per move (:func:`one_volume`)."""

    def __init__(self, by_axis: dict, floor: float):
        self.by_axis = by_axis
        self.removed = one_volume(np.stack([by_axis[a].removed for a in AXES], axis=1), floor)

    @property
    def total_removed(self) -> float:
        return float(self.removed.sum())


class TriModelCutter:
    """A :class:`sim.cut.Cutter` for the checks on a tri-dexel model: the same
    ``cut_moves`` / ``probe_moves`` (with ``body``), acting on all three grids.

    ``grid`` is the :class:`TriDexel` (the Checker's name for the model a cutter cuts);
    ``floor``: volumes (mm^3) at or below it are noise (see :func:`one_volume`).
    """

    def __init__(self, model: TriDexel, tool, tol, tools=None, kinematics=None, origin=None,
                 tool_lengths=None, floor: float = 0.0):
        self.grid = model
        self.floor = float(floor)
        self.tri = TriCutter(model, tool, tol=tol, tools=tools, kinematics=kinematics, origin=origin,
                             tool_lengths=tool_lengths)
        self.kinematics = self.tri.cutters["z"].kinematics

    def cut_moves(self, moves, move_ids=None, record_changes: bool = True, body=None) -> TriCutResult:
        """Cut ``moves`` (or sweep ``body``) into every grid; see ``Cutter.cut_moves``."""
        return TriCutResult({a: c.cut_moves(moves, move_ids, record_changes=record_changes, body=body)
                             for a, c in self.tri.cutters.items()}, self.floor)

    def probe_moves(self, moves, body=None) -> np.ndarray:
        """mm^3 (n,) each move's ``body`` would meet (:func:`one_volume`: over the floor
        where any grid says the body meets material)."""
        return one_volume(self.tri.probe_moves(moves, body), self.floor) if len(moves) else np.zeros(0)

    def probe_where(self, moves, body=None):
        """Where ``body`` would meet material, seen from above: the Z grid's
        ``Cutter.probe_where`` (None where only the X and Y grids see it: a finding's
        position then falls back to its move's end)."""
        return self.tri.cutters["z"].probe_where(moves, body)


# --- the design on the lattice ---------------------------------------------------------------

def tri_designs(model: TriDexel, design) -> dict:
    """{axis: DesignModel} of ``design`` (a :class:`DesignModel` on the Z grid's frame) on
    the grids that can judge it: all three for a closed design, only Z for an open sheet."""
    out = {"z": design}
    if design.closed:
        for a in ("x", "y"):
            out[a] = DesignModel(model.grids[a].frame, design.mesh, offset=design.offset, name=design.name)
    return out


class TriErrorMap:
    """Error maps of a tri-dexel model's grids (one :class:`ErrorMap` each), reported on
    the lattice's columns (see the module docstring).

    ``designs``: {axis: DesignModel} (:func:`tri_designs`); ``lo``, ``spacing``: the lattice.
    """

    def __init__(self, designs: dict, lo, spacing: float):
        self.designs = designs
        self.frame = designs["z"].frame
        self.maps = {a: ErrorMap(d.frame) for a, d in designs.items()}
        self.lo = np.asarray(lo, np.float64)
        self.spacing = float(spacing)
        self.last_worst = math.inf

    def update(self, model: TriDexel, rays: dict, tol, faces: str = "cut", exact_excess: bool = True) -> np.ndarray:
        """Re-assess the flat rays ``rays[axis]`` of each grid (see ``ErrorMap.update``);
        return the columns (Z-frame flat rays, int64) holding the worst point of a ray
        that has one."""
        cols = []
        #: the most negative error of the rays this update assessed (mm), +inf for none
        self.last_worst = math.inf
        for a, m in self.maps.items():
            got = m.update(model.grids[a], self.designs[a], rays[a], tol, faces=faces, exact_excess=exact_excess)
            if got.size:
                cols.append(self.columns(a, got, m.gouge_s[got]))
                self.last_worst = min(self.last_worst, float(np.nanmin(m.gouge[got])))
        return distinct(np.concatenate(cols)) if cols else np.zeros(0, np.int64)

    def update_all(self, model: TriDexel, tol, faces: str = "cut") -> None:
        """Assess every ray of every grid afresh."""
        self.maps = {a: ErrorMap(d.frame) for a, d in self.designs.items()}
        self.update(model, {a: np.arange(d.frame.n_rays) for a, d in self.designs.items()}, tol, faces=faces)

    def columns(self, axis: str, rays: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Column (Z-frame flat ray) of the points at ``s`` (mm along their ray) on the
        flat rays ``rays`` of grid ``axis``: the lattice node nearest to each, seen along Z."""
        f = self.frame
        rays = np.asarray(rays, np.int64)
        if axis == "z":
            return rays
        g = self.maps[axis].frame
        iu = rays % g.nu
        if axis == "x":  # rays (j, k) along X: s is world x
            i = np.rint((np.asarray(s) - self.lo[0]) / self.spacing).astype(np.int64)
            j = iu
        else:  # "y": rays (k, i) along Y: s is world y
            i = rays // g.nu
            j = np.rint((np.asarray(s) - self.lo[1]) / self.spacing).astype(np.int64)
        return np.clip(j, 0, f.nv - 1) * f.nu + np.clip(i, 0, f.nu - 1)

    def _world_z(self, axis: str, rays: np.ndarray, s: np.ndarray) -> np.ndarray:
        """World z (mm) of the points at ``s`` on flat rays ``rays`` of grid ``axis``."""
        if axis == "z":
            return np.asarray(s, np.float64)
        g = self.maps[axis].frame
        k = rays // g.nu if axis == "x" else rays % g.nu
        return self.lo[2] + self.spacing * k

    def combined(self, tol, undercut_limit=None):
        """(ErrorMap on the Z frame, per-column data): every grid's worst points placed in
        their columns, the worst of each column kept (its world z as the ray parameter),
        and per grid the summed length beyond the design of its rays past the tolerance
        in each column (for volumes)."""
        f = self.frame
        out = ErrorMap(f)
        worst_axis = {"gouge": np.full(f.n_rays, -1, np.int8), "excess": np.full(f.n_rays, -1, np.int8)}
        lengths = {kind: {a: np.zeros(f.n_rays) for a in self.maps} for kind in ("gouge", "excess")}
        limit_u = (np.full(f.n_rays, tol.undercut) if undercut_limit is None
                   else np.asarray(undercut_limit, np.float64))
        # material left further than the range of interest is not assessed (ErrorMap.findings):
        # such a point (an X ray's far end in the stock margin) must not hide an undercut
        # another ray put in the same column, so it ranks below every assessed one
        for kind, sign, ceiling in (("gouge", -1.0, math.inf), ("excess", 1.0, tol.interest)):
            dst_val = getattr(out, kind)

            def rank(mag, _ceiling=ceiling):
                return np.where(mag <= _ceiling, mag, -1e300)

            for ai, (a, m) in enumerate(self.maps.items()):
                val = getattr(m, kind)
                rays = np.nonzero(~np.isnan(val))[0]
                if rays.size == 0:
                    continue
                s = getattr(m, f"{kind}_s")[rays]
                cols = self.columns(a, rays, s)
                mag = sign * val[rays]
                ln = getattr(m, f"{kind}_len")[rays]
                limit = tol.gouge if kind == "gouge" else limit_u[cols]
                past = mag > limit
                np.add.at(lengths[kind][a], cols[past], np.where(np.isfinite(ln[past]), ln[past], np.inf))
                # the worst point of each column: the largest magnitude first, one per column
                order = np.lexsort((-mag, -rank(mag), cols))
                first = order[np.r_[True, cols[order][1:] != cols[order][:-1]]]
                c = cols[first]
                cur = sign * dst_val[c]
                better = np.isnan(cur) | (rank(mag[first]) > rank(cur)) | (
                    (rank(mag[first]) == rank(cur)) & (mag[first] > cur))
                c, pick = c[better], rays[first[better]]
                sel = first[better]
                dst_val[c] = val[pick]
                getattr(out, f"{kind}_id")[c] = getattr(m, f"{kind}_id")[pick]
                getattr(out, f"{kind}_s")[c] = self._world_z(a, pick, s[sel])
                getattr(out, f"{kind}_len")[c] = ln[sel]
                worst_axis[kind][c] = ai
        return out, worst_axis, lengths

    def findings(self, tol, move_lines=None, rays=None, undercut: bool = True, min_rays: int = 1,
                 join: float = 0.0, undercut_limit=None, detail_of=None) -> list:
        """Gouge and undercut findings of the whole model, as ``ErrorMap.findings`` (the
        regions on the lattice's columns; ``rays``: columns to report, None for all;
        ``detail_of(kind, members)`` on the lattice's Z columns).
        Volume: the largest of the grids' estimates (each grid's rays past the tolerance
        in the region, their lengths beyond the design times spacing^2)."""
        cmap, worst_axis, lengths = self.combined(tol, undercut_limit)
        names = list(self.maps)
        area = self.spacing ** 2

        def volume_of(kind, members):
            key = "gouge" if kind == "gouge" else "excess"
            sums = [lengths[key][a][members] for a in names]
            fin = [x[np.isfinite(x)] for x in sums]
            best = max((float(x.sum()) for x in fin if x.size), default=math.nan)
            return best * area

        found = cmap.findings(tol, move_lines, rays=rays, undercut=undercut, min_rays=min_rays, join=join,
                              undercut_limit=undercut_limit, volume_of=volume_of, detail_of=detail_of)
        f = self.frame
        out = []
        for x in found:
            key = "gouge" if x.kind == "gouge" else "excess"
            # the worst column: the one the finding's position stands on
            i = int(round((x.position[0] - f.origin[0]) / f.spacing))
            j = int(round((x.position[1] - f.origin[1]) / f.spacing))
            ai = int(worst_axis[key][min(max(j, 0), f.nv - 1) * f.nu + min(max(i, 0), f.nu - 1)])
            if ai >= 0:
                x.detail["grid"] = names[ai]
            out.append(x)
        return out
