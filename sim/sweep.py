"""Where a tool is on the dexel rays: one pose, one straight move, arcs and instances.

Array-in / array-out helpers around :mod:`sim.sweep_kernels`:

* :func:`body_params` - the parameter vector of the exact linear-sweep kernel.
* :func:`pose_on_rays` - the interval(s) a tool (or body) at one pose occupies on every
  ray of a frame (any tool axis).
* :func:`linear_sweep_on_rays` - the exact interval of a straight 3-axis move on every ray
  of a top frame.
* :func:`arc_points` - points along an arc / helix row of the move table.
* :func:`instances` - instances of motion between two poses (Huang & Oliver eq. 3-5).

Lengths mm, angles radians unless named ``*_deg``.
"""

from __future__ import annotations

import math

import numpy as np

from sim import sweep_kernels as K
from sim.errors import InputError
from sim.frame import Frame
from sim.tools import Body, Tool

_CODES = {"flat": K.CODE_FLAT, "ball": K.CODE_BALL, "bull": K.CODE_BULL, "vbit": K.CODE_CONE,
          "drill": K.CODE_CONE}


def has_exact_sweep(body: Tool | Body) -> bool:
    """True when straight moves of ``body`` (axis along the rays) have a closed-form sweep."""
    if isinstance(body, Body):
        return body.is_cylinder
    return body.kind in _CODES


def body_params(body: Tool | Body) -> np.ndarray:
    """float64 (7,) parameters of the exact kernel: [code, R, rc, cot, h_off, h_top, Rc].

    A tool gives its cutting part (up to the flute length); a cylindrical :class:`Body`
    gives a flat cylinder from its bottom to its top.
    """
    if isinstance(body, Body):
        if not body.is_cylinder:
            raise InputError(f"{body.name}: only cylinders have an exact sweep")
        r = float(body.profile[0, 1])
        return np.array([K.CODE_FLAT, r, 0.0, 0.0, body.bottom, body.top, r])
    if body.kind not in _CODES:
        raise InputError(f"{body.kind} tools have no exact sweep; use instances of motion")
    cot = 0.0
    if body.kind in ("vbit", "drill"):
        cot = 1.0 / math.tan(math.radians(body.angle) / 2.0)
    return np.array([_CODES[body.kind], body.radius, body.corner_radius, cot, 0.0,
                     body.flute_length, body.cutting_radius])


def body_profile(body: Tool | Body) -> np.ndarray:
    """float64 (k, 2) polyline (h, r) of the solid of revolution (cutting part for a tool)."""
    return np.ascontiguousarray(body.profile, dtype=np.float64)


def _frame_axis_local(frame: Frame, axis) -> np.ndarray:
    a = np.asarray(axis, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(a))
    if not np.isfinite(n) or n == 0:
        raise InputError(f"tool axis must be a non-zero 3-vector, got {a.tolist()}")
    a = a / n
    return np.array([a @ frame.u, a @ frame.v, a @ frame.direction])


def pose_on_rays(body: Tool | Body, tip, axis, frame: Frame):
    """Intervals of every ray of ``frame`` inside ``body`` standing on ``tip`` along ``axis``.

    tip: (3,) world mm; axis: (3,) direction from the tip up the tool. Returns
    ``(rays, lo, hi)``: int64 flat ray indices (a ray appears once per interval, in
    order) and float64 ray parameters ``s`` (mm) of each interval's ends.
    """
    prof = body_profile(body)
    tip_l = frame.to_local(np.asarray(tip, dtype=np.float64).reshape(3))
    ax_l = _frame_axis_local(frame, axis)
    rmax = float(prof[:, 1].max())
    pts = np.stack([tip_l + prof[0, 0] * ax_l, tip_l + prof[-1, 0] * ax_l])
    sp = frame.spacing
    i0 = max(0, int(math.ceil((pts[:, 0].min() - rmax) / sp)))
    i1 = min(frame.nu - 1, int(math.floor((pts[:, 0].max() + rmax) / sp)))
    j0 = max(0, int(math.ceil((pts[:, 1].min() - rmax) / sp)))
    j1 = min(frame.nv - 1, int(math.floor((pts[:, 1].max() + rmax) / sp)))
    rays, los, his = [], [], []
    out = np.empty((prof.shape[0], 2))
    buf = np.empty(2)
    for j in range(j0, j1 + 1):  # a helper for tests and single poses, not a hot path
        for i in range(i0, i1 + 1):
            m = K.pose_intervals(prof, tip_l, ax_l, i * sp, j * sp, out, buf)
            for q in range(m):
                rays.append(j * frame.nu + i)
                los.append(out[q, 0])
                his.append(out[q, 1])
    return np.array(rays, np.int64), np.array(los, np.float64), np.array(his, np.float64)


