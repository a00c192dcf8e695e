"""The one record every driver produces, and the interface every driver offers."""

from __future__ import annotations

import abc
import collections
import enum
import math
import os
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
    #: the link is down (port gone, socket closed): the position is the last one known
    DISCONNECTED = "Disconnected"
    #: the link is up but this poll brought no fresh answer (late, garbled, refused, busy):
    #: the position is the last one known
    MISSED = "Missed"
    #: the controller answered with numbers that cannot be right (non-finite, beyond any
    #: machine): the position is the last one known, ``raw`` holds what was received
    BAD = "Bad"


#: run states that carry no fresh position: the monitor records them, marks them, and
#: neither syncs nor cuts on them
NOT_FRESH = frozenset({RunState.DISCONNECTED, RunState.MISSED, RunState.BAD})

#: a position coordinate beyond this (mm, or deg for A/B/C) is no machine's: BAD
MAX_POSITION = 1.0e5
#: feed (mm/min) and spindle speed (rpm) beyond these are no machine's: BAD
MAX_FEED = 1.0e6
MAX_SPINDLE = 1.0e6
#: integers a controller reports (line, alarm, overrides, buffer) beyond this are garbage
MAX_REPORTED_INT = 2**31 - 1


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

    @property
    def fresh(self) -> bool:
        """True when this state carries a position the controller just reported."""
        return self.state not in NOT_FRESH


def implausible(state: MachineState) -> str | None:
    """Why ``state``'s numbers cannot be right (one line), or None when they can.

    Non-finite or beyond-any-machine positions, offsets, feed or spindle speed, and
    integers (line, alarm, overrides, buffer) out of a 32-bit range. A driver turns such
    a reading into a :data:`RunState.BAD` state (see :func:`stale_state`) instead of
    handing it on: nothing non-finite or huge may reach the model.
    """
    for name, vec in (("position", state.mpos), ("work offset", state.wco)):
        for axis, v in zip("XYZABC", vec):
            if not math.isfinite(v) or abs(v) > MAX_POSITION:
                return f"{name} {axis}={v!r} is not a machine coordinate (|v| <= {MAX_POSITION:g})"
    for name, v, top in (("feed", state.feed, MAX_FEED), ("spindle speed", state.spindle, MAX_SPINDLE)):
        if not math.isfinite(v) or abs(v) > top:
            return f"{name} {v!r} is not a machine's (|v| <= {top:g})"
    ints = [("line", state.line), ("alarm", state.alarm), ("substate", state.substate)]
    ints += [("override", v) for v in state.overrides] + [("buffer", v) for v in (state.buffer or ())]
    for name, v in ints:
        if v is not None and not -MAX_REPORTED_INT <= v <= MAX_REPORTED_INT:
            return f"{name} {v!r} is out of range"
    return None


def stale_state(last: MachineState | None, state: RunState, t: float, raw: str) -> MachineState:
    """A not-fresh state (:data:`NOT_FRESH`) at time ``t``: the last known position,
    offsets, overrides and line (zeros before any), run state ``state``, and ``raw``
    saying why (the reason and, for BAD, the text received)."""
    if last is None:
        return MachineState(t=t, mpos=(0.0,) * 6, state=state, raw=raw)
    return MachineState(t=t, mpos=last.mpos, wco=last.wco, state=state, line=last.line,
                        overrides=last.overrides, raw=raw)


def check_device(port: str, what: str) -> None:
    """DriverError when ``port`` is a device path (not a pyserial URL) that does not exist."""
    from drivers.errors import ConnectionLost

    if "://" not in port and not os.path.exists(port):
        raise ConnectionLost(f"{what}: no such serial device {port!r} (is the controller plugged in and "
                             "switched on? its name is in /dev/serial/by-id)")


@dataclass(frozen=True)
class Gap:
    """A time the link was away: ``t_lost``/``t_back`` monotonic s, and why.

    ``polls_missed``: polls answered with DISCONNECTED meanwhile; ``lines_lost``: lines
    in flight whose answers went with the link; ``came_back``: how the controller came
    back when that is worth saying ("reset: Grbl 1.1h banner", "alarm 1"), else "".
    """

    t_lost: float
    t_back: float
    reason: str
    polls_missed: int = 0
    lines_lost: int = 0
    came_back: str = ""

    @property
    def seconds(self) -> float:
        return self.t_back - self.t_lost

    def __iter__(self):  # unpacks as (t_lost, t_back)
        return iter((self.t_lost, self.t_back))


class LinkKind(str, enum.Enum):
    """What a :class:`LinkEvent` reports."""

    LOST = "lost"      # the link went away
    BACK = "back"      # the link is back (``gap`` says for how long and what was missed)
    RESET = "reset"    # the controller reset (banner) or came back reset / in alarm
    BAD = "bad"        # a reply that cannot be right was recorded as BAD and skipped
    NOTE = "note"      # anything else worth a line (retries of busy answers, a dropped sender output ...)


