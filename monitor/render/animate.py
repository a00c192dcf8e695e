"""Animations between two stages of a run, from the time-trace (no re-simulation).

Frames are Van Hook shaded pictures (:mod:`.shaded`); the time-trace gives each next
frame for the cost of the surface changes in between, forwards or backwards.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from monitor.render import shaded
from sim.errors import InputError


def reduce_factor(shape: tuple[int, int], max_size: int | None) -> int:
    """Integer stride so the larger side of ``shape`` is at most ``max_size`` pixels."""
    if not max_size:
        return 1
    return max(1, int(np.ceil(max(shape) / float(max_size))))


def frame_picture(heights, ids, frame, k: int = 1, tool=None, tip=None, path_ahead=None,
                  findings=None, color_by_move: bool = True, out=None) -> np.ndarray:
    """One animation frame: shaded heights, every ``k``-th ray (k > 1 shrinks the picture)."""
    h = heights[::k, ::k]
    ids_k = ids[::k, ::k] if (color_by_move and ids is not None) else None
    sub = frame if k == 1 else frame.__class__(frame.origin, frame.direction, frame.u, frame.spacing * k,
                                               h.shape[1], h.shape[0])
    return shaded.picture(h, sub, ids=ids_k, tool=tool, tip=tip, path_ahead=path_ahead,
                          findings=findings, out=out)


def stage_steps(first: int, last: int, max_frames: int) -> int:
    span = abs(int(last) - int(first))
    return max(1, int(np.ceil(span / max(1, max_frames - 1))))


def animation_frames(trace, first: int, last: int, max_frames: int = 120, max_size: int | None = 600,
                     tip_of=None, tool=None, findings=None, color_by_move: bool = True):
    """Yield RGB uint8 frames from ``first`` to ``last`` (backwards when ``last < first``).

    ``tip_of(stage) -> (3,) or None`` places the tool; ``findings`` (k, 3) are ringed.
    At most ``max_frames`` frames; pictures at most ``max_size`` pixels on a side.
    """
    if trace.t is None:
        raise InputError("the run has no time-trace: animations need it")
    step = stage_steps(first, last, max_frames)
    k = reduce_factor(trace.frame.shape, max_size)
    for stage, heights, ids in trace.t.frames(int(first), int(last), step):
        tip = tip_of(stage) if tip_of is not None else None
        yield stage, frame_picture(heights, ids, trace.frame, k, tool=tool, tip=tip,
                                   findings=findings, color_by_move=color_by_move)


def _even(img: np.ndarray) -> np.ndarray:
    """Pad to even width and height (the H.264 encoder needs them)."""
    h, w = img.shape[:2]
    if h % 2 == 0 and w % 2 == 0:
        return img
    return np.pad(img, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


def write_animation(frames, path, fps: float = 10.0) -> int:
    """Write RGB uint8 frames (an iterable of (stage, image) or images) to a GIF or MP4.

    The format follows the suffix (.gif or .mp4). Returns the number of frames written.
    """
    import imageio.v2 as imageio

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise InputError(f"animation must be .gif or .mp4, got {path.name!r}", str(path))
    if suffix == ".gif":
        writer = imageio.get_writer(path, mode="I", duration=1000.0 / fps, loop=0)
    else:
        writer = imageio.get_writer(path, fps=fps, codec="libx264", macro_block_size=2,
                                    quality=7, pixelformat="yuv420p", ffmpeg_log_level="error")
    n = 0
    try:
        for item in frames:
            img = item[1] if isinstance(item, tuple) else item
            writer.append_data(_even(np.ascontiguousarray(img)) if suffix == ".mp4" else img)
            n += 1
    finally:
        writer.close()
    if n == 0:
        raise InputError("no frames to write", str(path))
    return n


def animate(trace, first: int, last: int, path, fps: float = 10.0, max_frames: int = 120,
            max_size: int | None = 600, **kw) -> int:
    """Animate ``trace`` from stage ``first`` to ``last`` into ``path`` (.gif or .mp4)."""
    return write_animation(animation_frames(trace, first, last, max_frames, max_size, **kw), path, fps)
