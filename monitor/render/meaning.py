"""Colour by meaning, and the marks every picture of a run carries.

* :func:`top_deviation`: the signed error of the visible surface against the design
  (Huang & Oliver's error map, seen from above): negative = gouge, positive = material left.
* :func:`deviation_palette` / :func:`deviation_index`: that error as colours: within the
  tolerance a neutral grey, gouges a red scale (light at the tolerance, dark at the range
  of interest and beyond), excess material a blue scale (light at the tolerance, dark at
  the range of interest and beyond).
* :func:`draw_axes`: the work origin with an X/Y triad and millimetre ticks along the
  picture's edges. :func:`draw_moves`: the path, feeds solid and rapids dashed.

Colour by move id stays available (``color_by="move"``) but is never the default: a
finishing pass of thousands of moves in random colours reads as noise.
"""

from __future__ import annotations

import numpy as np

from monitor.render import shaded

#: colours of the deviation map (RGB): within tolerance, the ends of the gouge and excess scales
NEUTRAL = (176, 180, 188)
GOUGE_LIGHT, GOUGE_DARK = (250, 150, 130), (200, 0, 0)
EXCESS_LIGHT, EXCESS_DARK = (160, 200, 250), (20, 50, 190)
#: entries of each scale in the palette (index 0 is neutral)
SCALE_STEPS = 32
RAPID_COLOR = (255, 120, 200)
AXIS_X_COLOR = (240, 80, 70)
AXIS_Y_COLOR = (90, 220, 90)
TICK_COLOR = (215, 218, 226)


def deviation_palette(steps: int = SCALE_STEPS) -> np.ndarray:
    """uint8 (1 + 2 * steps, 3): entry 0 neutral, 1..steps gouge light -> dark, steps+1 ..
    2*steps excess light -> dark."""
    t = np.linspace(0.0, 1.0, steps)[:, None]
    red = np.asarray(GOUGE_LIGHT) + (np.asarray(GOUGE_DARK) - np.asarray(GOUGE_LIGHT)) * t
    blue = np.asarray(EXCESS_LIGHT) + (np.asarray(EXCESS_DARK) - np.asarray(EXCESS_LIGHT)) * t
    out = np.vstack([np.asarray(NEUTRAL, np.float64)[None], red, blue])
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def deviation_index(errors: np.ndarray, tol, steps: int = SCALE_STEPS) -> np.ndarray:
    """Palette index (int32, same shape) of signed ``errors`` mm under ``tol`` (a
    ``sim.tolerance.Tolerance``): 0 within ``-tol.gouge .. tol.undercut`` (and NaN),
    the gouge scale below, the excess scale above, both saturating at ``tol.interest``."""
    e = np.asarray(errors, np.float64)
    out = np.zeros(e.shape, np.int32)
    with np.errstate(invalid="ignore"):
        gouge = e < -tol.gouge
        excess = e > tol.undercut
    span_g = max(tol.interest - tol.gouge, 1e-9)
    span_x = max(tol.interest - tol.undercut, 1e-9)
    tg = np.clip((-e[gouge] - tol.gouge) / span_g, 0, 1)
    tx = np.clip((e[excess] - tol.undercut) / span_x, 0, 1)
    out[gouge] = 1 + np.rint(tg * (steps - 1)).astype(np.int32)
    out[excess] = 1 + steps + np.rint(tx * (steps - 1)).astype(np.int32)
    return out


def deviation_colors(errors: np.ndarray, tol) -> np.ndarray:
    """RGB uint8 (..., 3) of signed ``errors`` mm (the deviation map's colours)."""
    return deviation_palette()[deviation_index(errors, tol)]


def top_deviation(design, heights: np.ndarray, tol) -> np.ndarray:
    """Signed error (nv, nu) float64 mm of the top of every ray (``heights``, NaN =
    empty) against ``design`` (a ``sim.checks.error_map.DesignModel`` on the same
    frame): negative = below the design surface (gouge), positive = above it (material
    left; ``+inf`` where the part has none). NaN on empty rays."""
    h = np.asarray(heights, np.float64).reshape(-1)
    rays = np.nonzero(np.isfinite(h))[0]
    out = np.full(h.size, np.nan)
    if rays.size:
        out[rays] = design.errors(rays, h[rays], tol)
    return out.reshape(np.shape(heights))


# --- marks ------------------------------------------------------------------------------

def _nice_step(span: float, count: int = 5) -> float:
    """A round tick step (1, 2, 5 x 10^k mm) giving about ``count`` ticks over ``span`` mm."""
    raw = max(span / max(count, 1), 1e-6)
    e = 10.0 ** np.floor(np.log10(raw))
    for m in (1.0, 2.0, 5.0, 10.0):
        if m * e >= raw:
            return m * e
    return 10 * e


