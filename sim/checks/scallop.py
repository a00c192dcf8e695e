"""The scallop a finishing raster leaves, as the default undercut tolerance.

A ball (or bull-nose) end mill run in parallel passes ``s`` mm apart leaves a cusp
between two passes: on a flat part ``h = r - sqrt(r^2 - (s/2)^2)`` for the corner radius
``r``. On a slope rising across the passes the two tool positions are ``s / cos(theta)``
apart along the surface, so the cusp grows. That material is the path's design, not a
mistake: left to the fixed scallop-sized tolerance, a clean finishing pass on a dome
reports dozens of crests. Here the path's own stepover decides the tolerance per ray, from
the slope of the design under it (its top triangle's normal); material left higher than
that (a crease or a corner the tool cannot reach) is still an undercut; :mod:`.reach`
says how much of it the tool cannot reach.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: passes run within this angle (degrees) of the path's main direction
PASS_ANGLE_DEG = 5.0
#: the passes must make at least this share of the feed path (else: no raster)
MIN_PASS_SHARE = 0.5
#: and there must be at least this many of them
MIN_PASSES = 3
#: cusps are measured on the grid and the passes are not exactly straight: this much over
#: the computed scallop is still the scallop
MARGIN = 1.15


@dataclass(frozen=True)
class Raster:
    """A parallel-pass path: passes along ``along`` (unit XY), ``stepover`` mm apart
    across them (along ``across``, unit XY)."""

    along: tuple
    across: tuple
    stepover: float
    passes: int


def raster_of(tips: np.ndarray, pass_angle_deg: float = PASS_ANGLE_DEG) -> Raster | None:
    """The raster of feed moves ``tips`` (float (m, 6): start xyz, end xyz of the tool
    tip, mm), or None when they are not mostly parallel passes.

    The main direction is the one (to 1 degree) holding the most feed length; moves
    within ``pass_angle_deg`` of it are pass pieces; their offsets across it, grouped to
    within 0.01 mm, are the passes, and the median gap between neighbouring passes is
    the stepover."""
    tips = np.asarray(tips, np.float64).reshape(-1, 6)
    d = tips[:, 3:5] - tips[:, :2]
    length = np.hypot(d[:, 0], d[:, 1])
    moving = length > 1e-6
    if moving.sum() < MIN_PASSES:
        return None
    d, length, tips = d[moving], length[moving], tips[moving]
    ang = np.degrees(np.arctan2(d[:, 1], d[:, 0])) % 180.0
    hist = np.bincount(np.round(ang).astype(np.int64) % 180, weights=length, minlength=180)
    main = float(np.argmax(hist))
    off = np.abs((ang - main + 90.0) % 180.0 - 90.0)
    pas = off <= pass_angle_deg
    if length[pas].sum() < MIN_PASS_SHARE * length.sum():
        return None
    # the mean direction of the pass pieces (the histogram bin is 1 degree wide)
    a = math.radians(float(np.average(main + ((ang[pas] - main + 90.0) % 180.0 - 90.0), weights=length[pas])))
    along = np.array([math.cos(a), math.sin(a)])
    across = np.array([-along[1], along[0]])
    mid = 0.5 * (tips[pas, :2] + tips[pas, 3:5])
    v = np.sort(mid @ across)
    groups = v[np.concatenate([[True], np.diff(v) > 0.01])]
    if groups.size < MIN_PASSES:
        return None
    gaps = np.diff(groups)
    step = float(np.median(gaps))
    if not step > 0:
        return None
    return Raster(tuple(along), tuple(across), step, int(groups.size))


def cusp(r: float, spacing) -> np.ndarray:
    """Cusp height (mm) between two arcs of radius ``r`` whose centres are ``spacing`` mm
    apart (float or array); ``r`` where the arcs do not meet."""
    half = 0.5 * np.asarray(spacing, np.float64)
    return np.where(half < r, r - np.sqrt(np.maximum(r * r - half * half, 0.0)), r)


def allowance(design, tool, raster: Raster, floor: float, margin: float = MARGIN) -> np.ndarray | None:
    """Per-ray undercut tolerance (float64 (n_rays,) mm) of a design under ``raster`` run
    with ``tool``: ``margin`` x the cusp its corner radius leaves at the stepover measured
    along the design's surface across the passes (the slope of each ray's top triangle),
    never below ``floor``; ``floor`` where the ray misses the design. None for a tool
    without a rounded corner (a flat end mill leaves no scallop to allow for)."""
    rc = float(getattr(tool, "corner_radius", 0.0))
    if tool.kind not in ("ball", "bull") or rc <= 0:
        return None
    flat = 2.0 * max(float(tool.cutting_radius) - rc, 0.0)  # a bull-nose's flat bottom
    f = design.frame
    out = np.full(f.n_rays, float(floor))
    has = design.ptr[1:] > design.ptr[:-1]
    if not has.any():
        return out
    tri = design.hit_tri[design.ptr[1:][has] - 1]
    n = design.normals[tri]
    # slope across the passes: the normal's part along ``across`` against its vertical part
    # (world XY; the checks' frames look along Z)
    nv = n[:, 0] * raster.across[0] + n[:, 1] * raster.across[1]
    nz = np.abs(n[:, 2])
    cos_t = nz / np.maximum(np.hypot(nz, nv), 1e-12)
    spacing = raster.stepover / np.maximum(cos_t, 1e-6)
    h = margin * cusp(rc, np.maximum(spacing - flat, 0.0))
    out[has] = np.maximum(h, floor)
    return out


def note(raster: Raster, tool, floor: float) -> str:
    """One line saying what the undercut tolerance followed (for a command's notes)."""
    rc = float(tool.corner_radius)
    flat = float(cusp(rc, max(raster.stepover - 2.0 * max(float(tool.cutting_radius) - rc, 0.0), 0.0)))
    return (f"undercut: the path's scallops are not findings ({raster.passes} passes {raster.stepover:.4g} mm "
            f"apart with a {rc:g} mm corner radius leave {flat:.3f} mm on flat ground, more on slopes across "
            f"the passes; at least {floor:g} mm); give --undercut-tolerance to see them")
