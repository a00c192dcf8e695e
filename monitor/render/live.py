"""Van Hook's real-time shaded display for ``dexmon live|dry-run --view`` / ``--frames DIR``.

:class:`LiveView` redraws the shaded model (one pixel per ray, :mod:`.shaded`) with the
tool inverse-shaded at its pose, the path ahead and the predicted findings ringed. With a
display it shows a window (matplotlib, updated in place); without one, or when ``out_dir``
is given, it writes the frames as numbered PNG files. :class:`monitor.render.feed.ViewFeed`
feeds it from the session loop.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from monitor.render import shaded
from monitor.render.animate import reduce_factor
from monitor.render.view3d import has_display
from sim.errors import InputError


#: zlib level of the PNG frames (1: fast; the default 6 is three times slower)
PNG_COMPRESS_LEVEL = 1
#: the window shows at most this many pixels a side (every k-th ray): a redraw of a
#: million-pixel image in matplotlib takes ~0.1 s, a quarter of that keeps >= 10 frames/s
WINDOW_MAX_SIZE = 720
#: frames written to a folder are enlarged (whole pixels per ray) to at least this many
#: pixels on the long side, so that a small grid is still readable
MIN_FRAME_SIZE = 640
#: ... but not beyond this (a big grid is already strided to ``max_size``)
MAX_UPSCALED_SIZE = 1600
FIXTURE_COLOR = (255, 150, 40)
HOLDER_COLOR = (150, 150, 160)
STRIP_BG = (12, 12, 16)
TEXT_COLOR = (235, 235, 235)
DIM_TEXT = (160, 164, 172)


def finding_label(f) -> str:
    """What a ring says about finding ``f`` (a dict or object with ``kind``, ``line``,
    ``lines``): the kind and its line(s), e.g. ``GOUGE L22`` or ``GOUGE L22-31``."""
    get = f.get if isinstance(f, dict) else (lambda k, d=None: getattr(f, k, d))
    kind = str(get("kind", "") or "finding").upper().replace("_", " ")
    lines = [int(v) for v in (get("lines", None) or ()) if v]
    line = int(get("line", 0) or 0)
    span = get("line_range", None)   # first and last line, when ``lines`` may be cut short
    if span is not None and len(span) == 2 and span[0] != span[1]:
        return f"{kind} L{int(span[0])}-{int(span[1])}"
    if len(lines) > 1:
        return f"{kind} L{lines[0]}-{lines[-1]}"
    return f"{kind} L{line}" if line else kind


def _marks(findings) -> tuple[np.ndarray | None, list[str]]:
    """Ring positions (m, 3) and labels of ``findings`` (dicts, objects or an (m, 3) array)."""
    if findings is None:
        return None, []
    if isinstance(findings, np.ndarray):
        pts = findings.reshape(-1, 3)
        return pts, [""] * len(pts)
    pts, labels = [], []
    for f in findings:
        p = f.get("position") if isinstance(f, dict) else getattr(f, "position", f)
        if p is not None and len(p) >= 3:
            pts.append([float(v) for v in p[:3]])
            labels.append(finding_label(f) if (isinstance(f, dict) or hasattr(f, "kind")) else "")
    return np.asarray(pts, np.float64).reshape(-1, 3), labels


def _nice_ceil(x: float) -> float:
    """The smallest of 1, 2, 2.5, 5 x 10^k that is >= ``x`` (> 0)."""
    e = 10.0 ** np.floor(np.log10(x))
    for m in (1.0, 2.0, 2.5, 5.0, 10.0):
        if m * e >= x * (1 - 1e-9):
            return m * e
    return 10 * e


def _nice_floor(x: float) -> float:
    """The largest of 1, 2, 5 x 10^k that is <= ``x`` (> 0)."""
    e = 10.0 ** np.floor(np.log10(x))
    for m in (5.0, 2.0, 1.0):
        if m * e <= x * (1 + 1e-9):
            return m * e
    return e


#: the parts of the longest status line (how many lines a narrow picture wraps it onto)
STATUS_LONGEST = ["STAGE 99999", "LINE 99999", "T 9999.9 S", "X -999.999  Y -999.999  Z -999.999", "F 99999",
                  "T99 BALL 12.7", "FINDINGS 999"]


def _wrap_words(words: list[str], chars: int, gap: int) -> list[list[str]]:
    """``words`` on lines of at most ``chars`` characters, ``gap`` spaces apart (a word
    longer than a line has a line of its own)."""
    lines, line, used = [], [], 0
    for w in words:
        need = len(w) + (gap if line else 0)
        if line and used + need > chars:
            lines.append(line)
            line, used, need = [], 0, len(w)
        line.append(w)
        used += need
    return lines + [line] if line else lines


def _only_if(shown, draw):
    """A legend piece drawn only while ``shown()`` (its room is kept either way)."""
    def piece(strip, r, col, ts):
        return draw(strip if shown() else strip.copy(), r, col, ts)
    return piece


def _flow(pieces: list, width: int, ts: int, wrap: bool) -> list | None:
    """Place the legend ``pieces`` (None: a new row) left to right from column 6 at text
    scale ``ts``: rows of (piece, column). A piece passing ``width`` goes to the next row
    when ``wrap``, else the placing fails (None)."""
    scratch = np.zeros((7 * ts + 8, 4 * width + 1400, 3), np.uint8)
    rows, row, col = [], [], 6
    for piece in pieces:
        if piece is None:
            rows.append(row)
            row, col = [], 6
            continue
        end = piece(scratch, 2, col, ts)
        if end - 4 * ts > width and row:
            if not wrap:
                return None
            rows.append(row)
            row, col = [], 6
            end = piece(scratch, 2, col, ts)
        if end - 4 * ts > width and not wrap:
            return None
        row.append((piece, col))
        col = end
    rows.append(row)
    return [r for r in rows if r]


def _mm(x: float) -> str:
    return f"{x:g}" if abs(x) >= 0.1 or x == 0 else f"{x:.2g}"


def draw_circle(image: np.ndarray, frame, centre, radius: float, color, width: int = 1) -> None:
    """A circle of ``radius`` mm round world point ``centre`` on a top-view picture, in place."""
    n = max(24, int(2 * np.pi * radius / frame.spacing))
    a = np.linspace(0, 2 * np.pi, n + 1)
    c = np.asarray(centre, np.float64).reshape(3)
    pts = np.stack([c[0] + radius * np.cos(a), c[1] + radius * np.sin(a), np.full(a.size, c[2])], axis=1)
    shaded.draw_polyline(image, frame, pts, color=color, width=width)


def fixture_mask(frame, fixtures) -> np.ndarray:
    """Rays of ``frame`` (nv, nu) bool over which any of ``fixtures`` has material. A
    fixture is a ``sim.checks.collisions.Fixture`` (its ``grid`` on its own top frame), a
    DexelGrid, or an (nv, nu) bool mask already on ``frame``."""
    out = np.zeros(frame.shape, bool)
    pts = frame.ray_points()
    for fx in fixtures or ():
        if isinstance(fx, np.ndarray):
            out |= fx.reshape(frame.shape).astype(bool)
            continue
        g = getattr(fx, "grid", fx)
        top = g.top()
        f = g.frame
        loc = f.to_local(pts.reshape(-1, 3))
        i = np.rint(loc[:, 0] / f.spacing).astype(np.int64)
        j = np.rint(loc[:, 1] / f.spacing).astype(np.int64)
        ok = (i >= 0) & (i < f.nu) & (j >= 0) & (j < f.nv)
        hit = np.zeros(i.size, bool)
        hit[ok] = np.isfinite(top[j[ok], i[ok]])
        out |= hit.reshape(frame.shape)
    return out


class LiveView:
    """A redrawing shaded view of a live model, readable at a glance.

    The picture: the model Van Hook-shaded with cut areas coloured by their depth below the
    uncut stock (viridis, yellow = just below the top, dark violet = ``max_depth`` deep;
    uncut stock stays grey), the path ahead (cyan), the tool inverse-shaded at its pose,
    fixtures outlined (orange), findings ringed and labelled (``GOUGE L22``). Below it a
    text strip: program line, program time, X Y Z, feed, findings count, and a legend with
    the depth ramp and a scale bar in mm.

    Parameters
    ----------
    frame : sim.frame.Frame of the model.
    tool : a ``sim.tools.Tool`` (or a radius in mm) drawn at the tool pose, optional.
    out_dir : write frames as ``frame_000001.png`` ... here (made if missing). When None a
        window is opened, which needs a display (InputError otherwise).
    max_size : rays are strided so the model has at most this many rays a side.
    max_fps : updates arriving faster are skipped (0 = draw every update).
    color_by_move : colour faces by the move that made them (needs ``ids`` in update).
    stock_top : the uncut stock's top heights (nv, nu) mm (NaN = no stock) that depths are
        measured from; None takes the heights of the first render.
    max_depth : the depth (mm, > 0) at the end of the colour ramp; None: set from the
        program (:class:`monitor.render.feed.ViewFeed`) or the model. It grows when a cut goes deeper.
    fixtures : ``sim.checks.collisions.Fixture`` objects (or DexelGrids, or (nv, nu) bool
        masks) to outline, with their names when they have one.
    min_size : frames are enlarged by whole pixels per ray to at least this long side.
    color_by : ``"depth"`` (below the stock top, the default), ``"deviation"`` (the error
        against the design given to :meth:`render` as ``errors``: neutral within ``tol``,
        gouges red, excess blue) or ``"move"`` (the id of the move that made each face).
    tol : the ``sim.tolerance.Tolerance`` of the deviation map (its colour bar's stops).
    headless : neither a window nor files: :meth:`render` only (replay and report).
    axes : draw the work origin and millimetre ticks (:func:`.meaning.draw_axes`).
    """

    def __init__(self, frame, tool=None, out_dir=None, max_size: int | None = 1024, max_fps: float = 0.0,
                 color_by_move: bool = False, title: str = "dexmon", stock_top: np.ndarray | None = None,
                 max_depth: float | None = None, fixtures=None, min_size: int | None = None,
                 color_by: str | None = None, tol=None, headless: bool = False, axes: bool = False):
        self.frame = frame
        self.tool = tool
        self.color_by = color_by or ("move" if color_by_move else "depth")
        if self.color_by not in ("depth", "deviation", "move"):
            raise InputError(f"colour by depth, deviation or move, got {self.color_by!r}", "--color-by")
        if self.color_by == "deviation":
            from sim.tolerance import DEFAULT
            tol = tol or DEFAULT
        self.tol = tol
        self.axes = axes
        self.headless = headless
        if out_dir is None and max_size and not headless:
            max_size = min(max_size, WINDOW_MAX_SIZE)
        self.k = reduce_factor(frame.shape, max_size)
        self.sub = frame if self.k == 1 else frame.__class__(
            frame.origin, frame.direction, frame.u, frame.spacing * self.k,
            len(range(0, frame.nu, self.k)), len(range(0, frame.nv, self.k)))
        longest = max(self.sub.nu, self.sub.nv)
        if min_size is None:
            # a window is scaled by matplotlib: enlarging there only costs redraw time
            min_size = MIN_FRAME_SIZE if out_dir is not None else 0
        if headless:   # a picture asked for by size: whole pixels per ray, at most that size
            self.scale = max(1, int(min_size or 0) // longest)
        else:
            self.scale = max(1, min(int(np.ceil(min_size / longest)), max(MAX_UPSCALED_SIZE // longest, 1)))
        self.view_frame = shaded.upscaled_frame(self.sub, self.scale)
        self.text_scale = 2 if self.view_frame.nu >= 560 else 1
        self.stock_top = None if stock_top is None else self._sub(np.asarray(stock_top, np.float32))
        self.max_depth = None if max_depth is None else float(max_depth)
        self.depth_auto = max_depth is None   # the range may be set from the program
        if self.max_depth is not None and not self.max_depth > 0:
            raise InputError(f"the depth range must be a positive length in mm, got {max_depth}")
        self.fixtures = list(fixtures or ())
        self._fixture_mask = fixture_mask(self.sub, self.fixtures) if self.fixtures else None
        self._fixture_labels = self._fixture_places() if self.fixtures else []
        self.max_fps = float(max_fps)
        self.color_by_move = self.color_by == "move"
        self.frames_drawn = 0
        self.last_image: np.ndarray | None = None
        self._buf: np.ndarray | None = None
        self._base: np.ndarray | None = None   # the shaded model without overlays, one pixel a ray
        self._strip: np.ndarray | None = None  # the text strip's legend (redrawn when the range grows)
        self._last_t = -np.inf
        self.out_dir = Path(out_dir) if out_dir is not None else None
        self._fig = self._im = None
        if self.out_dir is not None:
            try:
                self.out_dir.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise InputError(f"cannot create the frames folder ({exc.strerror})", str(self.out_dir)) from exc
        elif not headless:
            if not has_display():
                raise InputError("no display for --view ($DISPLAY is not set); use --frames DIR", "--view")
            import matplotlib.pyplot as plt

            plt.ion()
            self._plt = plt
            self._fig, ax = plt.subplots(num=title)
            ax.set_axis_off()
            self._ax = ax

    # -- geometry of the picture
    def _sub(self, a: np.ndarray) -> np.ndarray:
        if a.shape != self.frame.shape:
            raise InputError(f"heights of shape {a.shape} do not fit the view's {self.frame.shape}")
        return np.ascontiguousarray(a[::self.k, ::self.k])

    @property
    def picture_shape(self) -> tuple[int, int]:
        """(rows, cols) of the model part of a frame (the text strip is below it)."""
        return self.view_frame.nv, self.view_frame.nu

    @property
    def strip_height(self) -> int:
        rows = self._status_rows + self._legend_rows
        return rows * (7 * self.text_scale) + (rows + 1) * 6 * self.text_scale // 2 + 4

    def pixel_of(self, points: np.ndarray) -> np.ndarray:
        """World points (k, 3) mm -> float (k, 2) (column, row) in the frames."""
        return shaded.to_pixels(self.view_frame, points)

    def _fixture_places(self) -> list[tuple[np.ndarray, str]]:
        out = []
        for k, fx in enumerate(self.fixtures):
            name = getattr(fx, "name", None)
            if not name or isinstance(fx, np.ndarray):
                continue
            m = fixture_mask(self.sub, [fx])
            if m.any():
                j, i = np.nonzero(m)
                p = self.sub.origin + (i.min() * self.sub.u + j.max() * self.sub.v) * self.sub.spacing
                out.append((p, str(name)))
        return out

    # -- colour by depth
    def expect_depth(self, deepest: float) -> None:
        """Fix the colour ramp to span ``deepest`` mm below the stock top (the program's
        deepest point, known before it cuts), unless the ramp was given."""
        if self.depth_auto and np.isfinite(deepest) and deepest > 0:
            self.max_depth = max(_nice_ceil(deepest), self.max_depth or 0.0)
            self.depth_auto = False
            self._base = self._strip = None   # shade everything with this range

    def _depth_setup(self, h: np.ndarray) -> bool:
        """Fix the stock top (first heights) and the depth range; True when the range grew
        (everything must be shaded again)."""
        if self.stock_top is None:
            self.stock_top = h.copy()
        with np.errstate(invalid="ignore"):
            d = self.stock_top - h
        deepest = float(np.nanmax(d)) if np.isfinite(d).any() else 0.0
        if self.max_depth is None:
            self.max_depth = _nice_ceil(max(deepest, 1.0))
            return True
        if deepest > self.max_depth * (1 + 1e-6):
            self.max_depth = _nice_ceil(deepest * 1.25)
            return True
        return False

    def _shade(self, h: np.ndarray, top: np.ndarray, out=None) -> np.ndarray:
        return shaded.shade(h, self.sub.spacing, stock_top=top, max_depth=self.max_depth, out=out)

    # -- drawing
    def render(self, heights_or_grid, tool_pose=None, path_ahead=None, findings=None,
               ids: np.ndarray | None = None, changed: tuple[int, int, int, int] | None = None,
               status: dict | None = None, errors: np.ndarray | None = None, moves: dict | None = None) -> np.ndarray:
        """The frame as RGB uint8 (rows, cols, 3) without showing or writing it.

        ``heights_or_grid``: (nv, nu) heights mm or a DexelGrid; ``tool_pose``: tip (3,)
        mm (or a 6-vector whose first three are the tip); ``path_ahead`` (k, 3);
        ``findings``: dicts with ``position`` (and ``kind``, ``line``, ``lines`` for the
        label), objects with ``.position`` or (m, 3). ``status``: optional ``line``
        (program line), ``time`` (program time s), ``feed`` (mm/min) for the text strip.
        ``changed``: the ray box ``(j0, j1, i0, i1)`` (end exclusive) holding every ray
        whose height changed since the previous render: only that box (and the pixels
        whose normals it moves) is shaded again (Van Hook: redraw what the tool
        touched); None shades everything. ``errors`` (nv, nu) signed mm against the
        design colours the surface when ``color_by="deviation"``. ``moves``: the path as
        ``{"start": (k, 3), "end": (k, 3), "rapid": (k,) bool}`` (feeds solid, rapids
        dashed), drawn instead of ``path_ahead``. ``status`` may also give ``stage`` and
        ``tool`` (a short text such as ``T1 FLAT 6``).
        """
        heights = heights_or_grid.top() if hasattr(heights_or_grid, "top") else np.asarray(heights_or_grid,
                                                                                          np.float32)
        h = self._sub(heights)
        grown = self._depth_setup(h)
        if grown:
            self._strip = None
        if self.color_by == "deviation" and errors is not None:
            from monitor.render import meaning

            idx = meaning.deviation_index(self._sub(np.asarray(errors, np.float64)), self.tol)
            self._base = shaded.shade(h, self.sub.spacing, ids=idx, palette=meaning.deviation_palette(),
                                      out=self._base)
        elif ids is not None and self.color_by_move:
            self._base = shaded.shade(h, self.sub.spacing, ids=self._sub(ids), out=self._base)
        elif changed is None or self._base is None or grown:
            self._base = self._shade(h, self.stock_top, out=self._base)
        else:
            self._reshade(h, changed)
        return self._compose(h, tool_pose, path_ahead, findings, status, moves)

    def _reshade(self, h: np.ndarray, changed) -> None:
        k = self.k
        nv, nu = h.shape
        j0, j1, i0, i1 = changed
        if j1 > j0 and i1 > i0:
            # the changed rays in picture rays, grown by one: their neighbours' normals moved
            a0, a1 = max(j0 // k - 1, 0), min((j1 - 1) // k + 2, nv)
            b0, b1 = max(i0 // k - 1, 0), min((i1 - 1) // k + 2, nu)
            # shaded with one more ray around, so the differences are those of the whole
            w0, w1, v0, v1 = max(a0 - 1, 0), min(a1 + 1, nv), max(b0 - 1, 0), min(b1 + 1, nu)
            part = self._shade(h[w0:w1, v0:v1], self.stock_top[w0:w1, v0:v1])
            # shade() flips rows (+v up): ray row j of the window is picture row w1-1-j
            self._base[nv - a1:nv - a0, b0:b1] = part[w1 - a1:w1 - a0, b0 - v0:b1 - v0]

    def _compose(self, h, tool_pose, path_ahead, findings, status, moves=None) -> np.ndarray:
        s = self.scale
        rows, cols = self.picture_shape
        shape = (rows + self.strip_height, cols, 3)
        if self._buf is None or self._buf.shape != shape:
            self._buf = np.empty(shape, np.uint8)
        img = self._buf
        pic = img[:rows]
        shaded.upscale(self._base, s, out=pic) if s > 1 else np.copyto(pic, self._base)
        vf = self.view_frame
        if self._fixture_mask is not None:
            shaded.draw_outline(pic, self.sub, self._fixture_mask, FIXTURE_COLOR, scale=s)
            for p, name in self._fixture_labels:
                c, r = shaded.to_pixels(vf, p[None])[0]
                shaded.draw_text(pic, name, int(r) - 7 * self.text_scale - 4, int(c) + 2, FIXTURE_COLOR,
                                 scale=self.text_scale, background=shaded.LABEL_BG)
        if self.axes:
            from monitor.render import meaning

            meaning.draw_axes(pic, vf, self.text_scale)
        if moves is not None and len(moves.get("start", ())):
            from monitor.render import meaning

            meaning.draw_moves(pic, vf, moves["start"], moves["end"], moves["rapid"], width=min(s, 2))
        elif path_ahead is not None and len(path_ahead) > 1:
            shaded.draw_polyline(pic, vf, path_ahead, width=min(s, 2))
        tip = None if tool_pose is None else np.asarray(tool_pose, np.float64).reshape(-1)[:3]
        if tip is not None and not np.all(np.isfinite(tip)):
            tip = None
        if tip is not None and self.tool is not None:
            shaded.draw_tool(pic, vf, h, tip, self.tool, scale=s)
            holder = getattr(self.tool, "holder", None)
            if holder is not None and getattr(holder, "max_radius", 0) > 0:
                # seen from above the holder is a circle round the tool: where it passes
                draw_circle(pic, vf, tip, float(holder.max_radius), HOLDER_COLOR, max(1, min(s, 2)))
        pts, labels = _marks(findings)
        if pts is not None and len(pts):
            shaded.draw_markers(pic, vf, pts)
            if any(labels):
                keep = [k for k, t in enumerate(labels) if t]
                shaded.draw_labels(pic, vf, pts[keep], [labels[k] for k in keep], scale=self.text_scale)
        self._draw_strip(img[rows:], tip, status or {}, 0 if pts is None else len(pts))
        return img

    def _draw_strip(self, strip: np.ndarray, tip, status: dict, n_findings: int) -> None:
        ts = self.text_scale
        if self._strip is None or self._strip.shape != strip.shape:
            self._strip = self._legend(strip.shape)
        np.copyto(strip, self._strip)
        parts = []
        if status.get("stage") is not None:
            parts.append(f"STAGE {int(status['stage'])}")
        line = status.get("line")
        parts.append(f"LINE {int(line)}" if line else "LINE -")
        t = status.get("time")
        parts.append(f"T {t:.1f} S" if t is not None and np.isfinite(t) else "T -")
        if tip is not None:
            parts.append(f"X {tip[0]:.3f}  Y {tip[1]:.3f}  Z {tip[2]:.3f}")
        else:
            parts.append("X -  Y -  Z -")
        feed = status.get("feed")
        parts.append(f"F {feed:.0f}" if feed is not None and np.isfinite(feed) else "F -")
        if status.get("tool"):
            parts.append(str(status["tool"]).upper())
        parts.append(f"FINDINGS {n_findings}")
        width = strip.shape[1] - 12
        sc = ts if shaded.text_size("   ".join(parts), ts)[1] <= width else 1
        lines = _wrap_words(parts, width // (shaded.GLYPH_W * sc), 3) if self._status_rows > 1 else [parts]
        for k, line in enumerate(lines):
            col = 6
            for part in line:
                # the count in the finding colour, so it is seen without reading the line
                color = shaded.FINDING_COLOR if n_findings and part.startswith("FINDINGS") else TEXT_COLOR
                shaded.draw_text(strip, part, 4 * ts + k * 10 * sc, col, color, scale=sc)
                col += shaded.GLYPH_W * sc * (len(part) + 3)

    def _legend(self, shape) -> np.ndarray:
        """The strip's legend rows (see :meth:`_legend_plan`) on a strip of ``shape``."""
        # drawn on a wider strip (a piece wider than a tiny picture is cut, not an error)
        strip = np.empty((shape[0], shape[1] + 1400, 3), np.uint8)
        strip[:] = STRIP_BG
        ts, rows = self._legend_plan(shape[1])
        th = 7 * ts
        for k, row in enumerate(rows):
            r = shape[0] - th - 5 * ts - (th + 3 * ts) * (len(rows) - 1 - k)
            for draw, col in row:
                draw(strip, r, col, ts)
        return np.ascontiguousarray(strip[:, :shape[1]])

    def _legend_plan(self, width: int) -> tuple[int, list]:
        """(text scale, rows of (piece, column)) of the legend on a picture ``width`` px
        wide: at the text's scale on its rows when that fits, else at the smallest scale,
        each row wrapped onto the next where it would pass the right edge (a narrow
        picture: nothing is cut off). The colour meaning (uncut stock and the depth ramp,
        or the deviation bar) comes first; with axes or a deviation map the scale bar and
        the overlay colours start a row of their own."""
        plan = self.__dict__.setdefault("_plans", {}).get(width)
        if plan is not None:
            return plan
        for ts in range(self.text_scale, 0, -1):
            rows = _flow(self._legend_pieces(width), width, ts, wrap=ts == 1)
            if rows is not None:
                self._plans[width] = plan = (ts, rows)
                return plan

    @property
    def _status_rows(self) -> int:
        """Lines of the status text: more than one on a picture too narrow for the
        longest at the smallest scale."""
        return len(_wrap_words(STATUS_LONGEST, (self.picture_shape[1] - 12) // shaded.GLYPH_W, 3))

    @property
    def _legend_rows(self) -> int:
        """Rows of the legend on this view's pictures."""
        return len(self._legend_plan(self.picture_shape[1])[1])

    def _legend_pieces(self, width: int) -> list:
        """The legend's pieces in order: functions ``draw(strip, row, col, ts) -> the column
        after it``; ``None`` where a new row starts."""
        def text(t, color=DIM_TEXT, gap=2):
            return lambda strip, r, col, ts: shaded.draw_text(strip, t, r, col, color, scale=ts)[3] + gap * ts

        def swatch(color, label, line=False):
            def draw(strip, r, col, ts):
                th, sw = 7 * ts, 21 * ts
                if line:   # a path colour: a thick line
                    strip[r + th // 2 - ts:r + th // 2 + ts, col:col + sw] = color
                else:
                    strip[r:r + th, col:col + sw] = color
                return shaded.draw_text(strip, label, r, col + sw + 3 * ts, DIM_TEXT, scale=ts)[3] + 6 * ts
            return draw

        if self.color_by == "deviation":
            pieces = self._deviation_pieces(text)
        elif self.color_by == "move":
            pieces = [text("COLOUR: MOVE ID", gap=8)]
        else:
            pieces = [swatch(shaded.STOCK_COLOR, "UNCUT"), self._depth_ramp]
        if self.axes or self.color_by == "deviation":
            pieces.append(None)
        pieces.append(self._scale_bar(width))
        from monitor.render.meaning import RAPID_COLOR

        for color, label in ((shaded.PATH_COLOR, "FEED" if self.axes else "PATH"), (RAPID_COLOR, "RAPID"),
                             (shaded.TOOL_COLOR, "TOOL"), (HOLDER_COLOR, "HOLDER"),
                             (shaded.FINDING_COLOR, "FINDING"), (FIXTURE_COLOR, "FIXTURE")):
            if label == "FIXTURE" and not self.fixtures or label == "RAPID" and not self.axes:
                continue
            # HOLDER is planned for always (the tool may change between pictures), drawn with one
            pieces.append(_only_if(lambda: label != "HOLDER" or getattr(self.tool, "holder", None) is not None,
                                   swatch(color, label, line=True)))
        return pieces

    def _depth_ramp(self, strip, r: int, col: int, ts: int) -> int:
        """``DEPTH 0`` [the ramp, shallow to deep] ``-max MM``; planned as wide as a
        3-digit range (the range grows as the cut deepens)."""
        th = 7 * ts
        ramp = shaded.depth_ramp()
        rw = 40 * ts
        col = shaded.draw_text(strip, "DEPTH 0", r, col, DIM_TEXT, scale=ts)[3] + 2 * ts
        strip[r:r + th, col:col + rw] = ramp[np.linspace(0, len(ramp) - 1, rw).round().astype(int)][None, :, :]
        col += rw + 3 * ts
        label = f"-{_mm(self.max_depth if self.max_depth is not None else 1.0)} MM"
        end = shaded.draw_text(strip, label, r, col, DIM_TEXT, scale=ts)[3]
        return max(end, col + shaded.text_size("-888.8 MM", ts)[1]) + 8 * ts

    def _scale_bar(self, width: int):
        """The scale bar: a round length about a sixth of a picture ``width`` px wide."""
        px_mm = 1.0 / self.view_frame.spacing
        length = _nice_floor(max(width / 6 / px_mm, 1e-3))
        bar = max(int(round(length * px_mm)), 2)

        def draw(strip, r, col, ts):
            th = 7 * ts
            strip[r + th // 2 - ts:r + th // 2 + ts, col:col + bar] = TEXT_COLOR
            strip[r:r + th, col:col + ts] = TEXT_COLOR
            strip[r:r + th, col + bar - ts:col + bar] = TEXT_COLOR
            return shaded.draw_text(strip, f"{_mm(length)} MM", r, col + bar + 3 * ts, DIM_TEXT, scale=ts)[3] + 8 * ts
        return draw

    def _deviation_pieces(self, text) -> list:
        """The deviation map's colour bar in three pieces (kept on one row when it fits):
        the gouge scale (dark at -interest, light at -gouge), the neutral band, the excess
        scale (light at +undercut, dark at +interest), each end labelled in mm."""
        from monitor.render import meaning

        tol = self.tol
        pal = meaning.deviation_palette()
        n = meaning.SCALE_STEPS

        def scale(first, last, idx):
            def draw(strip, r, col, ts):
                rw = 24 * ts
                for t, color in first:
                    col = text(t, color)(strip, r, col, ts) + (ts if t in ("GOUGE",) else 0)
                strip[r:r + 7 * ts, col:col + rw] = pal[np.linspace(*idx, rw).round().astype(int)][None]
                col += rw + 2 * ts
                for t, color in last:
                    col = text(t, color)(strip, r, col + (ts if t == "EXCESS" else 0), ts)
                return col + 4 * ts
            return draw

        def neutral(strip, r, col, ts):
            strip[r:r + 7 * ts, col:col + 8 * ts] = pal[0]
            return text("OK")(strip, r, col + 9 * ts, ts) + 4 * ts

        gouge = scale([("GOUGE", meaning.GOUGE_DARK), (f"-{_mm(tol.interest)}", DIM_TEXT)],
                      [(f"-{_mm(tol.gouge)}", DIM_TEXT)], (n, 1))            # dark (deep) to light
        excess = scale([(f"+{_mm(tol.undercut)}", DIM_TEXT)],
                       [(f"+{_mm(tol.interest)} MM", DIM_TEXT), ("EXCESS", meaning.EXCESS_DARK)],
                       (n + 1, 2 * n))                                              # light to dark
        return [gouge, neutral, excess]

    def update(self, heights_or_grid, tool_pose=None, path_ahead=None, findings=None,
               ids: np.ndarray | None = None, status: dict | None = None) -> bool:
        """Redraw with the new state; False when skipped by ``max_fps``."""
        now = time.monotonic()
        if self.max_fps > 0 and now - self._last_t < 1.0 / self.max_fps:
            return False
        self._last_t = now
        self.present(self.render(heights_or_grid, tool_pose, path_ahead, findings, ids, status=status))
        return True

    def present(self, img: np.ndarray) -> None:
        """Show ``img`` (RGB uint8 from :meth:`render`) in the window, or write it as the
        next numbered PNG. The window must be presented from the thread that made it."""
        self.frames_drawn += 1
        self.last_image = img
        if self.headless:
            return
        if self.out_dir is not None:
            import imageio.v3 as iio

            # zlib level 1: a third of the default's time for a few % more bytes
            iio.imwrite(self.out_dir / f"frame_{self.frames_drawn:06d}.png", np.ascontiguousarray(img),
                        extension=".png", compress_level=PNG_COMPRESS_LEVEL)
        else:
            if self._im is None:
                self._im = self._ax.imshow(img, interpolation="nearest")
            else:
                self._im.set_data(img)
            self._fig.canvas.draw_idle()
            self._fig.canvas.flush_events()

    def process_events(self) -> None:
        """Let the window handle its events (resize, close) between frames."""
        if self._fig is not None:
            self._fig.canvas.flush_events()

    @property
    def is_window(self) -> bool:
        return self.out_dir is None and not self.headless

    def close(self) -> None:
        if self._fig is not None:
            self._plt.close(self._fig)
            self._fig = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def finding_marks(findings, wco=None) -> list[dict]:
    """``findings`` (session records) as ``{"position", "kind", "line", "lines"}`` dicts
    for :meth:`LiveView.render`, in work coordinates: travel limits are told in machine coordinates, so ``wco``
    (6,) is taken off them."""
    out = []
    w = np.zeros(3) if wco is None else np.asarray(wco, np.float64).reshape(-1)[:3]
    for f in list(findings):
        get = f.get if isinstance(f, dict) else (lambda k, d=None, f=f: getattr(f, k, d))
        p = get("position")
        if p is None or len(p) < 3:
            continue
        q = np.asarray([float(v) for v in p[:3]])
        if get("kind") == "travel_limit":
            q = q - w
        if np.all(np.isfinite(q)):
            out.append({"position": q, "kind": get("kind", ""), "line": get("line", 0),
                        "lines": get("lines", None), "line_range": get("line_range", None)})
    return out
