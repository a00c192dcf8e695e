"""The one record every driver produces, and the interface every driver offers."""

from __future__ import annotations

import abc
import enum
import time
from dataclasses import dataclass, field
from typing import Iterator

import numpy as np


class RunState(str, enum.Enum):
    """Controller run state, named as GRBL names them (Modbus maps its codes onto these)."""

    IDLE = "Idle"
    RUN = "Run"
    HOLD = "Hold"
    JOG = "Jog"
    ALARM = "Alarm"
    DOOR = "Door"
    CHECK = "Check"
    HOME = "Home"
    SLEEP = "Sleep"
    UNKNOWN = "Unknown"
    DISCONNECTED = "Disconnected"


def _vec6(values) -> tuple[float, ...]:
    out = [float(v) for v in values]
    if len(out) > 6:
        raise ValueError(f"at most 6 axes (X Y Z A B C), got {len(out)}")
    return tuple(out + [0.0] * (6 - len(out)))


@dataclass(frozen=True, slots=True)
class MachineState:
    """What the controller said at one instant, stamped where it was read.

    Attributes
    ----------
    t : float
        Time of the reading, seconds, ``time.monotonic()`` of the process that read it
        (the driver stamps it at the source, as the bytes arrive).
    mpos : tuple of 6 float
        Machine position of the controlled point, X Y Z (mm) A B C (deg).
    wco : tuple of 6 float
        Work coordinate offset in force (G5x + G92 + tool length offset), mm; the work
        position is ``mpos - wco``.
    state : RunState
    substate : int or None
        GRBL's sub-state (``Hold:1`` decelerating, ``Door:2`` ...).
    feed : float
        Real-time feed rate, mm/min.
    spindle : float
        Spindle speed, rpm; negative for counter-clockwise when the controller says so.
    line : int or None
        Program line number the controller is executing, when it reports one.
    overrides : tuple of 3 int
        Feed, rapid and spindle overrides, percent.
    alarm : int or None
        Alarm code when ``state`` is ALARM and the code is known.
    buffer : tuple of 2 int or None
        Free planner blocks and free RX bytes (GRBL ``Bf:``).
    pins : str
        Input pins reported (GRBL ``Pn:``), e.g. ``"XZP"``.
    accessories : str
        Spindle/coolant flags (GRBL ``A:``), e.g. ``"SF"``.
    raw : str
        The text or register dump this state was parsed from, for debugging.
    """

    t: float
    mpos: tuple[float, ...]
    wco: tuple[float, ...] = (0.0,) * 6
    state: RunState = RunState.UNKNOWN
    substate: int | None = None
    feed: float = 0.0
    spindle: float = 0.0
    line: int | None = None
    overrides: tuple[int, int, int] = (100, 100, 100)
    alarm: int | None = None
    buffer: tuple[int, int] | None = None
    pins: str = ""
    accessories: str = ""
    raw: str = field(default="", compare=False)

    def __post_init__(self):
        object.__setattr__(self, "mpos", _vec6(self.mpos))
        object.__setattr__(self, "wco", _vec6(self.wco))

    @property
    def wpos(self) -> tuple[float, ...]:
        """Work position, ``mpos - wco``."""
        return tuple(m - w for m, w in zip(self.mpos, self.wco))

    @property
    def mpos_array(self) -> np.ndarray:
        """Machine position as a float64 array of shape (6,)."""
        return np.asarray(self.mpos, dtype=np.float64)


class Controller(abc.ABC):
    """Interface of every controller driver (GRBL, Modbus, virtual).

    A controller is opened from a URL (see :func:`drivers.registry.open_controller`),
    then ``connect()``-ed. ``poll()`` returns the newest state; ``states(period)`` yields
    states at a rate. The monitor only ever calls ``feed_hold()`` among the commands,
    and only when the user enabled it.
    """

    url: str = ""

    @abc.abstractmethod
    def connect(self) -> None:
        """Open the port or socket and do the protocol's handshake."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the port. Safe to call twice."""

    @abc.abstractmethod
    def poll(self) -> MachineState:
        """Ask for and return the controller's current state."""

    def states(self, period: float = 0.05) -> Iterator[MachineState]:
        """Yield a state every ``period`` seconds until the controller is closed."""
        next_t = time.monotonic()
        while True:
            yield self.poll()
            next_t += period
            delay = next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)  # pacing a poll loop, not synchronising a test
            else:
                next_t = time.monotonic()

    def send(self, line: str) -> None:
        """Send one program line (where the protocol allows streaming)."""
        raise NotImplementedError(f"{type(self).__name__} cannot stream program lines")

    def feed_hold(self) -> None:
        """Ask the controller to hold the feed (decelerate and stop along the path)."""
        raise NotImplementedError(f"{type(self).__name__} has no feed hold")

    def resume(self) -> None:
        """Resume after a feed hold."""
        raise NotImplementedError(f"{type(self).__name__} cannot resume")

    def __enter__(self):
        self.connect()
        return self

    def __exit__(self, *exc):
        self.close()
        return False
