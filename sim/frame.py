"""The frame of a dexel grid (Huang & Oliver eq. 1): where its rays are and where they point."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from sim.errors import InputError


def _unit(v, name: str) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(v))
    if not np.isfinite(n) or n == 0.0:
        raise InputError(f"{name} must be a non-zero 3-vector, got {v.tolist()}")
    return v / n


@dataclass(frozen=True)
class Frame:
    """A rectangular array of parallel rays.

    Ray ``(i, j)``, ``0 <= i < nu``, ``0 <= j < nv``, is the line
    ``origin + i*spacing*u + j*spacing*v + s*direction``; a point on it is named by its
    parameter ``s`` (mm along ``direction`` from the plane through ``origin``).
    ``v = direction x u``. Per-ray arrays have shape ``(nv, nu)`` and are indexed
    ``[j, i]``; the flat ray index is ``j*nu + i``.

    For the usual top view (``Frame.top``) direction is +Z, u is +X, v is +Y, the origin
    lies at z = 0, so ``s`` is the machine Z of a point and ``[j, i]`` is the ray at
    ``X = x0 + i*spacing, Y = y0 + j*spacing``.
    """

    origin: np.ndarray
    direction: np.ndarray
    u: np.ndarray
    spacing: float
    nu: int
    nv: int

    def __post_init__(self):
        d = _unit(self.direction, "dexel direction")
        u = np.asarray(self.u, dtype=np.float64).reshape(3)
        u = u - d * float(u @ d)  # orientation vector made orthogonal to the rays
        u = _unit(u, "dexel orientation (not parallel to the direction)")
        object.__setattr__(self, "direction", d)
        object.__setattr__(self, "u", u)
        object.__setattr__(self, "origin", np.asarray(self.origin, dtype=np.float64).reshape(3))
        if not (np.isfinite(self.spacing) and self.spacing > 0):
            raise InputError(f"grid spacing must be a positive length in mm, got {self.spacing}")
        if int(self.nu) < 1 or int(self.nv) < 1:
            raise InputError(f"grid needs at least one ray each way, got {self.nu} x {self.nv}")
        object.__setattr__(self, "spacing", float(self.spacing))
        object.__setattr__(self, "nu", int(self.nu))
        object.__setattr__(self, "nv", int(self.nv))

    @property
    def v(self) -> np.ndarray:
        return np.cross(self.direction, self.u)

    @property
    def shape(self) -> tuple[int, int]:
        """(nv, nu): the shape of per-ray arrays."""
        return (self.nv, self.nu)

    @property
    def n_rays(self) -> int:
        return self.nu * self.nv

    @cached_property
    def is_top(self) -> bool:
        """True when rays run along +Z with u = +X (the 3-axis fast paths apply). Kept once
        worked out: per-finding code asks it in every batch (a frame never changes)."""
        return bool(
            np.allclose(self.direction, (0, 0, 1)) and np.allclose(self.u, (1, 0, 0))
            and abs(self.origin[2]) == 0.0
        )

    @classmethod
    def top(cls, x0: float, y0: float, x1: float, y1: float, spacing: float) -> "Frame":
        """Rays along +Z covering ``[x0, x1] x [y0, y1]``, both ends included.

        The ray count each way is ``round((x1 - x0) / spacing) + 1``.
        """
        if not (np.isfinite(spacing) and spacing > 0):
            raise InputError(f"resolution must be a positive length in mm, got {spacing}")
        if not (x1 >= x0 and y1 >= y0):
            raise InputError(f"empty grid extent X {x0}..{x1}, Y {y0}..{y1}")
        nu = int(round((x1 - x0) / spacing)) + 1
        nv = int(round((y1 - y0) / spacing)) + 1
        return cls(np.array([x0, y0, 0.0]), np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]),
                   spacing, nu, nv)

    def ray_points(self) -> np.ndarray:
        """Foot of every ray on the origin plane, shape (nv, nu, 3), mm."""
        i = np.arange(self.nu) * self.spacing
        j = np.arange(self.nv) * self.spacing
        return (self.origin[None, None, :] + i[None, :, None] * self.u[None, None, :]
                + j[:, None, None] * self.v[None, None, :])

    def to_local(self, points: np.ndarray) -> np.ndarray:
        """World points (..., 3) -> (..., 3) of (u, v, s) in mm, u and v from the origin."""
        p = np.asarray(points, dtype=np.float64) - self.origin
        return np.stack([p @ self.u, p @ self.v, p @ self.direction], axis=-1)

    def to_world(self, local: np.ndarray) -> np.ndarray:
        """(u, v, s) in mm (..., 3) -> world points (..., 3)."""
        local = np.asarray(local, dtype=np.float64)
        return (self.origin + local[..., 0:1] * self.u + local[..., 1:2] * self.v
                + local[..., 2:3] * self.direction)

    def window(self, i0: int, i1: int, j0: int, j1: int) -> "Frame":
        """The sub-frame of rays ``i0 <= i < i1``, ``j0 <= j < j1``."""
        origin = self.origin + i0 * self.spacing * self.u + j0 * self.spacing * self.v
        return Frame(origin, self.direction, self.u, self.spacing, i1 - i0, j1 - j0)

    def same_rays(self, other: "Frame") -> bool:
        return (self.nu == other.nu and self.nv == other.nv and self.spacing == other.spacing
                and np.allclose(self.origin, other.origin) and np.allclose(self.direction, other.direction)
                and np.allclose(self.u, other.u))
