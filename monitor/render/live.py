"""Van Hook's real-time shaded display for ``dexmon live|dry-run --view`` / ``--frames DIR``.

:class:`LiveView` redraws the shaded model (one pixel per ray, :mod:`.shaded`) with the
tool inverse-shaded at its pose, the path ahead and the predicted findings ringed. With a
display it shows a window (matplotlib, updated in place); without one, or when ``out_dir``
is given, it writes the frames as numbered PNG files.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from monitor.render import shaded
from monitor.render.animate import reduce_factor
from monitor.render.view3d import has_display
from sim.errors import InputError


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
        self.k = reduce_factor(frame.shape, max_size)
        self.sub = frame if self.k == 1 else frame.__class__(
            frame.origin, frame.direction, frame.u, frame.spacing * self.k,
            len(range(0, frame.nu, self.k)), len(range(0, frame.nv, self.k)))
        self.max_fps = float(max_fps)
        self.color_by_move = color_by_move
        self.frames_drawn = 0
        self.last_image: np.ndarray | None = None
        self._buf: np.ndarray | None = None
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
               ids: np.ndarray | None = None) -> np.ndarray:
        """The frame as RGB uint8 (rows, cols, 3) without showing or writing it.

        ``heights_or_grid``: (nv, nu) heights mm or a DexelGrid; ``tool_pose``: tip (3,)
        mm (or a 6-vector whose first three are the tip); ``path_ahead`` (k, 3);
        ``findings``: dicts with ``position``, objects with ``.position`` or (m, 3).
        """
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

    def update(self, heights_or_grid, tool_pose=None, path_ahead=None, findings=None,
               ids: np.ndarray | None = None) -> bool:
        """Redraw with the new state; False when skipped by ``max_fps``."""
        now = time.monotonic()
        if self.max_fps > 0 and now - self._last_t < 1.0 / self.max_fps:
            return False
        self._last_t = now
        img = self.render(heights_or_grid, tool_pose, path_ahead, findings, ids)
        self.frames_drawn += 1
        self.last_image = img
        if self.out_dir is not None:
            shaded.save_png(img, self.out_dir / f"frame_{self.frames_drawn:06d}.png")
        else:
            if self._im is None:
                self._im = self._ax.imshow(img, interpolation="nearest")
            else:
                self._im.set_data(img)
            self._fig.canvas.draw_idle()
            self._fig.canvas.flush_events()
        return True

    def close(self) -> None:
        if self._fig is not None:
            self._plt.close(self._fig)
            self._fig = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
