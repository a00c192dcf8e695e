"""Van Hook's real-time shaded display for ``dexmon live|dry-run --view`` / ``--frames DIR``.

:class:`LiveView` redraws the shaded model (one pixel per ray, :mod:`.shaded`) with the
tool inverse-shaded at its pose, the path ahead and the predicted findings ringed. With a
display it shows a window (matplotlib, updated in place); without one, or when ``out_dir``
is given, it writes the frames as numbered PNG files.

:class:`ViewFeed` connects a view to the session loop without slowing the loop down: the
loop hands over only what changed (the new tops of the rays it cut, the tool pose, the
progress, the findings) and a render thread of its own keeps a private copy of the top
heights, draws at most ``fps`` frames a second and writes them (``--frames``) or passes
them to the main thread that owns the window (``--view``).
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numba as nb
import numpy as np

from monitor.render import shaded
from monitor.render.animate import reduce_factor
from monitor.render.view3d import has_display
from sim.dexel_store import ray_top
from sim.errors import InputError


#: zlib level of the PNG frames (1: fast; the default 6 is three times slower)
PNG_COMPRESS_LEVEL = 1
#: the window shows at most this many pixels a side (every k-th ray): a redraw of a
#: million-pixel image in matplotlib takes ~0.1 s, a quarter of that keeps >= 10 frames/s
WINDOW_MAX_SIZE = 720


@nb.njit(cache=True, nogil=True)
def _tops_of(S, rays, out):
    for k in range(rays.size):
        out[k] = ray_top(S, rays[k])


def tops_of(grid, rays: np.ndarray) -> np.ndarray:
    """Top (largest ``s``, mm) of the material on each of ``rays`` (k,) int64 flat ray
    indices of ``grid``, float32 (k,); NaN where a ray is empty. O(k): the live loop
    calls it with the rays one step changed."""
    rays = np.ascontiguousarray(rays, dtype=np.int64)
    out = np.empty(rays.size, np.float32)
    if rays.size:
        _tops_of(grid.S, rays, out)
    return out


def _positions(findings) -> np.ndarray | None:
    if findings is None:
        return None
    if isinstance(findings, np.ndarray):
        return findings.reshape(-1, 3)
    pts = []
    for f in findings:
        p = f.get("position") if isinstance(f, dict) else getattr(f, "position", f)
        if p is not None and len(p) >= 3:
            pts.append([float(v) for v in p[:3]])
    return np.asarray(pts, np.float64).reshape(-1, 3)


class LiveView:
    """A redrawing shaded view of a live model.

    Parameters
    ----------
    frame : sim.frame.Frame of the model.
    tool : a ``sim.tools.Tool`` (or a radius in mm) drawn at the tool pose, optional.
    out_dir : write frames as ``frame_000001.png`` ... here (made if missing). When None a
        window is opened, which needs a display (InputError otherwise).
    max_size : pictures at most this many pixels a side (rays are strided to fit).
    max_fps : updates arriving faster are skipped (0 = draw every update).
    color_by_move : colour faces by the move that made them (needs ``ids`` in update).
    """

    def __init__(self, frame, tool=None, out_dir=None, max_size: int | None = 1024, max_fps: float = 0.0,
                 color_by_move: bool = False, title: str = "dexmon"):
        self.frame = frame
        self.tool = tool
        if out_dir is None and max_size:
            max_size = min(max_size, WINDOW_MAX_SIZE)
        self.k = reduce_factor(frame.shape, max_size)
        self.sub = frame if self.k == 1 else frame.__class__(
            frame.origin, frame.direction, frame.u, frame.spacing * self.k,
            len(range(0, frame.nu, self.k)), len(range(0, frame.nv, self.k)))
        self.max_fps = float(max_fps)
        self.color_by_move = color_by_move
        self.frames_drawn = 0
        self.last_image: np.ndarray | None = None
        self._buf: np.ndarray | None = None
        self._base: np.ndarray | None = None   # the shaded model without overlays
        self._last_t = -np.inf
        self.out_dir = Path(out_dir) if out_dir is not None else None
        self._fig = self._im = None
        if self.out_dir is not None:
            try:
                self.out_dir.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise InputError(f"cannot create the frames folder ({exc.strerror})", str(self.out_dir)) from exc
        else:
            if not has_display():
                raise InputError("no display for --view ($DISPLAY is not set); use --frames DIR", "--view")
            import matplotlib.pyplot as plt

            plt.ion()
            self._plt = plt
            self._fig, ax = plt.subplots(num=title)
            ax.set_axis_off()
            self._ax = ax

    def render(self, heights_or_grid, tool_pose=None, path_ahead=None, findings=None,
               ids: np.ndarray | None = None, changed: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """The frame as RGB uint8 (rows, cols, 3) without showing or writing it.

        ``heights_or_grid``: (nv, nu) heights mm or a DexelGrid; ``tool_pose``: tip (3,)
        mm (or a 6-vector whose first three are the tip); ``path_ahead`` (k, 3);
        ``findings``: dicts with ``position``, objects with ``.position`` or (m, 3).
        ``changed``: the ray box ``(j0, j1, i0, i1)`` (end exclusive) holding every ray
        whose height changed since the previous render: only that box (and the pixels
        whose normals it moves) is shaded again (Van Hook: redraw what the tool
        touched); None shades everything.
        """
        if ids is None and not self.color_by_move:
            return self._render_incremental(heights_or_grid, tool_pose, path_ahead, findings, changed)
        if hasattr(heights_or_grid, "top"):
            heights = heights_or_grid.top()
        else:
            heights = np.asarray(heights_or_grid, np.float32)
        if heights.shape != self.frame.shape:
            raise InputError(f"heights of shape {heights.shape} do not fit the view's {self.frame.shape}")
        k = self.k
        h = heights[::k, ::k]
        idk = ids[::k, ::k] if (ids is not None and self.color_by_move) else None
        tip = None
        if tool_pose is not None:
            tip = np.asarray(tool_pose, np.float64).reshape(-1)[:3]
            if not np.all(np.isfinite(tip)):
                tip = None
        self._buf = shaded.picture(h, self.sub, ids=idk, tool=self.tool if tip is not None else None,
                                   tip=tip, path_ahead=path_ahead, findings=_positions(findings),
                                   out=self._buf)
        return self._buf

    def _render_incremental(self, heights_or_grid, tool_pose, path_ahead, findings, changed) -> np.ndarray:
        heights = heights_or_grid.top() if hasattr(heights_or_grid, "top") else np.asarray(heights_or_grid,
                                                                                          np.float32)
        if heights.shape != self.frame.shape:
            raise InputError(f"heights of shape {heights.shape} do not fit the view's {self.frame.shape}")
        k = self.k
        h = heights[::k, ::k]
        nv, nu = h.shape
        if changed is None or self._base is None:
            self._base = shaded.shade(h, self.sub.spacing, out=self._base)
        else:
            j0, j1, i0, i1 = changed
            if j1 > j0 and i1 > i0:
                # the changed rays in picture rays, grown by one: their neighbours' normals moved
                a0, a1 = max(j0 // k - 1, 0), min((j1 - 1) // k + 2, nv)
                b0, b1 = max(i0 // k - 1, 0), min((i1 - 1) // k + 2, nu)
                # shaded with one more ray around, so the differences are those of the whole
                w0, w1, v0, v1 = max(a0 - 1, 0), min(a1 + 1, nv), max(b0 - 1, 0), min(b1 + 1, nu)
                part = shaded.shade(h[w0:w1, v0:v1], self.sub.spacing)
                # shade() flips rows (+v up): ray row j of the window is picture row w1-1-j
                self._base[nv - a1:nv - a0, b0:b1] = part[w1 - a1:w1 - a0, b0 - v0:b1 - v0]
        if self._buf is None or self._buf.shape != self._base.shape:
            self._buf = np.empty_like(self._base)
        img = self._buf
        np.copyto(img, self._base)
        if path_ahead is not None and len(path_ahead) > 1:
            shaded.draw_polyline(img, self.sub, path_ahead)
        tip = None if tool_pose is None else np.asarray(tool_pose, np.float64).reshape(-1)[:3]
        if tip is not None and self.tool is not None and np.all(np.isfinite(tip)):
            shaded.draw_tool(img, self.sub, h, tip, self.tool)
        pts = _positions(findings)
        if pts is not None and len(pts):
            shaded.draw_markers(img, self.sub, pts)
        return img

    def update(self, heights_or_grid, tool_pose=None, path_ahead=None, findings=None,
               ids: np.ndarray | None = None) -> bool:
        """Redraw with the new state; False when skipped by ``max_fps``."""
        now = time.monotonic()
        if self.max_fps > 0 and now - self._last_t < 1.0 / self.max_fps:
            return False
        self._last_t = now
        self.present(self.render(heights_or_grid, tool_pose, path_ahead, findings, ids))
        return True

    def present(self, img: np.ndarray) -> None:
        """Show ``img`` (RGB uint8 from :meth:`render`) in the window, or write it as the
        next numbered PNG. The window must be presented from the thread that made it."""
        self.frames_drawn += 1
        self.last_image = img
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
        return self.out_dir is None

    def close(self) -> None:
        if self._fig is not None:
            self._plt.close(self._fig)
            self._fig = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def path_ahead(path, progress: float, end: float, max_points: int = 4000) -> np.ndarray:
    """The program path from program time ``progress`` to ``end`` (s), float64 (k, 3) mm:
    the point at ``progress``, then every segment end up to ``end`` (at most
    ``max_points``, the nearest kept). ``path`` is a :class:`monitor.sync.ProgramPath`."""
    if path is None or len(path) == 0 or not np.isfinite(progress):
        return np.zeros((0, 3))
    k0 = path.segment_at(progress)
    k1 = min(path.segment_at(max(end, progress)) + 1, k0 + max_points)
    return np.concatenate([path.point_at(progress)[None, :], path.p1[k0:k1]])


def finding_positions(findings, wco=None) -> np.ndarray:
    """Where to ring ``findings`` (session records) on the live model, float64 (m, 3) mm in
    work coordinates: travel limits are told in machine coordinates, so ``wco`` (6,) is
    taken off them."""
    pts = []
    w = np.zeros(3) if wco is None else np.asarray(wco, np.float64).reshape(-1)[:3]
    for f in list(findings):
        p = f.get("position") if isinstance(f, dict) else getattr(f, "position", None)
        if p is None or len(p) < 3:
            continue
        q = np.asarray([float(v) for v in p[:3]])
        kind = f.get("kind") if isinstance(f, dict) else getattr(f, "kind", "")
        if kind == "travel_limit":
            q = q - w
        if np.all(np.isfinite(q)):
            pts.append(q)
    return np.asarray(pts, np.float64).reshape(-1, 3)


class ViewFeed:
    """Draw a :class:`LiveView` of a live model from its own thread.

    The session loop calls :meth:`post` once per state with only what changed; posting
    costs a lock and two list appends. The render thread applies the posted ray tops to
    its own copy of the heights, so it never reads the model the loop is cutting, and
    draws at most ``fps`` frames a second (states arriving in between are merged into the
    next frame). With ``--frames`` the render thread writes the PNGs itself; a window must
    be drawn by the main thread, which calls :meth:`pump` while the loop runs elsewhere.

    Parameters
    ----------
    view : LiveView
    heights : float32 (nv, nu) mm, the model's top heights when the feed starts.
    path : monitor.sync.ProgramPath or None, for the path ahead.
    horizon : callable(progress s) -> program time s where the path ahead ends.
    fps : frames per second at most.
    """

    def __init__(self, view: LiveView, heights: np.ndarray, path=None, horizon=None, fps: float = 15.0):
        if not fps > 0:
            raise InputError(f"expected a positive number of frames per second, got {fps}", "--view-fps")
        self.view = view
        self.path = path
        self.horizon = horizon or (lambda progress: progress + 5.0)
        self.period = 1.0 / float(fps)
        self.heights = np.array(heights, np.float32, copy=True).reshape(view.frame.shape)
        self._flat = self.heights.reshape(-1)
        self._cond = threading.Condition()
        self._rays: list[np.ndarray] = []
        self._tops: list[np.ndarray] = []
        self._pose = None        # (tip (3,), tool, progress, findings, wco)
        self._posted = 0         # posts so far
        self._drawn = 0          # posts reflected in the last frame
        self._ready: np.ndarray | None = None   # a frame waiting for the window
        self._stop = False
        self.frame_seconds: list[float] = []    # render (+ write) time of every frame
        self._first = True                       # the first frame shades everything
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="dexmon live view", daemon=True)

    def start(self) -> "ViewFeed":
        self._thread.start()
        return self

    @property
    def frames(self) -> int:
        return len(self.frame_seconds)

    # -- the loop's side
    def post(self, rays: np.ndarray | None, tops: np.ndarray | None, tip=None, tool=None,
             progress: float | None = None, findings=None, wco=None) -> None:
        """Hand over one state: ``rays`` (k,) int64 the step changed and their new ``tops``
        (k,) float32 mm, the tool ``tip`` (3,) mm in work coordinates and the ``tool``
        there, the program ``progress`` s, the ``findings`` list (read, not copied, by
        the render thread) and the work offset ``wco``."""
        with self._cond:
            if rays is not None and len(rays):
                self._rays.append(rays)
                self._tops.append(tops)
            self._pose = (tip, tool, progress, findings, wco)
            self._posted += 1
            self._cond.notify_all()

    # -- the render thread
    def _run(self) -> None:
        last = -np.inf
        try:
            while True:
                with self._cond:
                    self._cond.wait_for(lambda: self._stop or self._posted != self._drawn)
                    if self._posted == self._drawn:
                        return  # stopping, and everything posted is drawn
                    # the frame budget: merge what arrives meanwhile into one frame
                    wait = last + self.period - time.monotonic()
                    if wait > 0 and not self._stop:
                        self._cond.wait_for(lambda: self._stop, wait)
                    rays, tops, self._rays, self._tops = self._rays, self._tops, [], []
                    pose, self._drawn = self._pose, self._posted
                last = time.monotonic()
                self._draw(rays, tops, pose)
        except BaseException as exc:  # noqa: BLE001 - a view failure must not stop the monitor
            self.error = exc
            with self._cond:
                self._cond.notify_all()

    def _draw(self, rays, tops, pose) -> None:
        t0 = time.perf_counter()
        changed = (0, 0, 0, 0)
        if rays:
            for r, h in zip(rays, tops):  # in posting order: a ray cut twice keeps its latest top
                self._flat[r] = h
            nu = self.view.frame.nu
            lo = min(int(r.min()) for r in rays)
            hi = max(int(r.max()) for r in rays)
            cols = np.concatenate([r % nu for r in rays]) if len(rays) > 1 else rays[0] % nu
            changed = (lo // nu, hi // nu + 1, int(cols.min()), int(cols.max()) + 1)
        if self._first:
            changed, self._first = None, False
        tip, tool, progress, findings, wco = pose if pose is not None else (None,) * 5
        ahead = None
        if progress is not None and self.path is not None:
            ahead = path_ahead(self.path, progress, self.horizon(progress))
        if tool is not None:
            self.view.tool = tool
        img = self.view.render(self.heights, tip, ahead, finding_positions(findings or (), wco), changed=changed)
        if self.view.is_window:
            with self._cond:
                self._ready = img.copy()
                self._cond.notify_all()
        else:
            self.view.present(img)
        self.frame_seconds.append(time.perf_counter() - t0)

    # -- the main thread's side (window)
    def pump(self, timeout: float) -> bool:
        """Show the newest frame in the window if one is ready within ``timeout`` s, and let
        the window handle its events; True if a frame was shown."""
        with self._cond:
            self._cond.wait_for(lambda: self._ready is not None or self.error is not None
                                or (self._stop and not self._thread.is_alive()), timeout)
            img, self._ready = self._ready, None
        if img is not None:
            self.view.present(img)
        else:
            self.view.process_events()
        return img is not None

    def close(self, timeout: float = 10.0) -> None:
        """Draw what is still posted, stop the render thread and (window) show the last
        frame."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        if self._thread.is_alive():
            self._thread.join(timeout)
        if self.view.is_window and self._ready is not None:
            img, self._ready = self._ready, None
            self.view.present(img)
