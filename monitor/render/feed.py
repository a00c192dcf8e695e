"""Feed a :class:`monitor.render.live.LiveView` from the session loop without slowing it.

:class:`ViewFeed` takes only what changed from the loop (the new tops of the rays it cut,
the tool pose, the progress, the findings); a render thread of its own keeps a private
copy of the top heights, draws at most ``fps`` frames a second and writes them
(``--frames``) or passes them to the main thread that owns the window (``--view``).
"""

from __future__ import annotations

import threading
import time

import numba as nb
import numpy as np

from monitor.render.live import LiveView, finding_marks
from sim.dexel_store import ray_top
from sim.errors import InputError


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


def path_ahead(path, progress: float, end: float, max_points: int = 4000) -> np.ndarray:
    """The program path from program time ``progress`` to ``end`` (s), float64 (k, 3) mm:
    the point at ``progress``, then every segment end up to ``end`` (at most
    ``max_points``, the nearest kept). ``path`` is a :class:`monitor.sync.ProgramPath`."""
    if path is None or len(path) == 0 or not np.isfinite(progress):
        return np.zeros((0, 3))
    k0 = path.segment_at(progress)
    k1 = min(path.segment_at(max(end, progress)) + 1, k0 + max_points)
    return np.concatenate([path.point_at(progress)[None, :], path.p1[k0:k1]])


def feed_status(path, progress: float | None) -> dict:
    """The text strip's program state at program time ``progress`` (s) of ``path`` (a
    :class:`monitor.sync.ProgramPath`): ``line``, ``time`` s, ``feed`` mm/min (the planned
    speed of the segment there)."""
    if path is None or len(path) == 0 or progress is None or not np.isfinite(progress):
        return {"time": progress}
    k = path.segment_at(progress)
    dt = float(path.t1[k] - path.t0[k])
    feed = 60.0 * float(path.s1[k] - path.s0[k]) / dt if dt > 0 else None
    row = int(path.row[k])
    line = int(path.lines[row]) if 0 <= row < len(path.lines) else None
    return {"line": line, "time": float(progress), "feed": feed}


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
    moves : the move table (the model's frame) or None: with it the path drawn is the
        moves near the machine's row (feeds solid, rapids dashed), as the replay
        pictures draw it (:func:`monitor.render.runpicture.path_near`), instead of the
        path ahead.
    """

    def __init__(self, view: LiveView, heights: np.ndarray, path=None, horizon=None, fps: float = 15.0,
                 moves=None):
        if not fps > 0:
            raise InputError(f"expected a positive number of frames per second, got {fps}", "--view-fps")
        self.view = view
        self.path = path
        self.moves = moves if moves is not None and len(moves) else None
        self.horizon = horizon or (lambda progress: progress + 5.0)
        self.period = 1.0 / float(fps)
        self.heights = np.array(heights, np.float32, copy=True).reshape(view.frame.shape)
        if view.stock_top is None:
            view.stock_top = view._sub(self.heights)
        if path is not None and len(path):
            # the colour ramp spans the program's deepest point below the stock
            top = np.nanmax(self.heights) if np.isfinite(self.heights).any() else np.nan
            view.expect_depth(float(top - min(path.p0[:, 2].min(), path.p1[:, 2].min())))
        self._flat = self.heights.reshape(-1)
        self._cond = threading.Condition()
        self._rays: list[np.ndarray] = []
        self._tops: list[np.ndarray] = []
        self._pose = None        # (tip (3,), tool, progress, findings, wco, stage)
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
             progress: float | None = None, findings=None, wco=None, stage: int | None = None) -> None:
        """Hand over one state: ``rays`` (k,) int64 the step changed and their new ``tops``
        (k,) float32 mm, the tool ``tip`` (3,) mm in work coordinates and the ``tool``
        there, the program ``progress`` s, the ``findings`` list (read, not copied, by
        the render thread), the work offset ``wco`` and the live ``stage``."""
        with self._cond:
            if rays is not None and len(rays):
                self._rays.append(rays)
                self._tops.append(tops)
            self._pose = (tip, tool, progress, findings, wco, stage)
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
        tip, tool, progress, findings, wco, stage = pose if pose is not None else (None,) * 6
        ahead = near = None
        if progress is not None and self.path is not None and len(self.path):
            if self.moves is not None:
                from monitor.render.runpicture import path_near

                near = path_near(self.moves, int(self.path.row[self.path.segment_at(progress)]))
            else:
                ahead = path_ahead(self.path, progress, self.horizon(progress))
        if tool is not None:
            self.view.tool = tool
        from monitor.render.runpicture import tool_text

        status = {**feed_status(self.path, progress), "stage": stage, "tool": tool_text(self.view.tool)}
        img = self.view.render(self.heights, tip, ahead, finding_marks(findings or (), wco), changed=changed,
                               status=status, moves=near)
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
