"""The machine's limits learned from GRBL's ``$$``: by the driver (at connect when Idle,
else at the next Idle) and by the passthrough (from the replies a sender's ``$$`` shows)."""

from __future__ import annotations

import math

import pytest
import serial

from drivers.grbl import protocol as p
from drivers.grbl import readings
from drivers.grbl.passthrough import Passthrough
from drivers.grbl.peer import GrblPeer
from drivers.registry import open_controller
from drivers.state import ControllerLimits, RunState
from drivers.virtual.machine import VirtualMachine
from drivers.virtual.machine_config import MachineConfig
from sim.gcode.moves import MoveKind, empty_moves

SLOW = dict(max_rate=(500.0, 400.0, 300.0), accel=(20.0, 15.0, 10.0), junction_deviation=0.02)


def test_settings_limits_reads_rates_accelerations_deviation_travel_and_flags():
    got = readings.settings_limits({**p.DEFAULT_SETTINGS, 110: 800, 122: 50, 11: 0.05, 132: 80, 20: 1, 13: 1}, "here")
    assert got == ControllerLimits(max_rate=(800.0, 500.0, 500.0), acceleration=(10.0, 10.0, 50.0),
                                   junction_deviation=0.05, travel=((-200.0, 0.0), (-200.0, 0.0), (-80.0, 0.0)),
                                   soft_limits=True, report_inches=True, source="here")
    assert got.timing() == {"max_rate": (800.0, 500.0, 500.0), "acceleration": (10.0, 10.0, 50.0),
                            "junction_deviation": 0.05}
    assert got.travel_limits() == {"X": (-200.0, 0.0), "Y": (-200.0, 0.0), "Z": (-80.0, 0.0)}
    # travel is no limit where the controller does not enforce it ($20=0: no homing needed)
    assert readings.settings_limits(p.DEFAULT_SETTINGS, "").travel_limits() is None
    # a firmware built with HOMING_FORCE_SET_ORIGIN ([OPT:Z..]) homes an axis whose $23 bit is
    # set to its negative end and sets the origin there: that axis travels [0, $13x]
    forced = readings.settings_limits({**p.DEFAULT_SETTINGS, 23: 5, 20: 1}, "", "VZ")
    assert forced.travel == ((0.0, 200.0), (-200.0, 0.0), (0.0, 200.0))
    assert readings.settings_limits({**p.DEFAULT_SETTINGS, 23: 5}, "", "V").travel == ((-200.0, 0.0),) * 3
    # $$ not read yet: nothing known; a group with a missing or impossible value is unknown
    assert readings.settings_limits({}, "") is None and readings.settings_limits({10: 1, 13: 0}, "") is None
    odd = readings.settings_limits({110: 500, 111: math.nan, 112: 500, 120: 10, 121: 10, 122: 0, 11: -1,
                             130: 100, 131: 100, 132: 100, 20: 7}, "")
    assert odd.max_rate is None and odd.acceleration is None and odd.junction_deviation is None
    assert odd.timing() == {} and odd.soft_limits is None


@pytest.fixture
def peer():
    made = []

    def make(config: MachineConfig, speed: float = 1.0) -> GrblPeer:
        made.append(GrblPeer(VirtualMachine(config), speed=speed))
        return made[-1]
    yield make
    for pr in made:
        pr.close()


def test_driver_reads_the_limits_at_connect(peer):
    pr = peer(MachineConfig(travel_min=(-300.0, -200.0, -100.0), travel_max=(0.0, 0.0, 0.0), **SLOW))
    c = open_controller(f"grbl://{pr.serve_pty()}")
    c.connect()
    try:
        got = c.machine_limits()
    finally:
        c.close()
    assert got.max_rate == (500.0, 400.0, 300.0) and got.acceleration == (20.0, 15.0, 10.0)
    assert got.junction_deviation == 0.02 and got.soft_limits is True and got.report_inches is False
    assert got.travel_limits() == {"X": (-300.0, 0.0), "Y": (-200.0, 0.0), "Z": (-100.0, 0.0)}
    assert got.source.startswith("GRBL $$ on /dev/")


def test_driver_attached_to_a_busy_machine_learns_the_limits_when_it_is_idle(peer):
    pr = peer(MachineConfig(travel_min=None, travel_max=None, **SLOW), speed=20.0)
    move = empty_moves(1)
    move["kind"], move["feed"] = MoveKind.FEED, 500.0
    move["end"][0, 0] = 40.0  # 40 mm at 500 mm/min: ~5 s of machine time, ~0.25 s here
    with pr.vm.lock:
        pr.vm.queue(move)
    c = open_controller(f"grbl://{pr.serve_pty()}?rate=50")
    c.connect()
    try:
        assert c.poll().state is RunState.RUN
        assert c.machine_limits() is None  # $$ is not asked of a machine in motion
        c.wait_for_state(lambda s: s.state is RunState.IDLE, 30)
        assert c.wait_for_message(lambda m: isinstance(m, p.Setting) and m.number == 132, 10) is not None
        got = c.machine_limits()
    finally:
        c.close()
    assert got is not None and got.max_rate == (500.0, 400.0, 300.0)


def test_passthrough_offers_the_limits_its_sender_asked_for(peer):
    pr = peer(MachineConfig(travel_min=None, travel_max=None, **SLOW))
    pt = Passthrough(pr.serve_pty(), rate=50)
    port = serial.serial_for_url(pt.start(), baudrate=115200, timeout=5)
    try:
        assert pt.machine_limits() is None  # no sender asked for $$ yet
        port.write(b"$$\n")
        while port.read_until(b"\n").strip() != b"ok":
            pass
        got = pt.machine_limits()
    finally:
        port.close()
        pt.close()
    assert got.max_rate == (500.0, 400.0, 300.0) and got.acceleration == (20.0, 15.0, 10.0)
    assert got.junction_deviation == 0.02 and "seen on" in got.source
