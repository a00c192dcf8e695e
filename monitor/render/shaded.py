"""Van Hook's image-space shaded display, straight from the dexels (numpy + numba, no VTK).

The picture is the dexel grid seen along its rays: one pixel per ray, the visible surface
is each ray's last FarZ (Blasquez rule 6). Normals come from finite differences of the
heights, shading is Lambert plus ambient with a light direction, faces can be coloured by
the id of the move that made them (Van Hook's "attribute per dixel"). The tool is drawn
*inverse-shaded*: the lower face of the cutter is lit with its normals turned inward, so it
looks exactly like the surface it is about to leave (Van Hook's negative solid).

Images are RGB uint8 ``(nv, nu, 3)`` with +v (usually +Y) pointing up the picture, so row 0
is the ray row ``j = nv - 1``.
"""

from __future__ import annotations

import numba as nb
import numpy as np

#: default light: from the upper left, in front (a unit vector towards the light)
LIGHT = (-0.45, 0.55, 0.70)
BACKGROUND = (28, 30, 36)
STOCK_COLOR = (178, 184, 196)
TOOL_COLOR = (235, 200, 40)
PATH_COLOR = (40, 220, 240)
FINDING_COLOR = (240, 40, 40)
PALETTE_SIZE = 64


def id_palette(n: int = PALETTE_SIZE, seed: int = 7) -> np.ndarray:
    """A fixed palette of ``n`` distinguishable muted colours, uint8 (n, 3); entry 0 is the stock."""
    rng = np.random.default_rng(seed)
    h = (np.arange(n) * 0.618033988749895) % 1.0
    s = 0.35 + 0.25 * rng.random(n)
    v = np.full(n, 0.85)
    i = np.floor(h * 6).astype(int) % 6
    f = h * 6 - np.floor(h * 6)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    rgb = np.choose(i[:, None], [np.stack(c, 1) for c in
                                 ((v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q))])
    out = np.clip(rgb * 255, 0, 255).astype(np.uint8)
    out[0] = STOCK_COLOR
    return out


#: viridis at 9 stops, from 0.18 (not its near-black end: shaded walls must stay visible on
#: the dark background) to 1; perceptually uniform and readable with colour-blindness.
#: Index 0 is the deepest cut, the last entry the shallowest (deeper reads darker).
_VIRIDIS = np.array([(253, 231, 37), (181, 222, 43), (110, 206, 88), (53, 183, 121), (31, 158, 137),
                     (38, 130, 142), (49, 104, 142), (62, 74, 137), (71, 45, 123)], np.float64)


def depth_ramp(n: int = 256) -> np.ndarray:
    """Colours of cut depth, uint8 (n, 3): entry 0 = just below the stock top (yellow), the
    last = the deepest cut of the range (dark violet)."""
    x = np.linspace(0, len(_VIRIDIS) - 1, n)
    out = np.stack([np.interp(x, np.arange(len(_VIRIDIS)), _VIRIDIS[:, c]) for c in range(3)], axis=1)
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64).reshape(3)
    n = np.linalg.norm(v)
    if not np.isfinite(n) or n == 0:
        raise ValueError(f"light direction must be a non-zero 3-vector, got {v.tolist()}")
    return v / n


