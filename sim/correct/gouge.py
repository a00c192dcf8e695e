"""How far one tool position, or one straight move, gouges the design.

:class:`GougeProbe` holds the design (a :class:`sim.checks.error_map.DesignModel` on a
top frame) as the arrays the kernels of :mod:`sim.correct.kernels` read, and answers for a
tool: the deepest gouge of a pose or of a move's sweep, and the guide vector of Huang &
Oliver's eq. 7 there. Lengths mm, world coordinates of the frame (Z up).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.checks.error_map import DesignModel
from sim.correct import kernels as K
from sim.errors import InputError
from sim.sweep import body_params, has_exact_sweep
from sim.tolerance import DEFAULT, Tolerance
from sim.tools import Tool


@dataclass(frozen=True)
class Gouge:
    """What one pose or move does to the design.

    ``rays``: rays gouged deeper than the threshold asked; ``depth``: the deepest gouge
    (mm, 0 when none); ``point``: where (world mm, NaN when none); ``guide``: the guide
    vector of eq. 7 (unnormalised, (3,)); ``lift``: the straight lift (mm) that frees every
    gouged point of a height-field design.
    """

    rays: int
    depth: float
    point: tuple
    guide: tuple
    lift: float


class GougeProbe:
    """The design seen by the correction kernels.

    Parameters
    ----------
    design : DesignModel
        The part on a top frame (``Frame.top``): rays along +Z.
    tol : Tolerance
        ``interest`` bounds the exact near-point search (1.5 x, as the error map does).
    """

    def __init__(self, design: DesignModel, tol: Tolerance = DEFAULT):
        f = design.frame
        if not f.is_top:
            raise InputError("tool path correction needs a top frame (rays along +Z)")
        self.design = design
        self.tol = tol
        self.frame = f
        self.search = 1.5 * tol.interest
        normals = np.array(design.normals, np.float64)
        if not design.closed:
            # an open sheet is a height field: its outside is up
            normals[normals[:, 2] < 0] *= -1.0
        bin_size, nbu, nbv, bptr, bitems = design._binned()
        self.arrays = (design.ptr, design.hit_s, design.hit_tri, design.tri_dz, not design.closed,
                       design.tri, design.tri_lo, design.tri_hi, float(bin_size), int(nbu), int(nbv), bptr, bitems,
                       np.ascontiguousarray(normals))
        self.frame_tuple = (float(f.origin[0]), float(f.origin[1]), float(f.spacing), int(f.nu), int(f.nv))

    @staticmethod
    def params(tool: Tool) -> np.ndarray:
        """The tool's exact-sweep parameters; InputError for a tool without a closed form."""
        if not has_exact_sweep(tool):
            raise InputError(f"tool path correction needs a flat, ball, bull-nose, vbit or drill tool, "
                             f"got {tool.kind}")
        return body_params(tool)

    def move(self, tool: Tool, p0, p1, thr: float) -> Gouge:
        """The sweep of ``tool`` from tip ``p0`` to ``p1`` (3,) mm: points deeper than ``thr``."""
        out = np.empty(K.G_SIZE)
        a = np.asarray(p0, np.float64)
        b = np.asarray(p1, np.float64)
        K.sweep_gouge(self.params(tool), a[0], a[1], a[2], b[0], b[1], b[2], self.frame_tuple, self.arrays,
                      float(thr), self.search, out)
        return self._gouge(out)

    def pose(self, tool: Tool, p, thr: float) -> Gouge:
        """The tool standing at tip ``p`` (3,) mm."""
        return self.move(tool, p, p, thr)

    def _gouge(self, out) -> Gouge:
        n = int(out[K.G_COUNT])
        if n == 0:
            return Gouge(0, 0.0, (np.nan,) * 3, (0.0, 0.0, 0.0), 0.0)
        f = self.frame
        r = int(out[K.G_RAY])
        x = f.origin[0] + (r % f.nu) * f.spacing
        y = f.origin[1] + (r // f.nu) * f.spacing
        return Gouge(n, float(out[K.G_DEPTH]), (float(x), float(y), float(out[K.G_S])),
                     tuple(float(v) for v in out[K.G_GX:K.G_GZ + 1]), float(out[K.G_LIFT]))