def _arrow(image, p0, p1, color, width: int):
    """A straight arrow from pixel ``p0`` to ``p1`` (col, row), with a head."""
    H, W = image.shape[:2]
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    d = p1 - p0
    n = max(int(np.hypot(*d)), 1)
    t = np.linspace(0, 1, n + 1)[:, None]
    pts = [p0 + d * t]
    u = d / max(np.hypot(*d), 1e-9)
    side = np.array([-u[1], u[0]])
    head = max(4 * width, 5)
    for sgn in (1, -1):
        q = p1 - u * head + sgn * side * head * 0.6
        pts.append(p1 + (q - p1) * t)
    for seg in pts:
        for dr in range(-(width // 2), width - width // 2):
            for dc in range(-(width // 2), width - width // 2):
                c = np.rint(seg[:, 0]).astype(int) + dc
                r = np.rint(seg[:, 1]).astype(int) + dr
                ok = (c >= 0) & (c < W) & (r >= 0) & (r < H)
                image[r[ok], c[ok]] = color


def draw_axes(image: np.ndarray, frame, text_scale: int = 1) -> None:
    """The work origin and millimetre ticks, in place on a top-view picture of ``frame``.

    Ticks every round step (1/2/5 x 10^k mm) along the bottom (X) and left (Y) edges with
    their values; an X (red) / Y (green) triad at the work origin X0 Y0 when it is in the
    picture, else at the lower-left corner labelled with the corner's coordinates."""
    H, W = image.shape[:2]
    ts = text_scale
    sp = frame.spacing
    x0, y0 = frame.origin[0], frame.origin[1]
    x1, y1 = x0 + (W - 1) * sp, y0 + (H - 1) * sp
    tick = 5 * ts
    for axis, lo, hi in (("x", x0, x1), ("y", y0, y1)):
        step = _nice_step(hi - lo, 5)
        for v in np.arange(np.ceil(lo / step) * step, hi + 1e-9, step):
            label = f"{v + 0.0:g}"
            if axis == "x":
                c = int(round((v - x0) / sp))
                image[H - tick:H, max(c - ts // 2, 0):c + max(ts, 1)] = TICK_COLOR
                w = shaded.text_size(label, ts)[1]
                if 8 * ts < c < W - w - 2:
                    shaded.draw_text(image, label, H - tick - 9 * ts, c - w // 2, TICK_COLOR, ts,
                                     background=shaded.LABEL_BG, pad=1)
            else:
                r = int(round((H - 1) - (v - y0) / sp))
                image[max(r - ts // 2, 0):r + max(ts, 1), 0:tick] = TICK_COLOR
                if 9 * ts < r < H - 18 * ts:
                    shaded.draw_text(image, label, r - 3 * ts, tick + 2 * ts, TICK_COLOR, ts,
                                     background=shaded.LABEL_BG, pad=1)
    inside = x0 <= 0 <= x1 and y0 <= 0 <= y1
    o = shaded.to_pixels(frame, np.array([[0.0, 0.0, 0.0]]))[0] if inside else \
        np.array([tick + 22 * ts, H - tick - 22 * ts], float)
    length = 18 * ts + 6
    _arrow(image, o, o + [length, 0], AXIS_X_COLOR, max(ts, 1))
    _arrow(image, o, o - [0, length], AXIS_Y_COLOR, max(ts, 1))
    shaded.draw_text(image, "X", int(o[1]) - 3 * ts, int(o[0] + length + 3 * ts), AXIS_X_COLOR, ts,
                     background=shaded.LABEL_BG, pad=1)
    shaded.draw_text(image, "Y", int(o[1] - length - 10 * ts), int(o[0]) - 2 * ts, AXIS_Y_COLOR, ts,
                     background=shaded.LABEL_BG, pad=1)
    r = 2 * ts + 1
    rr, cc = np.mgrid[-r:r + 1, -r:r + 1]
    disc = rr ** 2 + cc ** 2 <= r * r
    rows, cols = int(round(o[1])) + rr[disc], int(round(o[0])) + cc[disc]
    ok = (rows >= 0) & (rows < H) & (cols >= 0) & (cols < W)
    image[rows[ok], cols[ok]] = (255, 255, 255)
    if inside:
        shaded.draw_text(image, "X0 Y0", int(o[1]) + 3 * ts, int(o[0]) + 3 * ts, (255, 255, 255), ts,
                         background=shaded.LABEL_BG, pad=1)
    else:
        shaded.draw_text(image, f"X{x0 + o[0] * sp:.0f} Y{y1 - o[1] * sp:.0f}", int(o[1]) + 3 * ts,
                         int(o[0]) + 3 * ts, (255, 255, 255), ts, background=shaded.LABEL_BG, pad=1)


def draw_moves(image: np.ndarray, frame, starts: np.ndarray, ends: np.ndarray, rapid: np.ndarray,
               width: int = 1, feed_color=shaded.PATH_COLOR, rapid_color=RAPID_COLOR) -> None:
    """The path of moves ``starts`` -> ``ends`` (k, 3) mm, in place: feeds solid in
    ``feed_color``, rapids (``rapid`` bool (k,)) dashed in ``rapid_color``."""
    starts = np.asarray(starts, np.float64).reshape(-1, 3)
    ends = np.asarray(ends, np.float64).reshape(-1, 3)
    rapid = np.asarray(rapid, bool).reshape(-1)
    ok = np.all(np.isfinite(starts), axis=1) & np.all(np.isfinite(ends), axis=1)
    for k in np.nonzero(ok & ~rapid)[0]:
        shaded.draw_polyline(image, frame, np.stack([starts[k], ends[k]]), color=feed_color, width=width)
    dash = max(6, 4 * width)
    for k in np.nonzero(ok & rapid)[0]:
        a, b = shaded.to_pixels(frame, np.stack([starts[k], ends[k]]))
        n = max(int(np.hypot(*(b - a)) // dash), 1)
        t = np.linspace(0, 1, n + 1)
        for q in range(0, n, 2):
            pa = starts[k] + (ends[k] - starts[k]) * t[q]
            pb = starts[k] + (ends[k] - starts[k]) * t[q + 1]
            shaded.draw_polyline(image, frame, np.stack([pa, pb]), color=rapid_color, width=width)
