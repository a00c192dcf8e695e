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

from sim.errors import InputError
from sim.frame import Frame

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


class TriCutter:
    """Cuts a :class:`TriDexel` with one :class:`sim.cut.Cutter` per grid.

    The arguments are :class:`sim.cut.Cutter`'s. The Z grid takes the exact sweep
    where the Cutter has one; the X and Y grids are swept by instances of motion.
    """

    def __init__(self, model: TriDexel, tool, tol=None, tools=None, threads: int | None = None,
                 kinematics=None, origin=None):
        from sim.cut import Cutter
        from sim.tolerance import DEFAULT

        self.model = model
        self.cutters = {a: Cutter(g, tool, tol or DEFAULT, tools=tools, threads=threads,
                                  kinematics=kinematics, origin=origin)
                        for a, g in model.grids.items()}

    def cut_moves(self, moves: np.ndarray, move_ids=None, record_changes: bool = False) -> dict:
        """Cut every row of ``moves`` into all three grids; ``{axis: CutResult}``."""
        return {a: c.cut_moves(moves, move_ids, record_changes=record_changes)
                for a, c in self.cutters.items()}

    def cut_poses(self, tips, axes, move_id: int, body=None) -> dict[str, float]:
        """Cut the tool (or ``body``) standing at each pose (tips, axes (n, 3) world);
        ``{axis: mm^3 removed}`` (three estimates of one volume)."""
        return {a: c.cut_poses(tips, axes, move_id, body) for a, c in self.cutters.items()}

    def probe_moves(self, moves: np.ndarray, body=None) -> np.ndarray:
        """Material (mm^3) each move's swept body would meet, float64 (n, 3): one column
        per grid in :data:`AXES` order; a body meets material where any column is > 0."""
        return np.stack([self.cutters[a].probe_moves(moves, body) for a in AXES], axis=1)
