"""The machine limits in force for program timing (and so lead times) and travel checks.

Each planner field (``max_rate``, ``acceleration``, ``junction_deviation``) comes from
the job's ``[machine]`` when it gives it, else from the controller (GRBL ``$$``, the
virtual machine's configuration), else :data:`monitor.job.DEFAULT_MACHINE`. Travel limits
come from the job's ``[limits]``, else from the controller when it enforces its travel
(GRBL ``$20=1``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from drivers.state import ControllerLimits
from monitor.job import DEFAULT_MACHINE

TIMING_FIELDS = ("max_rate", "acceleration", "junction_deviation")


@dataclass(frozen=True)
class InForce:
    """Program timing limits in force and where each came from.

    ``machine``: the planner's fields (mm/min, mm/s^2, mm); ``sources``: field ->
    ``"job"``, ``"controller"`` or ``"default"``; ``controller``: what the controller
    said (None while unknown)."""

    machine: dict
    sources: dict
    controller: ControllerLimits | None = None
    travel: dict | None = field(default=None)
    travel_source: str = ""

    def describe(self) -> str:
        """One line for the run's start: each figure, and where it came from."""
        m, src = self.machine, self.sources
        where = {"job": "job [machine]", "default": "dexmon default",
                 "controller": (self.controller.source if self.controller and self.controller.source
                                else "controller")}
        figures = {"max_rate": f"max rate {_xyz(m['max_rate'])} mm/min",
                   "acceleration": f"acceleration {_xyz(m['acceleration'])} mm/s^2",
                   "junction_deviation": f"junction deviation {m['junction_deviation']:g} mm"}
        by_source: dict[str, list[str]] = {}
        for name in TIMING_FIELDS:
            by_source.setdefault(src[name], []).append(figures[name])
        line = "machine limits: " + "; ".join(f"{', '.join(parts)} (from {where[s]})"
                                              for s, parts in by_source.items())
        if self.travel_source == "controller":
            line += f"; travel limits {_ranges(self.travel)} mm (from {where['controller']}, soft limits on)"
        return line

    def to_json(self) -> dict:
        out = {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.machine.items()}
        out["sources"] = dict(self.sources)
        if self.controller is not None:
            out["controller"] = self.controller.source
        if self.travel_source:
            out["travel_source"] = self.travel_source
        return out


def in_force(job_machine: dict | None, controller: ControllerLimits | None, job_limits: dict | None = None,
             default: dict = DEFAULT_MACHINE) -> InForce:
    """The limits in force: the job's ``[machine]`` field by field over the controller's
    over ``default``; travel: the job's ``[limits]``, else the controller's when it
    enforces them."""
    said = controller.timing() if controller is not None else {}
    machine, sources = {}, {}
    for name in TIMING_FIELDS:
        for source, values in (("job", job_machine or {}), ("controller", said), ("default", default)):
            if name in values:
                machine[name] = values[name]
                sources[name] = source
                break
    travel, travel_source = (dict(job_limits), "job") if job_limits else (None, "")
    if travel is None and controller is not None and controller.travel_limits():
        travel, travel_source = controller.travel_limits(), "controller"
    return InForce(machine, sources, controller, travel, travel_source)


def _xyz(values) -> str:
    return " ".join(f"{a}{float(v):g}" for a, v in zip("XYZABC", values))


def _ranges(travel: dict | None) -> str:
    return " ".join(f"{a}[{lo:g}, {hi:g}]" for a, (lo, hi) in (travel or {}).items())
