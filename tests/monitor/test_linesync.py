"""StreamedLines.finished: only the controller's answer finishes a streamed line."""

from __future__ import annotations

import pytest

from drivers.state import MachineState, RunState
from monitor.linesync import StreamedLines
from tests.monitor.test_passthrough_live import FakeLine, FakeStream, _two_passes

_PROGRAM = ("G90 G21", "G1 X20 Y0 Z-1 F600", "G1 X20 Y20", "G1 X0 Y0", "G1 X20 Y0", "G1 X20 Y20", "G1 X0 Y0")


@pytest.mark.parametrize("fate", ["lost", "reset"])
def test_a_last_line_without_an_answer_does_not_end_the_run(fate):
    """The link dropped (or the controller reset) with the last line in flight: its
    answer went with the link, so the job is not over even though the machine is idle."""
    text, m = _two_passes()
    ctl = FakeStream()
    lines = StreamedLines(ctl, text, m)
    ctl.learned_lines.extend(FakeLine(t) for t in _PROGRAM)
    ctl.learned_lines[-1].result = fate
    ctl.last_state = MachineState(t=0, mpos=(0,) * 3, state=RunState.IDLE)
    assert not lines.finished()
    ctl.learned_lines[-1].result = "ok"  # the same run with the answer arrived
    assert lines.finished()


def test_a_refused_last_line_is_answered():
    text, m = _two_passes()
    ctl = FakeStream()
    lines = StreamedLines(ctl, text, m)
    ctl.learned_lines.extend(FakeLine(t) for t in _PROGRAM)
    ctl.learned_lines[-1].result = "error:33"
    ctl.last_state = MachineState(t=0, mpos=(0,) * 3, state=RunState.IDLE)
    assert lines.finished()
