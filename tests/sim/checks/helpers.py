"""Move tables built by hand for the checks tests."""

from __future__ import annotations

import numpy as np

from sim.gcode.moves import MoveKind, empty_moves


def table(rows, spindle=12000.0, tool_length=0.0):
    """Move table from ``(kind, start xyz, end xyz[, extra dict])`` tuples; line = 10*(i+1)."""
    m = empty_moves(len(rows))
    for k, r in enumerate(rows):
        kind, s, e = r[:3]
        extra = r[3] if len(r) > 3 else {}
        m[k]["line"] = 10 * (k + 1)
        m[k]["kind"] = int(kind)
        m[k]["start"][:3] = s
        m[k]["end"][:3] = e
        m[k]["start"][2] += tool_length
        m[k]["end"][2] += tool_length
        m[k]["tool_length"] = tool_length
        m[k]["spindle"] = spindle
        m[k]["spindle_dir"] = 1 if spindle > 0 else 0
        m[k]["feed"] = 0.0 if kind == MoveKind.RAPID else 600.0
        m[k]["tool"] = 1
        for key, v in extra.items():
            m[k][key] = v
    return m


def polyline(points, kinds=None, **kw):
    """Consecutive moves through ``points``; ``kinds`` per move (default FEED)."""
    pts = np.asarray(points, float)
    kinds = kinds or [MoveKind.FEED] * (len(pts) - 1)
    return table([(kinds[i], pts[i], pts[i + 1]) for i in range(len(pts) - 1)], **kw)
