"""Tri-dexel models: one solid held by three dexel grids whose rays run along X, Y and Z.

A single dexel direction holds only the faces it crosses: a wall parallel to the rays
(the side of a slot cut by a tilted tool, a groove round a bar on the A axis) is seen
only as the jump between two neighbouring rays. Three orthogonal grids of the same
lattice hold every face to within the spacing, whatever way the tool stood (Huang &
Oliver's view-independent dexels, made orthogonal).

The lattice: nodes ``lo + spacing * (i, j, k)``, ``0 <= i < nx``, ``0 <= j < ny``,
``0 <= k < nz``. Each grid's rays pass through the nodes (the frames are cyclic
permutations of X Y Z, all right-handed):

==== ========= ====== ====== ============ =============== ===============
grid direction u      v      ray (iu, iv) per-ray arrays  s (ray param.)
==== ========= ====== ====== ============ =============== ===============
z    +Z        +X     +Y     (i, j)       (ny, nx)        world z
x    +X        +Y     +Z     (j, k)       (nz, ny)        world x
y    +Y        +Z     +X     (k, i)       (nx, nz)        world y
==== ========= ====== ====== ============ =============== ===============

So a node's occupancy can be read from any of the three rays through it, and the
crossings of the solid's surface with the lattice's edges are the dexels' segment ends.
"""

from __future__ import annotations

import numpy as np

from sim import bands
from sim.errors import InputError
from sim.frame import Frame
from sim.solids import box_grid, check_closed, cylinder_grid, load_mesh, mesh_grid
from sim.tolerance import DEFAULT, Tolerance

#: the grids of a tri-dexel model, in the order they are stored and cut
AXES = ("x", "y", "z")


def lattice_shape(lo, hi, spacing: float) -> tuple[int, int, int]:
    """(nx, ny, nz): nodes each way covering ``[lo, hi]`` (mm 3-vectors), both ends included."""
    lo = np.asarray(lo, np.float64).reshape(3)
    hi = np.asarray(hi, np.float64).reshape(3)
    if not (np.isfinite(spacing) and spacing > 0):
        raise InputError(f"tri-dexel spacing must be a positive length in mm, got {spacing}")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi >= lo)):
        raise InputError(f"tri-dexel extent needs lo <= hi on every axis, got lo {lo.tolist()} hi {hi.tolist()}")
    n = np.rint((hi - lo) / spacing).astype(np.int64) + 1
    return int(n[0]), int(n[1]), int(n[2])


def tridexel_frames(lo, spacing: float, shape: tuple[int, int, int]) -> dict[str, Frame]:
    """The three frames of the lattice with first node ``lo`` (mm) and ``shape`` (nx, ny, nz).

    Returns ``{"x": Frame, "y": Frame, "z": Frame}`` laid out as in the module's table:
    each frame's origin is the first node with its own direction's coordinate set to 0, so
    a ray parameter ``s`` is the world coordinate along that direction.
    """
    lo = np.asarray(lo, np.float64).reshape(3)
    nx, ny, nz = (int(n) for n in shape)
    ex, ey, ez = np.eye(3)
    return {
        "z": Frame(np.array([lo[0], lo[1], 0.0]), ez, ex, spacing, nx, ny),
        "x": Frame(np.array([0.0, lo[1], lo[2]]), ex, ey, spacing, ny, nz),
        "y": Frame(np.array([lo[0], 0.0, lo[2]]), ey, ez, spacing, nz, nx),
    }


