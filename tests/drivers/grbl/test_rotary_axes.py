"""A B C through the GRBL driver: grblHAL reports 4 to 6 axes (MPos, WPos, WCO); they reach
the machine state in degrees, also in inch reports ($13=1, $376 rotary mask). Against the
GRBL peer on a real pty, its reports rewritten to carry the extra axes as grblHAL sends them."""

from __future__ import annotations

import pytest

from drivers.grbl.peer import GrblPeer
from drivers.registry import open_controller
from drivers.state import RunState
from drivers.virtual.machine import VirtualMachine
from drivers.virtual.machine_config import MachineConfig
from tests.drivers.thread_errors import thread_errors


@pytest.fixture
def link():
    """(peer, controller) connected over a pty at 50 polls/s, the machine idle at 0, 0, 0."""
    vm = VirtualMachine(MachineConfig(travel_min=(-200.0,) * 3, travel_max=(200.0,) * 3))
    pr = GrblPeer(vm, speed=4.0)
    c = open_controller(pr.serve_url("pty", "rate=50"))
    c.connect()
    yield pr, c
    c.close()
    pr.close()


def rewrite_status(pr: GrblPeer, old: bytes, new: bytes) -> None:
    pr.mutate = lambda d: d.replace(old, new) if d.startswith(b"<") else d


@pytest.mark.parametrize("axes, want", [
    (b",90.000", (90.0, 0.0, 0.0)),                      # a 4th axis A (the hobby setup)
    (b",-45.500,12.250,370.000", (-45.5, 12.25, 370.0)),  # grblHAL's 6 axes
])
def test_grblhal_reports_with_rotary_axes_reach_the_state(link, axes, want):
    pr, c = link
    with thread_errors() as errors:
        rewrite_status(pr, b"MPos:0.000,0.000,0.000|", b"MPos:0.000,0.000,0.000" + axes + b"|")
        s = c.wait_for_state(lambda s: s.fresh and s.mpos[3:] != (0.0, 0.0, 0.0), 5)
    assert errors == []
    assert s.state is RunState.IDLE and s.mpos == (0.0, 0.0, 0.0) + want


def test_inch_reports_keep_rotary_axes_in_degrees(link):
    pr, c = link
    with thread_errors() as errors:
        c.command("G1 X25.4 F3000")
        c.wait_for_state(lambda s: s.state is RunState.IDLE and s.mpos[0] == pytest.approx(25.4), 5)
        c.command("$13=1")  # the peer now reports in inches, 4 decimals
        pr.inject(b"$13=1\r\n$376=8\r\n")  # what $$ would tell the driver: inches, A rotary
        rewrite_status(pr, b"MPos:1.0000,0.0000,0.0000|", b"MPos:1.0000,0.0000,0.0000,90.000|")
        s = c.wait_for_state(lambda s: s.fresh and s.state is RunState.IDLE and s.mpos[3] != 0.0, 5)
    assert errors == []
    assert c.settings[13] == 1 and c.settings[376] == 8
    assert s.mpos[0] == pytest.approx(25.4) and s.mpos[3] == 90.0