@nb.njit(cache=True)
def _shade(h, spacing, zscale, lx, ly, lz, ambient, ids, palette, base, bg, out,
           ref, inv_depth, lut, eps):
    """Shade heights ``h`` (nv, nu) into ``out`` (nv, nu, 3) uint8, flipped so +v is up.

    With ``ref`` (nv, nu) (the stock's top per ray) a ray cut more than ``eps`` below it is
    coloured ``lut[depth * inv_depth]`` instead of ``base``/``ids``."""
    nv, nu = h.shape
    use_ids = ids.shape[0] == nv
    use_depth = ref.shape[0] == nv and lut.shape[0] > 0
    nlut = lut.shape[0]
    npal = palette.shape[0]
    for j in range(nv):
        row = nv - 1 - j
        for i in range(nu):
            z = h[j, i]
            if np.isnan(z):
                out[row, i, 0] = bg[0]
                out[row, i, 1] = bg[1]
                out[row, i, 2] = bg[2]
                continue
            # central differences, one-sided at edges and next to empty rays
            il = i - 1 if i > 0 and not np.isnan(h[j, i - 1]) else i
            ir = i + 1 if i < nu - 1 and not np.isnan(h[j, i + 1]) else i
            jd = j - 1 if j > 0 and not np.isnan(h[j - 1, i]) else j
            ju = j + 1 if j < nv - 1 and not np.isnan(h[j + 1, i]) else j
            gx = 0.0
            gy = 0.0
            if ir != il:
                gx = (h[j, ir] - h[j, il]) * zscale / ((ir - il) * spacing)
            if ju != jd:
                gy = (h[ju, i] - h[jd, i]) * zscale / ((ju - jd) * spacing)
            nx = -gx
            ny = -gy
            nz = 1.0
            norm = np.sqrt(nx * nx + ny * ny + nz * nz)
            d = (nx * lx + ny * ly + nz * lz) / norm
            if d < 0.0:
                d = 0.0
            k = ambient + (1.0 - ambient) * d
            depth = ref[j, i] - z if use_depth else 0.0
            if use_depth and depth > eps:
                t = depth * inv_depth
                c = int(t * (nlut - 1) + 0.5)
                if c > nlut - 1:
                    c = nlut - 1
                r = lut[c, 0]
                g = lut[c, 1]
                b = lut[c, 2]
            elif use_ids:
                c = ids[j, i] % npal
                r = palette[c, 0]
                g = palette[c, 1]
                b = palette[c, 2]
            else:
                r = base[0]
                g = base[1]
                b = base[2]
            out[row, i, 0] = min(255, int(r * k + 0.5))
            out[row, i, 1] = min(255, int(g * k + 0.5))
            out[row, i, 2] = min(255, int(b * k + 0.5))


def shade(heights: np.ndarray, spacing: float, light=LIGHT, ambient: float = 0.22,
          ids: np.ndarray | None = None, palette: np.ndarray | None = None,
          color=STOCK_COLOR, background=BACKGROUND, zscale: float = 1.0,
          out: np.ndarray | None = None, stock_top: np.ndarray | None = None,
          max_depth: float = 1.0, ramp: np.ndarray | None = None, min_depth: float = 1e-3) -> np.ndarray:
    """Shaded picture of a height field seen from above.

    heights : (nv, nu) float, mm along the ray (NaN = no material: background).
    spacing : ray spacing, mm. ids : optional (nv, nu) int face ids coloured through
    ``palette`` (uint8 (k, 3), default :func:`id_palette`); otherwise every face is
    ``color``. ``light`` points towards the light; ``ambient`` in [0, 1]. ``zscale``
    exaggerates relief. Returns RGB uint8 (nv, nu, 3) (``out`` reused when given).

    Colour by depth: with ``stock_top`` (nv, nu) float mm (the uncut stock's top per ray,
    NaN = none) every ray cut more than ``min_depth`` mm below it takes the colour of
    ``ramp`` (uint8 (k, 3), default :func:`depth_ramp`) at ``depth / max_depth`` (clipped),
    shaded like the rest; uncut rays keep ``color``.
    """
    h = np.ascontiguousarray(heights, dtype=np.float32)
    if h.ndim != 2:
        raise ValueError(f"heights must be (nv, nu), got shape {h.shape}")
    L = _unit(light)
    if out is None or out.shape != h.shape + (3,):
        out = np.empty(h.shape + (3,), np.uint8)
    idarr = np.zeros((0, 0), np.int32) if ids is None else np.ascontiguousarray(ids, dtype=np.int32)
    pal = id_palette() if palette is None else np.ascontiguousarray(palette, dtype=np.uint8)
    if stock_top is None:
        ref, lut, inv = np.zeros((0, 0), np.float32), np.zeros((0, 3), np.uint8), 0.0
    else:
        ref = np.ascontiguousarray(stock_top, dtype=np.float32)
        if ref.shape != h.shape:
            raise ValueError(f"stock_top of shape {ref.shape} does not fit heights {h.shape}")
        lut = depth_ramp() if ramp is None else np.ascontiguousarray(ramp, dtype=np.uint8)
        inv = 1.0 / max(float(max_depth), 1e-9)
    _shade(h, float(spacing), float(zscale), L[0], L[1], L[2], float(ambient), idarr, pal,
           np.asarray(color, np.float64), np.asarray(background, np.uint8), out, ref, inv, lut,
           float(min_depth))
    return out


