"""Fault injection for the virtual controller and the protocol peers.

A :class:`FaultPlan` says what goes wrong and when; a :class:`FaultInjector` draws the
faults from a seeded generator, so a run with the same plan fails the same way every
time. The plan is written as a spec string in URLs and on the command line::

    drop=0.05,garble=0.02,late=0.1,late_s=0.3,bad=0.01,disconnect=12.5,disconnect_for=2,reset=1,alarm=30:1,seed=7

``drop``/``garble``/``late``/``bad`` are probabilities per reply (``bad``: a reply whose
numbers cannot be right, a NaN position); ``disconnect`` and ``alarm`` are simulated times
(s) at which the link goes away (for ``disconnect_for`` s) and at which the machine raises
an alarm (``alarm=T`` or ``alarm=T:CODE``, code 1 by default, GRBL's hard limit);
``reset=1``: the controller restarted while the link was down and comes back at
(0, 0, 0) in alarm, its position lost. ``:`` may replace ``=`` (``drop:0.05``).
"""

from __future__ import annotations

import random
from dataclasses import dataclass, fields

from drivers.errors import DriverError

#: what can happen to one reply
REPLY_OK, REPLY_DROP, REPLY_GARBLE, REPLY_LATE, REPLY_BAD = "ok", "drop", "garble", "late", "bad"


class FaultSpecError(DriverError):
    """A fault spec string that does not parse."""


@dataclass(frozen=True)
class FaultPlan:
    """What goes wrong. Probabilities in [0, 1]; times in simulated seconds."""

    drop: float = 0.0
    garble: float = 0.0
    late: float = 0.0
    late_s: float = 0.25
    bad: float = 0.0
    disconnect: float | None = None
    disconnect_for: float = 1.0
    reset: bool = False
    alarm: float | None = None
    alarm_code: int = 1
    seed: int = 0

    def __post_init__(self):
        for name in ("drop", "garble", "late", "bad"):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise FaultSpecError(f"fault {name}={p}: expected a probability between 0 and 1")
        if self.drop + self.garble + self.late + self.bad > 1.0:
            raise FaultSpecError("faults drop+garble+late+bad add up to more than 1")
        if self.late_s < 0 or self.disconnect_for < 0:
            raise FaultSpecError("fault durations late_s and disconnect_for must be >= 0")

    @property
    def any(self) -> bool:
        return bool(self.drop or self.garble or self.late or self.bad or self.disconnect is not None
                    or self.alarm is not None)

    @classmethod
    def parse(cls, spec: str | None) -> "FaultPlan":
        """Parse ``"drop=0.1,alarm=30:2,seed=3"``; empty or None gives no faults."""
        if not spec:
            return cls()
        known = {f.name for f in fields(cls)}
        values: dict[str, object] = {}
        for item in spec.replace(";", ",").split(","):
            item = item.strip()
            if not item:
                continue
            key, sep, val = item.replace("=", ":", 1).partition(":")
            key = key.strip()
            if not sep or key not in known or key == "alarm_code":
                expected = "drop, garble, late, late_s, bad, disconnect, disconnect_for, reset, alarm, seed"
                raise FaultSpecError(f"fault spec {spec!r}: bad item {item!r}; expected KEY=VALUE with KEY one of {expected}")
            try:
                if key == "alarm":
                    t, _, code = val.partition(":")
                    values["alarm"] = float(t)
                    if code:
                        values["alarm_code"] = int(code)
                elif key == "seed":
                    values["seed"] = int(val)
                elif key == "reset":
                    if val.strip() not in ("0", "1"):
                        raise FaultSpecError(f"fault spec {spec!r}: reset={val!r}: expected 0 or 1")
                    values["reset"] = val.strip() == "1"
                else:
                    values[key] = float(val)
            except ValueError:
                raise FaultSpecError(f"fault spec {spec!r}: {key}={val!r} is not a number") from None
        return cls(**values)


class FaultInjector:
    """Draws faults from a :class:`FaultPlan` with its own seeded generator."""

    def __init__(self, plan: FaultPlan | str | None = None):
        self.plan = plan if isinstance(plan, FaultPlan) else FaultPlan.parse(plan)
        self.rng = random.Random(self.plan.seed)
        self._alarm_fired = False
        self.counts = {REPLY_DROP: 0, REPLY_GARBLE: 0, REPLY_LATE: 0, REPLY_BAD: 0, "disconnect": 0, "alarm": 0}
        self._was_down = False

    def reply_fault(self) -> str:
        """One draw per reply: ``"ok"``, ``"drop"``, ``"garble"``, ``"late"`` or ``"bad"``."""
        p = self.plan
        if not (p.drop or p.garble or p.late or p.bad):
            return REPLY_OK
        x = self.rng.random()
        for kind, prob in ((REPLY_DROP, p.drop), (REPLY_GARBLE, p.garble), (REPLY_LATE, p.late), (REPLY_BAD, p.bad)):
            if x < prob:
                self.counts[kind] += 1
                return kind
            x -= prob
        return REPLY_OK

    def garble_bytes(self, data: bytes) -> bytes:
        """``data`` with a few bytes replaced by noise (line ends kept, so framing holds)."""
        if not data:
            return data
        buf = bytearray(data)
        body = [i for i, b in enumerate(buf) if b not in (0x0A, 0x0D)]
        if not body:
            return bytes(buf)
        for _ in range(max(1, len(body) // 8)):
            i = self.rng.choice(body)
            buf[i] = self.rng.choice(b"#%&@~\x7f\xfe\x00|:,.")
        return bytes(buf)

    def disconnected(self, t: float) -> bool:
        """True while simulated time ``t`` (s) is inside the disconnect window."""
        p = self.plan
        down = p.disconnect is not None and p.disconnect <= t < p.disconnect + p.disconnect_for
        if down and not self._was_down:
            self.counts["disconnect"] += 1
        self._was_down = down
        return down

    def due_alarm(self, t: float) -> int | None:
        """The alarm code, once, when simulated time ``t`` has reached the alarm time."""
        p = self.plan
        if p.alarm is not None and not self._alarm_fired and t >= p.alarm:
            self._alarm_fired = True
            self.counts["alarm"] += 1
            return p.alarm_code
        return None