class TriDexel:
    """One solid on the three grids of a lattice (see the module docstring).

    grids: ``{"x": DexelGrid, "y": DexelGrid, "z": DexelGrid}`` on the frames of
    :func:`tridexel_frames` (``lo``, ``spacing``, ``shape``). Cutting and probing act on
    all three; each grid keeps its own face ids (the move that made the face).
    """

    def __init__(self, grids: dict, lo, spacing: float, shape: tuple[int, int, int]):
        frames = tridexel_frames(lo, spacing, shape)
        if set(grids) != set(AXES):
            raise InputError(f"a tri-dexel model needs grids {AXES}, got {sorted(grids)}")
        for a in AXES:
            if not grids[a].frame.same_rays(frames[a]):
                raise InputError(f"tri-dexel grid {a!r} is not on the lattice's {a} frame")
        self.grids = {a: grids[a] for a in AXES}
        self.lo = np.asarray(lo, np.float64).reshape(3)
        self.spacing = float(spacing)
        self.shape = tuple(int(n) for n in shape)

    # --- construction ------------------------------------------------------------------
    @classmethod
    def build(cls, lo, hi, spacing: float, make_grid) -> "TriDexel":
        """The lattice covering ``[lo, hi]`` with each grid from ``make_grid(frame)``
        (e.g. ``lambda f: box_grid(f, lo, hi)``)."""
        shape = lattice_shape(lo, hi, spacing)
        frames = tridexel_frames(lo, spacing, shape)
        return cls({a: make_grid(frames[a]) for a in AXES}, lo, spacing, shape)

    @classmethod
    def box(cls, lo, hi, spacing: float, margin: float | None = None, face_id: int = 0,
            tol: Tolerance = DEFAULT) -> "TriDexel":
        """The box stock ``[lo, hi]`` (mm 3-vectors) on a lattice whose nodes lie half a
        spacing inside ``lo`` (no ray runs on a face: every face crosses rays, and the
        three grids' volumes are the box's when its sides are whole spacings), with at
        least ``margin`` (mm, default one spacing) of empty lattice round it."""
        lo = np.asarray(lo, np.float64).reshape(3)
        hi = np.asarray(hi, np.float64).reshape(3)
        a, b = stock_lattice(lo, hi, spacing, margin)
        return cls.build(a, b, spacing, lambda f: box_grid(f, lo, hi, face_id, tol))

    @classmethod
    def cylinder(cls, x0: float, x1: float, radius: float, spacing: float, center=(0.0, 0.0),
                 margin: float | None = None, face_id: int = 0, tol: Tolerance = DEFAULT) -> "TriDexel":
        """Stock of revolution on the A axis: the cylinder of ``radius`` (mm) along X from
        ``x0`` to ``x1`` whose axis passes through (Y, Z) = ``center``. The lattice has a
        row of nodes on the axis (rays at whole spacings from it), nodes half a spacing
        inside ``x0`` (no ray on an end face), and at least ``margin`` (default one
        spacing) of empty lattice round the cylinder."""
        if not (np.isfinite(radius) and radius > 0 and np.isfinite(x0) and np.isfinite(x1) and x1 > x0):
            raise InputError(f"cylinder stock needs radius > 0 and x0 < x1 (mm), got radius {radius}, "
                             f"x {x0}..{x1}")
        cy, cz = (float(c) for c in center)
        base = np.array([x0, cy, cz])
        a, b = lattice_around(base - [0.0, radius, radius], np.array([x1, cy + radius, cz + radius]),
                               base + [0.5 * spacing, 0.0, 0.0], spacing, margin)
        return cls.build(a, b, spacing, lambda f: cylinder_grid(f, base, (1.0, 0.0, 0.0), radius,
                                                               x1 - x0, face_id, tol))

    @classmethod
    def mesh(cls, mesh_or_path, spacing: float, margin: float | None = None, face_id: int = 0,
             tol: Tolerance = DEFAULT) -> "TriDexel":
        """The solid a closed triangle mesh bounds (a ``trimesh.Trimesh`` or an STL/OBJ
        path, mm), cast on each grid by :func:`sim.solids.mesh_grid`; the lattice's nodes lie
        half a spacing inside the mesh's lowest corner, with ``margin`` (default one
        spacing) round its bounds."""
        mesh, name = load_mesh(mesh_or_path)
        check_closed(mesh, name)
        lo, hi = (np.asarray(c, np.float64) for c in mesh.bounds)
        a, b = stock_lattice(lo, hi, spacing, margin)
        return cls.build(a, b, spacing, lambda f: mesh_grid(f, mesh, face_id, tol))

    @property
    def hi(self) -> np.ndarray:
        """The last node (mm)."""
        return self.lo + self.spacing * (np.array(self.shape) - 1)

    def copy(self) -> "TriDexel":
        return TriDexel({a: g.copy() for a, g in self.grids.items()}, self.lo, self.spacing, self.shape)

    def nbytes(self) -> int:
        return sum(g.nbytes() for g in self.grids.values())

    def volumes(self) -> dict[str, float]:
        """Each grid's material volume, mm^3 (trapezoid rule): three estimates of one solid."""
        return {a: g.volume("trapezoid") for a, g in self.grids.items()}


def stock_lattice(lo, hi, spacing: float, margin: float | None = None,
                  cover=None) -> tuple[np.ndarray, np.ndarray]:
    """(first, last) node (mm) of the lattice of a stock whose box is ``[lo, hi]`` (mm
    3-vectors): nodes half a spacing inside ``lo``, so no ray runs on a face of the box
    (a tool touching a face cuts no ray); it covers the box grown by ``margin`` (mm,
    default one spacing) and ``cover`` ((lo, hi) mm 3-vectors: e.g. a job's frame) when given."""
    lo = np.asarray(lo, np.float64).reshape(3)
    hi = np.asarray(hi, np.float64).reshape(3)
    a, b = lattice_around(lo, hi, lo + 0.5 * spacing, spacing, margin)
    if cover is not None:
        c0, c1 = (np.asarray(c, np.float64).reshape(3) for c in cover)
        c0, c1 = lattice_around(c0, c1, a, spacing, 0.0)
        a, b = np.minimum(a, c0), np.maximum(b, c1)
    return a, b


