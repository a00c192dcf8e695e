"""Small array helpers the checks need on every batch."""

from __future__ import annotations

import numpy as np


def distinct(a: np.ndarray) -> np.ndarray:
    """Sorted distinct values of a 1-D array (same as ``np.unique(a)``).

    Sort-based: ``np.unique`` of numpy 2.3+ hashes integers first, which costs
    milliseconds even on tiny arrays and seconds on a million ray indices.
    """
    a = np.sort(np.asarray(a).reshape(-1))
    if a.size < 2:
        return a
    keep = np.empty(a.size, bool)
    keep[0] = True
    np.not_equal(a[1:], a[:-1], out=keep[1:])
    return a[keep]


def runs_of(ids: np.ndarray) -> list[slice]:
    """Slices of ``ids`` split where the ids stop being consecutive."""
    if ids.size == 0:
        return []
    d = np.diff(ids)
    cuts = [0, *(np.nonzero((d < 0) | (d > 1))[0] + 1).tolist(), int(ids.size)]
    return [slice(a, b) for a, b in zip(cuts[:-1], cuts[1:])]
