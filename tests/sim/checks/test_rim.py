"""A move through space the tool's last pose already occupied removes nothing.

The analytic invariant behind ``rapid_into_stock``: the tool's final pose cut every ray it
reaches, its rim included, down to its bottom; a move that stays in that pose (a zero
move) or goes straight up from it (a retract, the flutes reaching above the stock) meets
no material. The cut of the move that ended there and the cut (or overlap measure) of the
next must agree on the rim: a ray exactly on the rim of the final pose (a helix returning
to its start, whose end sits on the grid) is cut by both or by neither.
"""

from __future__ import annotations

import numpy as np
import pytest

from sim.checks import Checker
from sim.cut import Cutter
from sim.frame import Frame
from sim.gcode import interpret
from sim.solids import box_grid
from sim.tools import parse_tool_spec

START = "G21 G90 G17\nM3 S10000\nG0 X25 Y15 Z5\nG1 Z0 F200\n"
#: full-turn helices ending where they start (X25 Y15: on the grid, 3 mm from a ray)
HELICES = {
    "one_turn": "G3 X25 Y15 I-5 J0 Z-0.5\n",
    "two_turns": "G3 X25 Y15 I-5 J0 Z-0.5\nG3 X25 Y15 I-5 J0 Z-1.0\n",
    "level_turn": "G3 X25 Y15 I-5 J0 Z-0.5\nG3 X25 Y15 I-5 J0 Z-1.0\nG3 X25 Y15 I-5 J0 Z-1.0\n",
    "cw_turn": "G2 X25 Y15 I-4 J0 Z-0.7\n",
    "half_turn": "G3 X15 Y15 I-5 J0 Z-0.5\n",
    "line": "G1 X40 Y15 Z-0.5\n",
    "diagonal": "G1 X37 Y24 Z-0.5\n",
}
AFTER = {"retract": "G0 Z5\n", "stay": "G0 Z-0.5\n"}


def _cut_then(path, after, spec, spacing):
    """What each row of ``path`` then ``after`` removed from the box X0..60 Y0..30 Z-20..0."""
    program = START + path + after.replace("Z-0.5", f"Z{_last_z(path)}") + "M2\n"
    moves = interpret(program).moves
    fr = Frame.top(0, 0, 60, 30, spacing)
    grid = box_grid(fr, (0, 0, -20), (60, 30, 0))
    return moves, grid, Cutter(grid, parse_tool_spec(spec), threads=1).cut_moves(moves).removed


def _last_z(path):
    return path.strip().split("\n")[-1].split("Z")[-1].split()[0]


@pytest.mark.parametrize("spacing", [0.2, 0.1])
@pytest.mark.parametrize("spec", ["flat:6:L=10", "ball:6:L=10", "bull:6:1:L=10"])
@pytest.mark.parametrize("after", sorted(AFTER))
@pytest.mark.parametrize("path", sorted(HELICES))
def test_nothing_is_left_for_a_move_within_the_final_pose(path, after, spec, spacing):
    moves, _, removed = _cut_then(HELICES[path], AFTER[after], spec, spacing)
    last = int(np.flatnonzero(moves["kind"] == 0)[-1])  # the G0 after the path
    assert removed[:last].sum() > 0 and removed[last] == 0.0


@pytest.mark.parametrize("prog", ["helix1", "helix2", "helix"])
@pytest.mark.parametrize("spacing", [0.2, 0.1])
def test_a_retract_after_a_full_turn_helix_is_no_rapid_into_stock(prog, spacing):
    # the audit's programs: the helix from Z0 (Z0.1), then G0 Z5
    path = {"helix1": HELICES["one_turn"], "helix2": HELICES["two_turns"], "helix": HELICES["level_turn"]}[prog]
    program = START + path + "G0 Z5\nM5\nM2\n"
    if prog == "helix":
        program = program.replace("G1 Z0 F200", "G1 Z0.1 F200")
    fr = Frame.top(0, 0, 60, 30, spacing)
    ch = Checker(box_grid(fr, (0, 0, -20), (60, 30, 0)), parse_tool_spec("flat:6:L=10"))
    res, found = ch.cut_and_check(interpret(program).moves)
    assert res.removed.sum() > 0 and [f.kind for f in found] == []
