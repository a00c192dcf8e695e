"""Small cutters the trace tests drive through ``DexelGrid.subtract`` (no cut kernel needed),
and a move table of feeds and arcs for the tests that do use it."""

from __future__ import annotations

import numpy as np

from sim.frame import Frame
from sim.gcode.moves import MoveKind, Plane, empty_moves
from sim.grid import DexelGrid


def box(nx=40, ny=30, spacing=0.5, z0=0.0, z1=10.0) -> DexelGrid:
    frame = Frame.top(0.0, 0.0, (nx - 1) * spacing, (ny - 1) * spacing, spacing)
    return DexelGrid.from_intervals(frame, np.full(frame.shape, z0), np.full(frame.shape, z1))


def ball_cut(grid: DexelGrid, centre, radius: float, move_id: int, top: float = 1e3) -> np.ndarray:
    """Remove a ball (and the shank above it) at ``centre``; return the flat rays touched."""
    f = grid.frame
    cx, cy, cz = centre
    i = np.arange(f.nu)
    j = np.arange(f.nv)
    x = f.origin[0] + i * f.spacing
    y = f.origin[1] + j * f.spacing
    d2 = (x[None, :] - cx) ** 2 + (y[:, None] - cy) ** 2
    jj, ii = np.nonzero(d2 < radius * radius)
    for a, b in zip(ii, jj):
        low = cz - np.sqrt(radius * radius - d2[b, a])
        grid.subtract(int(a), int(b), low, top, move_id)
    return jj * f.nu + ii


def slab_cut(grid: DexelGrid, i0, i1, j0, j1, a, b, move_id: int) -> np.ndarray:
    """Remove ``[a, b]`` from the rays of a window (undercuts, through cuts, cuts from below)."""
    rays = []
    for j in range(j0, j1):
        for i in range(i0, i1):
            grid.subtract(i, j, a, b, move_id)
            rays.append(j * grid.frame.nu + i)
    return np.array(rays, np.int64)


def program(grid: DexelGrid, n_moves: int = 24, seed: int = 1):
    """A mixed sequence of cuts: ball passes (rule 5), undercut slots (rule 2),
    through cuts (rule 3) and cuts from below (rule 4). Yields (stage, rays) after each."""
    rng = np.random.default_rng(seed)
    f = grid.frame
    w, h = (f.nu - 1) * f.spacing, (f.nv - 1) * f.spacing
    for s in range(1, n_moves + 1):
        kind = s % 6
        if kind == 3:
            i0 = int(rng.integers(0, f.nu - 6)); j0 = int(rng.integers(0, f.nv - 6))
            rays = slab_cut(grid, i0, i0 + 5, j0, j0 + 4, 3.0, 4.5, s)       # undercut: splits
        elif kind == 5:
            i0 = int(rng.integers(0, f.nu - 4)); j0 = int(rng.integers(0, f.nv - 4))
            rays = slab_cut(grid, i0, i0 + 3, j0, j0 + 3, -1.0, 1.5, s)      # from below: NearZ
        elif s == 12:
            rays = slab_cut(grid, 2, 5, 2, 5, -1.0, 20.0, s)                  # through: deletes
        else:
            c = (rng.uniform(0, w), rng.uniform(0, h), rng.uniform(6.0, 9.5))
            rays = ball_cut(grid, c, 3.0, s)
        yield s, rays


def feed_moves(rows, arcs=()):
    """Feed moves through ``rows`` ((start, end) tip points); ``arcs``: {row: centre} CCW."""
    mv = empty_moves(len(rows))
    for k, (a, b) in enumerate(rows):
        mv["kind"][k] = MoveKind.FEED
        mv["start"][k, :3] = a
        mv["end"][k, :3] = b
        mv["feed"][k] = 600
        mv["line"][k] = k + 1
    for k, c in dict(arcs).items():
        mv["kind"][k] = MoveKind.ARC_CCW
        mv["center"][k] = c
        mv["plane"][k] = Plane.XY
        mv["turns"][k] = 1
    return mv
