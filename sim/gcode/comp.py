"""Cutter radius compensation G41/G42 (placeholder until the full engine lands)."""

from __future__ import annotations

from sim.gcode.errors import LineError


class CompEngine:
    def __init__(self, it, left: bool, radius: float):
        self.it = it
        self.left = left
        self.radius = radius

    def straight(self, target, rapid, col, words=None):
        raise LineError("cutter radius compensation is not implemented yet", col)

    def arc(self, cw, target, center, turns, col, words):
        raise LineError("cutter radius compensation is not implemented yet", col)

    def flush(self):
        pass
