"""Block delete: a line starting with '/' runs unless the switch is on (issue 13).

LinuxCNC's block delete switch is off when a program starts (rs274 without ``-b``), so
'/' lines run; ``block_delete=True`` (``--block-delete``, ``[program] block_delete``)
skips them whole, as rs274 -b does.
"""

from __future__ import annotations

import numpy as np
import pytest

from sim.gcode import GCodeError, interpret, work_end
from tests.sim.gcode import rs274_harness as h

PROGRAM = h.DATA / "programs" / "block_delete.ngc"


def test_slash_lines_run_by_default():
    p = interpret("G21 G90\n/G0 X9\nG0 Y1\n/ G0 Z3\nM2")
    np.testing.assert_allclose(work_end(p.moves)[:3, :3], [[9, 0, 0], [9, 1, 0], [9, 1, 3]])


def test_block_delete_switch_skips_slash_lines():
    p = interpret("G21 G90\n/G0 X9\nG0 Y1\n/ G0 Z3\nM2", block_delete=True)
    np.testing.assert_allclose(work_end(p.moves)[:1, :3], [[0, 1, 0]])


def test_a_skipped_line_is_not_read():
    # rs274 -b drops the whole line before reading it: its errors do not count
    p = interpret("G21\n/G0 X[1+]\nG0 X1\nM2", block_delete=True)
    assert work_end(p.moves)[0, 0] == 1
    with pytest.raises(GCodeError, match="line 2|:2:"):
        interpret("G21\n/G0 X[1+]\nG0 X1\nM2")


def test_slash_o_word_lines():
    text = "G21\n/o1 if [0]\nG0 X5\n/o1 endif\nG0 Y1\nM2"
    ran = work_end(interpret(text).moves)[:, :3]
    skipped = work_end(interpret(text, block_delete=True).moves)[:, :3]
    np.testing.assert_allclose(ran[0], [0, 1, 0])   # the if runs: X5 is skipped by it
    np.testing.assert_allclose(skipped[:2], [[5, 0, 0], [5, 1, 0]])


@pytest.mark.parametrize("block_delete", [False, True])
def test_equals_rs274(block_delete):
    if h.RS274 is None:
        pytest.skip("rs274 is not installed (apt-get install linuxcnc-uspace)")
    ref = h.parse_canon(h.run_rs274(PROGRAM, h.DATA / "tools.tbl", h.DATA / "params.var", block_delete=block_delete))
    got = h.dexmon_run(PROGRAM, h.DATA / "tools.tbl", h.DATA / "params.var", block_delete=block_delete)
    result = h.compare(ref, got)
    assert result.status == "match", result.detail


def test_slash_after_a_comment_is_no_block_delete():
    # rs274: "Bad character '/' used" (only a line's first character deletes it)
    with pytest.raises(GCodeError, match="'/'") as info:
        interpret("G21\n(c) /G0 Y1\nM2")
    assert info.value.line == 2
