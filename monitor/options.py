"""Checks of the numbers given on the command line, shared by every command.

argparse's ``type=float`` takes ``nan``, ``inf``, ``0`` and ``-3`` alike; a number that
means nothing for its option (a frame rate of 0, a speed of inf, a negative count) is
refused here with one line naming the option, what was expected and what was given
(``--fps: expected a positive number, got 0``), so the command exits 2 instead of
failing deep inside with a traceback or running on with a value it cannot use.
"""

from __future__ import annotations

import math

from sim.errors import InputError


def number(value, option: str, *, whole: bool = False, zero: bool = False, most: float | None = None,
           why_most: str = ""):
    """``value`` when it is a finite number > 0 (``zero``: >= 0; ``whole``: an integer)
    and at most ``most``; None when the option was not given. Otherwise InputError naming
    ``option``; ``why_most`` says why a value over ``most`` is refused."""
    if value is None:
        return None
    kind = "whole number" if whole else "number"
    expected = f"a {kind} >= 0" if zero else f"a positive {kind}"
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or (whole and value != int(value)) or not (value >= 0 if zero else value > 0):
        raise InputError(f"expected {expected}, got {_show(value)}", option)
    if most is not None and value > most:
        raise InputError(f"expected at most {most:g}, got {_show(value)}" + (f" ({why_most})" if why_most else ""),
                         option)
    return int(value) if whole else float(value)


def picture_size(value, option: str = "--size", least: int = 16) -> int:
    """A picture's size in pixels (its long side): a whole number of at least ``least``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < least:
        raise InputError(f"expected a picture size of at least {least} pixels, got {_show(value)}", option)
    return value


def _show(value) -> str:
    """``0``, ``-3``, ``2.5``, ``nan``: as the user would have typed it."""
    if isinstance(value, float) and math.isfinite(value) and value == int(value):
        return str(int(value))
    return str(value)
