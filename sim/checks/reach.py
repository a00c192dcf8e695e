"""Material a tool cannot reach: the part of an undercut no path of that tool removes.

A 3-axis tool that must not cut into the design stops, over every ray, at the design
closed by the tool: where the design is concave more tightly than the tool (an inside
corner under a ball, a crease), that surface lies above the design, and the material
between the two is left by any gouge-free path of the tool. An undercut there is true
(the part is not finished) but it is not the path's fault: a smaller tool is needed. Its
finding says so (``detail["unreachable_share"]``), so a machinist can tell it from
material the path missed.
"""

from __future__ import annotations

import math

import numpy as np

from sim.checks.design_kernels import tool_reach_floor

#: the share of a region's material that must lie out of the tool's reach for its finding
#: to say "the tool cannot reach it"
UNREACHABLE_SHARE = 0.9
#: from this share on, a finding says how much of it the tool cannot reach
MENTION_SHARE = 0.25
#: a region whose closing takes more footprint steps than this is not measured (a whole
#: part left under a finishing allowance, a large tool on a fine grid: about 0.4 s)
MAX_STEPS = 400_000_000


def footprint(tool, spacing: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rays under ``tool`` centred on a ray: int64 (k,) offsets ``di``, ``dj`` and
    float64 (k,) the tool's lowest height above its tip over each (mm)."""
    n = int(math.floor(tool.cutting_radius / spacing))
    dj, di = np.mgrid[-n:n + 1, -n:n + 1]
    d = np.hypot(di, dj).ravel() * spacing
    dh = tool.lowest_height(d)
    ok = np.isfinite(dh)
    return di.ravel()[ok].astype(np.int64), dj.ravel()[ok].astype(np.int64), dh[ok].astype(np.float64)


def unreachable_share(design_top: np.ndarray, model_top: np.ndarray, members: np.ndarray, tool,
                      spacing: float, slack: float) -> float | None:
    """The share (0..1) of the material left on rays ``members`` that ``tool`` cannot
    reach without cutting into the design: material whose top lies no more than ``slack``
    mm above the lowest the tool reaches there. None when the region is too large to
    measure (:data:`MAX_STEPS`).

    design_top, model_top: float64 (nv, nu) heights (mm; NaN: no design / no material) on
    a grid of rays ``spacing`` mm apart looking down Z; members: int64 flat ray indices.
    The material left on a ray is its model top less its design top (0 where either is
    missing)."""
    nv, nu = design_top.shape
    members = np.asarray(members, np.int64)
    left = (model_top.reshape(-1)[members] - design_top.reshape(-1)[members])
    left = np.where(np.isfinite(left) & (left > 0), left, 0.0)
    if not left.sum() > 0:
        return 0.0
    di, dj, dh = footprint(tool, spacing)
    pad = 2 * int(max(np.abs(di).max(), np.abs(dj).max())) + 1
    mi, mj = members % nu, members // nu
    # the window holds every tip that reaches the members and every ray under those tips;
    # past the grid's edge lies no design (the grid covers the stock): the tool may stand
    # there, as a path running off the stock's edge does
    i0, i1 = int(mi.min()) - pad, int(mi.max()) + pad + 1
    j0, j1 = int(mj.min()) - pad, int(mj.max()) + pad + 1
    z = np.full((j1 - j0, i1 - i0), -np.inf)
    a, b, c, d = max(i0, 0), min(i1, nu), max(j0, 0), min(j1, nv)
    z[c - j0:d - j0, a - i0:b - i0] = np.nan_to_num(design_top[c:d, a:b], nan=-np.inf)
    floor, measured = tool_reach_floor(z, di, dj, dh, mi - i0, mj - j0, MAX_STEPS)
    if not measured:
        return None
    top = model_top.reshape(-1)[members]
    out_of_reach = top <= floor + slack
    return float(left[out_of_reach].sum() / left.sum())