# --- overlays ---------------------------------------------------------------------------

def to_pixels(frame, points: np.ndarray) -> np.ndarray:
    """World points (k, 3) -> float (k, 2) of (column, row) in the picture of ``frame``."""
    loc = frame.to_local(np.asarray(points, np.float64).reshape(-1, 3))
    col = loc[:, 0] / frame.spacing
    row = (frame.nv - 1) - loc[:, 1] / frame.spacing
    return np.stack([col, row], axis=1)


def draw_tool(image: np.ndarray, frame, heights: np.ndarray, tip, tool, light=LIGHT,
              ambient: float = 0.22, color=TOOL_COLOR, alpha: float = 0.75, scale: int = 1) -> np.ndarray:
    """Draw the cutter at tip position ``tip`` (x, y, z mm), inverse-shaded, in place.

    ``tool`` has ``cutting_radius`` and ``lowest_height(d)`` (a :class:`sim.tools.Tool`) or is
    a float radius (a flat end mill). Where the tool's lower face is below the material it
    is drawn opaque (it is cutting there); elsewhere blended by ``alpha``; the rim is
    outlined. ``scale``: ``heights`` has one value per ``scale`` x ``scale`` pixels of
    ``frame`` (a picture upscaled from the rays, see :func:`upscaled_frame`). Returns ``image``.
    """
    radius = float(getattr(tool, "cutting_radius", tool))
    lowest = getattr(tool, "lowest_height", lambda d: np.zeros_like(d))
    tip = np.asarray(tip, np.float64).reshape(3)
    c = frame.to_local(tip)
    sp = frame.spacing
    i0 = max(int(np.floor((c[0] - radius) / sp)) - 1, 0)
    i1 = min(int(np.ceil((c[0] + radius) / sp)) + 2, frame.nu)
    j0 = max(int(np.floor((c[1] - radius) / sp)) - 1, 0)
    j1 = min(int(np.ceil((c[1] + radius) / sp)) + 2, frame.nv)
    if i1 <= i0 or j1 <= j0:
        return image
    u = np.arange(i0, i1) * sp - c[0]
    v = np.arange(j0, j1) * sp - c[1]
    d = np.hypot(u[None, :], v[:, None])
    inside = d <= radius
    face = np.where(inside, c[2] + np.nan_to_num(lowest(d), nan=0.0), np.nan).astype(np.float32)
    L = _unit(light)
    patch = np.empty(face.shape + (3,), np.uint8)
    # the lower face's outward normals point down, away from the viewer; turned inward they
    # point up and are the normals of the surface the tool leaves -- which is exactly what
    # shading the face's heights from above computes (Van Hook's inverse-shaded tool)
    _shade(face, sp, 1.0, L[0], L[1], L[2], float(ambient), np.zeros((0, 0), np.int32),
           id_palette(1), np.asarray(color, np.float64), np.zeros(3, np.uint8), patch,
           np.zeros((0, 0), np.float32), 0.0, np.zeros((0, 3), np.uint8), 0.0)
    patch = patch[::-1]  # _shade flips; the window rows are ray rows
    if scale == 1:
        mat = np.asarray(heights, np.float32)[j0:j1, i0:i1]
    else:
        jj, ii = np.arange(j0, j1) // scale, np.arange(i0, i1) // scale
        mat = np.asarray(heights, np.float32)[jj[:, None], ii[None, :]]
    cutting = inside & (face < np.nan_to_num(mat, nan=-np.inf))
    a = np.where(cutting, 1.0, np.where(inside, alpha, 0.0))[..., None]
    rows = (frame.nv - 1) - np.arange(j0, j1)
    region = image[rows[:, None], np.arange(i0, i1)[None, :]].astype(np.float32)
    blended = region * (1 - a) + patch.astype(np.float32) * a
    rim = inside & (d > radius - max(1.5 * sp, 2.5 * sp * (scale > 1)))
    blended[rim] = np.asarray(color, np.float32) * 0.45
    image[rows[:, None], np.arange(i0, i1)[None, :]] = np.clip(blended + 0.5, 0, 255).astype(np.uint8)
    return image