def lattice_around(lo: np.ndarray, hi: np.ndarray, anchor: np.ndarray, spacing: float,
                   margin: float | None) -> tuple[np.ndarray, np.ndarray]:
    """(first, last) node (mm) of the lattice that has a node at ``anchor`` and covers
    ``[lo, hi]`` grown by ``margin`` (default one spacing) on every side."""
    if not (np.isfinite(spacing) and spacing > 0):
        raise InputError(f"tri-dexel spacing must be a positive length in mm, got {spacing}")
    m = spacing if margin is None else float(margin)
    if not (np.isfinite(m) and m >= 0):
        raise InputError(f"tri-dexel margin must be a length >= 0 in mm, got {margin}")
    below = np.ceil((anchor - lo + m) / spacing - 1e-9)
    above = np.ceil((hi - anchor + m) / spacing - 1e-9)
    return anchor - below * spacing, anchor + above * spacing


#: the threads the three grids are cut on at once (a pool of its own: a grid's Cutter may
#: hand bands to :data:`sim.bands.BAND_POOL`, and waiting on a pool from its own threads
#: can deadlock)
_GRID_POOL = bands.ThreadPool("dexmon-tri")


class TriCutter:
    """Cuts a :class:`TriDexel` with one :class:`sim.cut.Cutter` per grid.

    The arguments are :class:`sim.cut.Cutter`'s. The Z grid takes the exact sweep
    where the Cutter has one; the X and Y grids are swept by instances of motion in
    their frames' coordinates. threads (default :func:`sim.bands.default_threads`):
    each grid's Cutter cuts a large batch on bands of rows on that many threads, the
    grids one after the other. grids_at_once: instead cut the three grids at the same
    time, one thread each (the kernels release the GIL). Bands are the default because
    one grid (the one whose rays cross the feed) takes most of the time and bands split
    it evenly; on the shared 2-core machine the two measured alike or bands ahead
    (``bench/tridexel_bench.py``: ``threads_gain``, ``grids_at_once_gain``). Either
    way every grid ends bit for bit as a Cutter of its own leaves it.
    """

    def __init__(self, model: TriDexel, tool, tol=None, tools=None, threads: int | None = None,
                 kinematics=None, origin=None, grids_at_once: bool = False, tool_lengths=None):
        from sim.cut import Cutter

        self.model = model
        self.threads = bands.default_threads() if threads is None else max(1, int(threads))
        self.grids_at_once = bool(grids_at_once) and self.threads > 1
        per_grid = 1 if self.grids_at_once else self.threads
        self.cutters = {a: Cutter(g, tool, tol or DEFAULT, tools=tools, threads=per_grid,
                                  kinematics=kinematics, origin=origin, tool_lengths=tool_lengths)
                        for a, g in model.grids.items()}

    def _each(self, call) -> dict:
        """``{axis: call(cutter)}`` over the three grids (at the same time with
        ``grids_at_once``: the instance-swept X and Y grids first, they take longest)."""
        if not self.grids_at_once:
            return {a: call(self.cutters[a]) for a in AXES}
        order = sorted(AXES, key=lambda a: self.cutters[a]._top)
        futures = {a: _GRID_POOL.get(len(AXES)).submit(call, self.cutters[a]) for a in order}
        return {a: futures[a].result() for a in AXES}

    def cut_moves(self, moves: np.ndarray, move_ids=None, record_changes: bool = False) -> dict:
        """Cut every row of ``moves`` into all three grids; ``{axis: CutResult}``."""
        return self._each(lambda c: c.cut_moves(moves, move_ids, record_changes=record_changes))

    def cut_poses(self, tips, axes, move_id: int, body=None) -> dict[str, float]:
        """Cut the tool (or ``body``) standing at each pose (tips, axes (n, 3) world);
        ``{axis: mm^3 removed}`` (three estimates of one volume)."""
        return self._each(lambda c: c.cut_poses(tips, axes, move_id, body))

    def probe_moves(self, moves: np.ndarray, body=None) -> np.ndarray:
        """Material (mm^3) each move's swept body would meet, float64 (n, 3): one column
        per grid in :data:`AXES` order; a body meets material where any column is > 0."""
        got = self._each(lambda c: c.probe_moves(moves, body))
        return np.stack([got[a] for a in AXES], axis=1)
