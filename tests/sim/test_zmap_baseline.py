"""The benchmark's baseline z-map kernel computes the same surface as dexmon's plain cut."""

from __future__ import annotations

import numpy as np
import pytest

from bench.zmap_baseline import cut_program
from sim.cut import Cutter
from sim.frame import Frame
from sim.gcode.moves import MoveKind, empty_moves
from sim.grid import DexelGrid
from sim.tools import parse_tool_spec

TOP, BOTTOM = 10.0, 0.0


def tiny_program() -> np.ndarray:
    """A plunge, a ramp, a diagonal, a climb and a retract (tip coordinates, mm); the
    positions are off the ray lattice so no ray lies on a flat tool's wall."""
    pts = [(3.013, 4.017, 12.0), (3.013, 4.017, 7.531), (14.071, 6.029, 6.213),
           (9.047, 15.083, 8.377), (17.023, 13.011, 9.419), (17.023, 13.011, 12.0)]
    mv = empty_moves(len(pts) - 1)
    for k in range(len(pts) - 1):
        mv["kind"][k] = MoveKind.FEED
        mv["start"][k, :3] = pts[k]
        mv["end"][k, :3] = pts[k + 1]
        mv["line"][k] = k + 1
    return mv


@pytest.mark.parametrize("spec", ["ball:6:L=20", "flat:6:L=20"])
def test_baseline_heights_equal_dexmon_plain_cut(spec):
    tool = parse_tool_spec(spec)
    moves = tiny_program()
    frame = Frame.top(0.0, 0.0, 20.0, 20.0, 0.1)
    grid = DexelGrid.from_intervals(frame, np.full(frame.shape, BOTTOM), np.full(frame.shape, TOP))
    Cutter(grid, tool).cut_moves(moves, record_changes=False)
    dexmon = np.nan_to_num(grid.top().astype(np.float64), nan=BOTTOM)
    baseline = cut_program(frame, tool, moves, TOP, BOTTOM)
    assert (baseline < TOP).sum() > 1000  # the program cuts
    assert np.abs(baseline - dexmon).max() <= 1e-3