def linear_sweep_on_rays(body: Tool | Body, p0, p1, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """Exact interval of every ray inside the body swept from tip ``p0`` to ``p1``.

    frame must be a top frame (rays along +Z) and the tool axis +Z. Returns ``lo, hi``,
    float64 (nv, nu) in mm, NaN where the ray misses the swept body.
    """
    if not frame.is_top:
        raise InputError("exact linear sweeps need a top frame (rays along +Z)")
    tp = body_params(body)
    p0 = np.asarray(p0, np.float64).reshape(3)
    p1 = np.asarray(p1, np.float64).reshape(3)
    lo = np.full(frame.n_rays, np.nan)
    hi = np.full(frame.n_rays, np.nan)
    _linear_all(tp, frame, p0, p1, lo, hi)
    return lo.reshape(frame.shape), hi.reshape(frame.shape)


def _linear_all(tp, frame, p0, p1, lo, hi):
    d = p1 - p0
    ell = math.hypot(d[0], d[1])
    if ell > 1e-9:
        ux, uy = d[0] / ell, d[1] / ell
    else:
        ell, ux, uy = 0.0, 1.0, 0.0
    x = frame.origin[0] + np.arange(frame.nu) * frame.spacing
    y = frame.origin[1] + np.arange(frame.nv) * frame.spacing
    _fill_linear(tp, p0, d[2], ell, ux, uy, x, y, lo, hi)


# the kernel lives in sweep_kernels: numba's cache only notices edits to a function's own file
_fill_linear = K.linear_fill


# --- arcs and instances of motion -----------------------------------------------------

#: (first, second, axis) coordinate indices of each plane; CCW turns first toward second
PLANE_AXES = {0: (0, 1, 2), 1: (2, 0, 1), 2: (1, 2, 0)}


def arc_points(start, end, center, plane: int, turns: int, clockwise: bool,
               max_step_angle: float | None = None, max_step_length: float | None = None) -> np.ndarray:
    """Points along an arc or helix from ``start`` to ``end`` (both included), float64 (k, 3).

    ``center`` is the arc centre (its axis coordinate is ignored); ``plane`` 0/1/2 for
    G17/G18/G19; ``turns`` = 1 + extra full turns; CCW turns from the plane's first axis
    toward its second (X->Y, Z->X, Y->Z). The radius is interpolated linearly from the
    start radius to the end radius (controllers accept a small mismatch), the axis
    coordinate linearly in angle. Steps are at most ``max_step_angle`` (rad) and
    ``max_step_length`` (mm of path).
    """
    p, q, ax = PLANE_AXES[int(plane)]
    s = np.asarray(start, np.float64)
    e = np.asarray(end, np.float64)
    c = np.asarray(center, np.float64)
    r0 = math.hypot(s[p] - c[p], s[q] - c[q])
    r1 = math.hypot(e[p] - c[p], e[q] - c[q])
    if not (np.all(np.isfinite(c[[p, q]])) and r0 > 0):
        raise InputError(f"arc with centre {c.tolist()} and start {s.tolist()} has no radius")
    a0 = math.atan2(s[q] - c[q], s[p] - c[p])
    a1 = math.atan2(e[q] - c[q], e[p] - c[p])
    sweep = a1 - a0
    if clockwise:
        sweep = -((-sweep) % (2 * math.pi))
        if sweep == 0.0:
            sweep = -2 * math.pi
        sweep -= 2 * math.pi * max(int(turns) - 1, 0)
    else:
        sweep = sweep % (2 * math.pi)
        if sweep == 0.0:
            sweep = 2 * math.pi
        sweep += 2 * math.pi * max(int(turns) - 1, 0)
    n = 1
    rmax = max(r0, r1)
    if max_step_angle:
        n = max(n, int(math.ceil(abs(sweep) / max_step_angle)))
    if max_step_length:
        length = math.hypot(abs(sweep) * rmax, e[ax] - s[ax])
        n = max(n, int(math.ceil(length / max_step_length)))
    t = np.linspace(0.0, 1.0, n + 1)
    ang = a0 + sweep * t
    rad = r0 + (r1 - r0) * t
    pts = np.empty((n + 1, 3))
    pts[:, p] = c[p] + rad * np.cos(ang)
    pts[:, q] = c[q] + rad * np.sin(ang)
    pts[:, ax] = s[ax] + (e[ax] - s[ax]) * t
    pts[0] = s[:3]
    pts[-1] = e[:3]
    return pts


def chord_step_angle(radius: float, chord: float) -> float:
    """Largest angle (rad) of a chord of a ``radius`` arc whose sagitta is within ``chord``."""
    if radius <= chord:
        return math.pi / 2
    return 2.0 * math.acos(1.0 - chord / radius)


def line_instances(p0: np.ndarray, p1: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Instances of motion of many straight moves of a tool whose axis does not turn:
    what :func:`instances` gives each row with ``axis0 == axis1``, all rows at once.

    p0, p1: (n, 3) tip positions (mm); ``step`` (mm) the largest distance between two
    instances along any coordinate. Returns ``tips`` ((sum(counts + 1), 3): each row's
    ``counts[k] + 1`` instances, both ends included, row after row) and ``counts`` (int64
    (n,), the steps of each row). Bit for bit the tips :func:`instances` makes (the
    same ``linspace`` fractions).
    """
    p0 = np.asarray(p0, np.float64).reshape(-1, 3)
    p1 = np.asarray(p1, np.float64).reshape(-1, 3)
    s = p1 - p0
    counts = np.maximum(1, np.ceil(np.abs(s).max(axis=1, initial=0.0) / step)).astype(np.int64)
    sizes = counts + 1
    row = np.repeat(np.arange(len(p0)), sizes)
    first = np.cumsum(sizes) - sizes
    idx = np.arange(int(sizes.sum())) - np.repeat(first, sizes)
    # np.linspace(0, 1, n + 1) is arange(n + 1) * (1 / n), its last value set to 1
    f = idx * (1.0 / counts[row])
    tips = p0[row] + f[:, None] * s[row]
    tips[first] = p0
    tips[first + counts] = p1
    return tips, counts


def instances(p0, p1, axis0, axis1, length: float, step: float):
    """Instances of motion between two poses (Huang & Oliver eq. 3-5).

    p0, p1: (3,) tip positions; axis0, axis1: (3,) tool axes; ``length`` the tool length
    (mm, so the top moves by ``s + L (v - u)``); ``step`` the largest distance allowed
    between adjacent instances (mm). Returns ``tips`` (n+1, 3) and unit ``axes`` (n+1, 3),
    both ends included.
    """
    p0 = np.asarray(p0, np.float64)
    p1 = np.asarray(p1, np.float64)
    u = np.asarray(axis0, np.float64)
    v = np.asarray(axis1, np.float64)
    u = u / np.linalg.norm(u)
    v = v / np.linalg.norm(v)
    s = p1 - p0
    t = s + length * (v - u)
    n = max(1, int(math.ceil(max(np.abs(s).max(), np.abs(t).max()) / step)))
    for _ in range(8):
        f = np.linspace(0.0, 1.0, n + 1)[:, None]
        tips = p0 + f * s
        tips[0] = p0
        tips[-1] = p1
        axes = u + f * (v - u)
        axes /= np.linalg.norm(axes, axis=1, keepdims=True)
        # eq. 3 spaces the tops of the *unnormalised* axes; unit axes move the top
        # unevenly, so refine until every top step is within ``step`` too
        worst = np.abs(np.diff(tips + length * axes, axis=0)).max() if n > 0 else 0.0
        if worst <= step * (1 + 1e-9):
            break
        n = int(math.ceil(n * worst / step)) + 1
    return tips, axes
