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

#: the longest side a picture may have, px. A picture is drawn with a few float arrays per
#: pixel besides its RGB bytes, about PICTURE_BYTES_PER_PX in all (a 2-D replay picture
#: measured ~10, the 3-D view more): 8192 px a side takes about 2 GB while drawn, as much
#: as half the 4096 MB grid limit; unbounded, --size 100000 grew until the OS killed dexmon
MAX_PICTURE_PX = 8192
PICTURE_BYTES_PER_PX = 32


def number(value, option: str, *, whole: bool = False, zero: bool = False, most: float | None = None,
           unit: str = "", why_most: str = ""):
    """``value`` when it is a finite number > 0 (``zero``: >= 0; ``whole``: an integer)
    and at most ``most`` (in ``unit``); None when the option was not given. Otherwise
    InputError naming ``option``; ``why_most`` says why a value over ``most`` is refused."""
    if value is None:
        return None
    kind = "whole number" if whole else "number"
    expected = f"a {kind} >= 0" if zero else f"a positive {kind}"
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or (whole and value != int(value)) or not (value >= 0 if zero else value > 0):
        raise InputError(f"expected {expected}, got {_show(value)}", option)
    if most is not None and value > most:
        raise InputError(f"expected at most {most:g}{' ' + unit if unit else ''}, got {_show(value)}" + (f" ({why_most})" if why_most else ""),
                         option)
    return int(value) if whole else float(value)


def picture_size(value, option: str = "--size", least: int = 16) -> int:
    """A picture's size in pixels (its long side): a whole number from ``least`` to
    :data:`MAX_PICTURE_PX`; over it the message says what the size asked for would take."""
    if isinstance(value, bool) or not isinstance(value, int) or value < least:
        raise InputError(f"expected a picture size of at least {least} pixels, got {_show(value)}", option)
    return number(value, option, whole=True, most=MAX_PICTURE_PX, unit="pixels",
                  why_most=f"a picture {value} px a side needs about {_memory(value)} to draw, "
                           f"{MAX_PICTURE_PX} px about {_memory(MAX_PICTURE_PX)}")


def _memory(side: int) -> str:
    need = float(side) ** 2 * PICTURE_BYTES_PER_PX
    return f"{need / 2**30:,.0f} GB" if need >= 2**30 else f"{need / 2**20:,.0f} MB"


def _show(value) -> str:
    """``0``, ``-3``, ``2.5``, ``nan``: as the user would have typed it."""
    if isinstance(value, float) and math.isfinite(value) and value == int(value):
        return str(int(value))
    return str(value)