@dataclass(frozen=True)
class LinkEvent:
    """Something that happened to the link, for the monitor to say and record.

    ``t`` monotonic s; ``message`` one line for a person (names the port); ``raw`` the
    bytes or registers involved, if any; ``gap`` the finished :class:`Gap` on BACK.
    """

    t: float
    kind: LinkKind
    message: str
    raw: str = ""
    gap: Gap | None = None


@dataclass(frozen=True)
class ControllerLimits:
    """The machine's limits as its controller states them (GRBL ``$$``, a Modbus map,
    the virtual machine's configuration); a field is None when the controller did not say.

    ``max_rate``: X Y Z, mm/min (GRBL ``$110-$112``); ``acceleration``: X Y Z, mm/s^2
    (``$120-$122``); ``junction_deviation``: mm (``$11``); ``travel``: X Y Z machine
    coordinate ranges ``(lo, hi)`` mm (GRBL homes to the positive end: ``(-$13x, 0)``);
    ``soft_limits``: whether the controller enforces ``travel`` (``$20``);
    ``report_inches``: positions are reported in inches (``$13``; the limits above are mm
    whatever it says); ``source``: where they were read, for the user ("GRBL $$ on
    /dev/ttyUSB0").
    """

    max_rate: tuple[float, float, float] | None = None
    acceleration: tuple[float, float, float] | None = None
    junction_deviation: float | None = None
    travel: tuple[tuple[float, float], ...] | None = None
    soft_limits: bool | None = None
    report_inches: bool | None = None
    source: str = ""

    def timing(self) -> dict:
        """The planner fields known, as ``[machine]`` names them (``max_rate``,
        ``acceleration``, ``junction_deviation``)."""
        out = {}
        for name in ("max_rate", "acceleration", "junction_deviation"):
            if getattr(self, name) is not None:
                out[name] = getattr(self, name)
        return out

    def travel_limits(self) -> dict | None:
        """``{axis: (lo, hi)}`` machine coordinates, mm, when the controller enforces its
        travel (soft limits on), else None: without soft limits (and so homing) machine
        coordinates need not be where the travel numbers say."""
        if not self.soft_limits or not self.travel:
            return None
        return {axis: (float(lo), float(hi)) for axis, (lo, hi) in zip("XYZ", self.travel)}


class Controller(abc.ABC):
    """Interface of every controller driver (GRBL, Modbus, virtual).

    A controller is opened from a URL (see :func:`drivers.registry.open_controller`),
    then ``connect()``-ed. ``poll()`` returns the newest state; ``states(period)`` yields
    states at a rate. The monitor only ever calls ``feed_hold()`` among the commands,
    and only when the user enabled it.

    The contract the monitor relies on, once ``connect()`` succeeded:

    * ``poll()`` does not raise for anything the link or the controller does: a link
      that is down gives a DISCONNECTED state, a late, garbled, refused or busy answer a
      MISSED one, an answer whose numbers cannot be right (:func:`implausible`) a BAD
      one (:func:`stale_state` makes all three). The driver reconnects by itself,
      retrying at least as often as it is polled, and redoes its handshake.
    * A fresh state (``state.fresh``) comes from an answer that arrived after the poll
      asked for it; ``t`` never goes backwards from one returned state to the next.
    * Link trouble is also told once as :class:`LinkEvent` s, drained with
      :meth:`link_events`; every finished outage is in ``gaps``.
    * No driver thread dies quietly: a failure inside becomes a state, an event or a
      reconnect.
    """

    url: str = ""
    #: whether states carry the controller's work offset in ``wco`` (False: not reported,
    #: zeros); the monitor compares it with the job's work offset only when True
    reports_wco: bool = True
    #: finished outages, oldest first
    gaps: list[Gap]

    def link_events(self) -> list[LinkEvent]:
        """The link events since the last call, oldest first (and forgets them)."""
        q = self.__dict__.get("_link_q")
        out = []
        while q:
            try:
                out.append(q.popleft())
            except IndexError:
                break
        return out

    def _link_event(self, kind: LinkKind, message: str, raw: str = "", gap: Gap | None = None,
                    t: float | None = None) -> LinkEvent:
        """Queue a :class:`LinkEvent` for :meth:`link_events` (thread-safe; the oldest are
        dropped past 1000 undrained)."""
        ev = LinkEvent(time.monotonic() if t is None else t, LinkKind(kind), message, raw, gap)
        self.__dict__.setdefault("_link_q", collections.deque(maxlen=1000)).append(ev)
        return ev

    def preflight(self) -> None:
        """Cheap checks that need no connection (a serial device that does not exist),
        made before anything slow starts: raise DriverError naming what is wrong."""

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

    def machine_limits(self) -> ControllerLimits | None:
        """The machine's limits as the controller stated them, or None while unknown (a
        GRBL attached to a busy machine reads ``$$`` once it is Idle)."""
        return None

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
