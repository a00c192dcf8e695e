"""Animations between two stages of a run, from the time-trace (no re-simulation).

Frames are the replay pictures (:class:`monitor.render.runpicture.RunPictures`, the live
view's overlay on each); the time-trace gives each next frame for the cost of the
surface changes in between, forwards or backwards. This module strides and writes them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sim.errors import InputError


def reduce_factor(shape: tuple[int, int], max_size: int | None) -> int:
    """Integer stride so the larger side of ``shape`` is at most ``max_size`` pixels."""
    if not max_size:
        return 1
    return max(1, int(np.ceil(max(shape) / float(max_size))))


def stage_steps(first: int, last: int, max_frames: int) -> int:
    """Stages between frames so that ``first``..``last`` takes at most ``max_frames``."""
    span = abs(int(last) - int(first))
    return max(1, int(np.ceil(span / max(1, max_frames - 1))))


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
