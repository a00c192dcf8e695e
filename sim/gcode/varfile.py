"""LinuxCNC parameter (.var) files: one ``<number> <value>`` pair per line."""

from __future__ import annotations

import math
from pathlib import Path

from sim.gcode.errors import GCodeError


def read_var_file(path) -> dict[int, float]:
    """Read a LinuxCNC .var file; return ``{parameter number: value}`` (values as written).

    Lengths are in the machine's units; the interpreter converts them. Raises
    :class:`GCodeError` naming file and line for a line that is not ``int float``.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise GCodeError(f"cannot read parameter file: {exc.strerror or exc}", str(path), 0) from None
    params: dict[int, float] = {}
    for lineno, raw in enumerate(text.splitlines(), start=1):
        body = raw.split(";", 1)[0].split("#", 1)[0].strip()
        if not body:
            continue
        parts = body.split()
        try:
            if len(parts) != 2:
                raise ValueError
            num = int(parts[0])
            value = float(parts[1])
            if not (1 <= num <= 5601) or not math.isfinite(value):
                raise ValueError
        except ValueError:
            raise GCodeError(
                "expected '<parameter number 1..5601> <value>'", str(path), lineno, 1, raw
            ) from None
        params[num] = value
    return params
