"""Reference-image comparison with a tolerant metric.

References live in tests/data/images/. Set DEXMON_REGEN_IMAGES=1 to (re)write them from
the current output (then look at them before committing).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

IMAGES = Path(__file__).resolve().parents[2] / "data" / "images"


def image_difference(a: np.ndarray, b: np.ndarray) -> float:
    """Mean absolute difference per channel (0..255) of two RGB images; inf if shapes differ."""
    a = np.asarray(a)[..., :3].astype(np.float64)
    b = np.asarray(b)[..., :3].astype(np.float64)
    if a.shape != b.shape:
        return float("inf")
    return float(np.abs(a - b).mean())


def check_image(img: np.ndarray, name: str, threshold: float) -> float:
    import imageio.v3 as iio

    path = IMAGES / name
    if os.environ.get("DEXMON_REGEN_IMAGES") == "1" or not path.exists():
        if os.environ.get("DEXMON_REGEN_IMAGES") != "1":
            raise AssertionError(f"reference image {path} is missing (DEXMON_REGEN_IMAGES=1 writes it)")
        IMAGES.mkdir(parents=True, exist_ok=True)
        iio.imwrite(path, np.ascontiguousarray(img[..., :3]), extension=".png")
    ref = iio.imread(path)
    d = image_difference(img, ref)
    assert d <= threshold, f"{name}: mean difference {d:.2f} > {threshold}"
    return d


def hue_shares(img: np.ndarray) -> np.ndarray:
    """Share of the saturated pixels of an RGB image in each of 36 hue bins (10 degrees each)."""
    rgb = img.reshape(-1, img.shape[-1])[:, :3].astype(np.float64)
    mx, mn = rgb.max(1), rgb.min(1)
    sat = (mx - mn) > 40
    r, g, b = rgb[sat].T
    d = (mx - mn)[sat]
    h = np.where(mx[sat] == r, ((g - b) / d) % 6, np.where(mx[sat] == g, (b - r) / d + 2, (r - g) / d + 4))
    counts = np.bincount((h * 6).astype(int) % 36, minlength=36)
    return counts / max(counts.sum(), 1)