def draw_polyline(image: np.ndarray, frame, points: np.ndarray, color=PATH_COLOR, width: int = 1) -> np.ndarray:
    """Draw the path through world ``points`` (k, 3) onto the picture, ``width`` pixels
    wide, in place."""
    px = to_pixels(frame, points)
    if len(px) < 2:
        return image
    a, b = px[:-1], px[1:]
    steps = np.maximum(np.ceil(np.abs(b - a).max(axis=1)), 1).astype(np.int64)
    seg = np.repeat(np.arange(len(a)), steps + 1)
    t = np.concatenate([np.arange(s + 1) / s for s in steps])
    p = a[seg] + (b[seg] - a[seg]) * t[:, None]
    col = np.rint(p[:, 0]).astype(np.int64)
    row = np.rint(p[:, 1]).astype(np.int64)
    for dr in range(-(width // 2), width - width // 2):
        for dc in range(-(width // 2), width - width // 2):
            r, c = row + dr, col + dc
            ok = (c >= 0) & (c < image.shape[1]) & (r >= 0) & (r < image.shape[0])
            image[r[ok], c[ok]] = color
    return image


def draw_markers(image: np.ndarray, frame, points: np.ndarray, color=FINDING_COLOR,
                 size: int | None = None) -> np.ndarray:
    """Mark world ``points`` (k, 3) with rings of ``size`` pixels radius (default scales
    with the picture), in place."""
    size = int(size or max(6, max(image.shape[:2]) // 90))
    px = to_pixels(frame, points)
    ang = np.linspace(0, 2 * np.pi, max(16, 8 * size), endpoint=False)
    for rad in (size, size - 1):
        col = np.rint(px[:, :1] + rad * np.cos(ang)[None, :]).astype(np.int64).ravel()
        row = np.rint(px[:, 1:] + rad * np.sin(ang)[None, :]).astype(np.int64).ravel()
        ok = (col >= 0) & (col < image.shape[1]) & (row >= 0) & (row < image.shape[0])
        image[row[ok], col[ok]] = color
    return image


def picture(heights: np.ndarray, frame, ids: np.ndarray | None = None, tool=None, tip=None,
            path_ahead: np.ndarray | None = None, findings: np.ndarray | None = None,
            light=LIGHT, out: np.ndarray | None = None, **shade_kw) -> np.ndarray:
    """The full live frame: shaded model, path ahead, tool inverse-shaded, findings ringed.

    ``findings`` are world positions (k, 3). Returns RGB uint8 (nv, nu, 3).
    """
    img = shade(heights, frame.spacing, light=light, ids=ids, out=out, **shade_kw)
    if path_ahead is not None and len(path_ahead) > 1:
        draw_polyline(img, frame, path_ahead)
    if tool is not None and tip is not None:
        draw_tool(img, frame, heights, tip, tool, light=light)
    if findings is not None and len(findings):
        draw_markers(img, frame, findings)
    return img


def save_png(image: np.ndarray, path) -> None:
    import imageio.v3 as iio
    iio.imwrite(path, np.ascontiguousarray(image), extension=".png")


def upscaled_frame(frame, scale: int):
    """The frame of a picture of ``frame`` enlarged ``scale`` times (each ray a ``scale`` x
    ``scale`` block of pixels): spacing / scale, ray centres at the blocks' centres."""
    if scale == 1:
        return frame
    sp = frame.spacing / scale
    shift = (scale - 1) / 2 * sp
    return frame.__class__(frame.origin - shift * (frame.u + frame.v), frame.direction, frame.u, sp,
                           frame.nu * scale, frame.nv * scale)


def upscale(image: np.ndarray, scale: int, out: np.ndarray | None = None) -> np.ndarray:
    """Nearest-neighbour enlargement of ``image`` (h, w, 3) to (h * scale, w * scale, 3)."""
    if scale == 1:
        return image
    h, w = image.shape[:2]
    if out is None or out.shape != (h * scale, w * scale, 3):
        out = np.empty((h * scale, w * scale, 3), np.uint8)
    view = out.reshape(h, scale, w, scale, 3)
    view[...] = image[:, None, :, None, :]
    return out


# --- text: a 5 x 7 bitmap font drawn with numpy (no font files, identical everywhere) ---

_GLYPHS = {
    "0": ".###.#...##..###.#.###..##...#.###.", "1": "..#...##....#....#....#....#...###.",
    "2": ".###.#...#....#...#...#...#...#####", "3": "#####" "...#." "..#.." "...#." "....#" "#...#" ".###.",
    "4": "...#...##..#.#.#..#.#####...#....#.", "5": "#####" "#...." "####." "....#" "....#" "#...#" ".###.",
    "6": "..##..#...#....####.#...##...#.###.", "7": "#####....#...#...#...#....#....#...",
    "8": ".###.#...##...#.###.#...##...#.###.", "9": ".###.#...##...#.####....#...#..##..",
    "A": ".###.#...##...#######...##...##...#", "B": "####.#...##...#####.#...##...#####.",
    "C": ".###.#...##....#....#....#...#.###.", "D": "###..#..#.#...##...##...##..#.###..",
    "E": "######....#....####.#....#....#####", "F": "######....#....####.#....#....#....",
    "G": ".###.#...##....#.####...##...#.####", "H": "#...##...##...#######...##...##...#",
    "I": ".###...#....#....#....#....#...###.", "J": "..###...#....#....#....#.#..#..##..",
    "K": "#...##..#.#.#..##...#.#..#..#.#...#", "L": "#....#....#....#....#....#....#####",
    "M": "#...###.###.#.##.#.##...##...##...#", "N": "#...##...###..##.#.##..###...##...#",
    "O": ".###.#...##...##...##...##...#.###.", "P": "####.#...##...#####.#....#....#....",
    "Q": ".###.#...##...##...##.#.##..#..##.#", "R": "####.#...##...#####.#.#..#..#.#...#",
    "S": ".#####....#.....###.....#....#####.", "T": "#####..#....#....#....#....#....#..",
    "U": "#...##...##...##...##...##...#.###.", "V": "#...##...##...##...##...#.#.#...#..",
    "W": "#...#" "#...#" "#...#" "#.#.#" "#.#.#" "#.#.#" ".#.#.", "X": "#...##...#.#.#...#...#.#.#...##...#",
    "Y": "#...##...#.#.#...#....#....#....#..", "Z": "#####....#...#...#...#...#....#####",
    " ": "." * 35, ".": "." * 25 + ".##...##..", "-": "." * 15 + "#####" + "." * 15,
    "+": "....." "..#.." "..#.." "#####" "..#.." "..#.." ".....",
    ":": "......##...##........##...##.......", "/": "....#...#....#...#...#....#...#....",
    "(": "...#...#...#....#....#.....#.....#.", ")": ".#.....#.....#....#....#...#...#...",
    "=": "..........#####.....#####..........", ",": "....................##....#...#....",
    "_": "." * 30 + "#####", "%": "##..#" "##..#" "...#." "..#.." ".#..." "#..##" "#..##",
    "?": ".###.#...#....#...#...#.........#..", "'": "..#.." "..#.." ".#..." + "." * 20,
}
_FONT_CHARS = "".join(_GLYPHS)
_FONT = np.zeros((len(_GLYPHS), 7, 5), bool)
for _k, _g in enumerate(_GLYPHS.values()):
    _FONT[_k] = np.frombuffer(_g.encode(), np.uint8).reshape(7, 5) == ord("#")
_FONT_INDEX = np.full(128, _FONT_CHARS.index("?"), np.int64)
for _k, _c in enumerate(_FONT_CHARS):
    _FONT_INDEX[ord(_c)] = _k
GLYPH_W, GLYPH_H = 6, 9   # cell of one character (5 x 7 glyph, 1 column and 2 rows apart)


def text_mask(text: str, scale: int = 1) -> np.ndarray:
    """Pixels of ``text`` in the bitmap font, bool (7 * scale, 6 * scale * len(text)).
    Lower case is drawn as upper case; characters the font lacks as ``?``."""
    codes = np.frombuffer(text.upper().encode("ascii", "replace"), np.uint8)
    g = _FONT[_FONT_INDEX[np.minimum(codes, 127)]]                  # (n, 7, 5)
    cells = np.zeros((len(codes), 7, GLYPH_W), bool)
    cells[:, :, :5] = g
    m = cells.transpose(1, 0, 2).reshape(7, -1)
    if scale > 1:
        m = np.repeat(np.repeat(m, scale, axis=0), scale, axis=1)
    return m


def text_size(text: str, scale: int = 1) -> tuple[int, int]:
    """(height, width) in pixels of ``text`` drawn by :func:`draw_text` with ``pad``=0."""
    return 7 * scale, GLYPH_W * scale * len(text) - scale


def draw_text(image: np.ndarray, text: str, row: int, col: int, color=(240, 240, 240), scale: int = 1,
              background=None, pad: int = 2) -> tuple[int, int, int, int]:
    """Write ``text`` with its top-left corner at pixel (``row``, ``col``), in place; with
    ``background`` on a filled box ``pad`` pixels larger. Clipped to the image. Returns
    the box drawn (r0, r1, c0, c1), end exclusive."""
    m = text_mask(text, scale)[:, :max(GLYPH_W * scale * len(text) - scale, 0)]
    H, W = image.shape[:2]
    r0, c0 = row - pad, col - pad
    r1, c1 = row + m.shape[0] + pad, col + m.shape[1] + pad
    if background is not None:
        image[max(r0, 0):max(min(r1, H), 0), max(c0, 0):max(min(c1, W), 0)] = background
    a0, b0 = max(row, 0), max(col, 0)
    a1, b1 = min(row + m.shape[0], H), min(col + m.shape[1], W)
    if a1 > a0 and b1 > b0:
        sub = m[a0 - row:a1 - row, b0 - col:b1 - col]
        image[a0:a1, b0:b1][sub] = color
    return r0, r1, c0, c1


LABEL_BG = (16, 16, 20)


def draw_labels(image: np.ndarray, frame, points: np.ndarray, labels, color=FINDING_COLOR,
                scale: int = 1, size: int | None = None) -> list[tuple[int, int, int, int]]:
    """Write ``labels`` (k strings) beside the rings of :func:`draw_markers` at world
    ``points`` (k, 3), on dark boxes, moved down (then up) so that no two overlap.
    Returns the boxes (r0, r1, c0, c1)."""
    size = int(size or max(6, max(image.shape[:2]) // 90))
    px = to_pixels(frame, points)
    H, W = image.shape[:2]
    boxes: list[tuple[int, int, int, int]] = []
    th = 7 * scale + 4
    for (c, r), text in zip(px, labels):
        if not (np.isfinite(c) and np.isfinite(r)):
            continue
        h, w = text_size(text, scale)
        col = int(round(c)) + size + 3
        if col + w + 2 > W:                       # no room on the right: to the left
            col = int(round(c)) - size - 3 - w
        col = min(max(col, 2), max(W - w - 2, 2))
        row0 = min(max(int(round(r)) - size - h, 2), max(H - h - 2, 2))
        for k in range(2 * len(boxes) + 1):
            step = (k + 1) // 2 * th * (1 if k % 2 else -1)
            row = min(max(row0 + step, 2), max(H - h - 2, 2))
            box = (row - 2, row + h + 2, col - 2, col + w + 2)
            if not any(b[0] < box[1] and box[0] < b[1] and b[2] < box[3] and box[2] < b[3] for b in boxes):
                break
        boxes.append(draw_text(image, text, row, col, color=color, scale=scale, background=LABEL_BG))
    return boxes


def draw_outline(image: np.ndarray, frame, mask: np.ndarray, color, scale: int = 1) -> np.ndarray:
    """Outline the region ``mask`` (nv, nu) bool (rays of ``frame`` before upscaling by
    ``scale``) on the picture, in place: the pixels of the region's boundary rays."""
    m = np.asarray(mask, bool)
    inner = m.copy()
    inner[1:-1, 1:-1] = m[1:-1, 1:-1] & m[:-2, 1:-1] & m[2:, 1:-1] & m[1:-1, :-2] & m[1:-1, 2:]
    inner[[0, -1], :] = False
    inner[:, [0, -1]] = False
    edge = (m & ~inner)[::-1]
    if scale > 1:
        edge = np.repeat(np.repeat(edge, scale, 0), scale, 1)
    image[edge[:image.shape[0], :image.shape[1]]] = color
    return image
