"""What the virtual machine can do, in GRBL's terms: :class:`MachineConfig` (rates,
accelerations, junction deviation, arc tolerance, travel and planner size), as the
machine plans with it and as a controller states it (:meth:`MachineConfig.limits`).

Units: mm/min for rates, mm/s^2 for accelerations, mm for lengths (A B C: degrees).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivers.state import ControllerLimits


def _vec6(values, name: str) -> tuple[float, ...]:
    out = [float(v) for v in values]
    if not 1 <= len(out) <= 6:
        raise ValueError(f"{name}: expected 1 to 6 values (X Y Z A B C), got {len(out)}")
    return tuple(out)


@dataclass(frozen=True)
class MachineConfig:
    """What the machine can do, in GRBL's terms.

    Attributes
    ----------
    max_rate : tuple of float, per axis X Y Z [A B C], mm/min (GRBL $110-$112)
    accel : tuple of float, per axis, mm/s^2 (GRBL $120-$122)
    junction_deviation : float, mm (GRBL $11)
    arc_tolerance : float, mm (GRBL $12): chord error of arc segments
    travel_min, travel_max : tuple of float per axis, mm, or None for no soft limits.
        GRBL homes to the positive end, so its travel is ``[-$13x, 0]``.
    planner_blocks : int, free planner blocks (GRBL 1.1: 15, 14 with line numbers)
    soft_limits : bool (GRBL $20)
    """

    max_rate: tuple[float, ...] = (500.0, 500.0, 500.0)
    accel: tuple[float, ...] = (10.0, 10.0, 10.0)
    junction_deviation: float = 0.01
    arc_tolerance: float = 0.002
    travel_min: tuple[float, ...] | None = (-200.0, -200.0, -200.0)
    travel_max: tuple[float, ...] | None = (0.0, 0.0, 0.0)
    planner_blocks: int = 15
    soft_limits: bool = True

    def __post_init__(self):
        object.__setattr__(self, "max_rate", _vec6(self.max_rate, "max_rate"))
        object.__setattr__(self, "accel", _vec6(self.accel, "accel"))
        if len(self.accel) != len(self.max_rate):
            raise ValueError("accel and max_rate must name the same axes")
        if any(v <= 0 for v in self.max_rate + self.accel):
            raise ValueError("max_rate and accel must be > 0")
        if self.junction_deviation < 0 or self.arc_tolerance <= 0:
            raise ValueError("junction_deviation must be >= 0 and arc_tolerance > 0")
        if self.planner_blocks < 1:
            raise ValueError("planner_blocks must be >= 1")
        for name in ("travel_min", "travel_max"):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, _vec6(v, name))

    @property
    def n_axes(self) -> int:
        return len(self.max_rate)

    def axis_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-axis max rate (mm/s) and acceleration (mm/s^2), shape (6,); axes beyond
        the configured ones get +inf (they never limit) ."""
        rate = np.full(6, np.inf)
        acc = np.full(6, np.inf)
        rate[: self.n_axes] = np.asarray(self.max_rate) / 60.0
        acc[: self.n_axes] = np.asarray(self.accel)
        return rate, acc

    def limits(self, source: str) -> ControllerLimits:
        """These limits as a controller states them (X Y Z)."""
        travel = None
        if self.travel_min is not None and self.travel_max is not None:
            travel = tuple((float(lo), float(hi)) for lo, hi in zip(self.travel_min[:3], self.travel_max[:3]))
        return ControllerLimits(max_rate=tuple(float(v) for v in self.max_rate[:3]),
                                acceleration=tuple(float(v) for v in self.accel[:3]),
                                junction_deviation=float(self.junction_deviation) or None, travel=travel,
                                soft_limits=bool(self.soft_limits), report_inches=False, source=source)

    def out_of_travel(self, target: np.ndarray) -> bool:
        """True when ``target`` (shape (6,), mm) is outside the soft limits."""
        if not self.soft_limits:
            return False
        eps = 1e-6
        if self.travel_min is not None:
            lo = np.asarray(self.travel_min)
            if np.any(target[: len(lo)] < lo - eps):
                return True
        if self.travel_max is not None:
            hi = np.asarray(self.travel_max)
            if np.any(target[: len(hi)] > hi + eps):
                return True
        return False
