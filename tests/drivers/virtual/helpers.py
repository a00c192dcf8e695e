"""Build move-table rows by hand (no G-code interpreter needed)."""

from __future__ import annotations

import numpy as np

from sim.gcode.moves import MoveKind, empty_moves


def rows(*moves, start=(0.0, 0.0, 0.0)):
    """Rows from ``(kind, end_xyz, feed)`` or ``(kind, end_xyz, feed, extra_dict)`` tuples;
    each row starts where the previous ended; work coords = machine coords."""
    out = empty_moves(len(moves))
    pos = np.zeros(6)
    pos[:3] = start
    for i, m in enumerate(moves):
        kind, end, feed = m[:3]
        extra = m[3] if len(m) > 3 else {}
        out["kind"][i] = kind
        out["line"][i] = i + 1
        out["start"][i] = pos
        e = pos.copy()
        e[: len(end)] = end
        out["end"][i] = e
        out["feed"][i] = feed
        for k, v in extra.items():
            out[k][i] = v
        pos = e
    return out  # wco 0: work coordinates = machine


def line(end, feed):
    return (MoveKind.FEED, end, feed)


def rapid(end):
    return (MoveKind.RAPID, end, 0.0)


def run_until_idle(vm, dt=0.001, limit=1000.0):
    """Advance in steps of ``dt`` until the machine is idle; returns elapsed time."""
    t = 0.0
    while vm.busy:
        vm.advance(dt)
        t += dt
        assert t < limit, "machine never finished"
    return t
