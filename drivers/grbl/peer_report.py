"""What the GRBL peer reports, formatted as Grbl 1.1h's report.c does.

* :class:`ReportCadence`: when a status report carries ``WCO:`` and ``Ov:`` (with ``A:``);
* :class:`Accessories`: the spindle and coolant outputs (``FS:`` rpm, ``A:`` letters);
* :func:`status_report`: the ``<...>`` line from a machine snapshot;
* the ``$$`` ``$#`` ``$G`` lines.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivers.grbl import protocol as p
from drivers.state import RunState
from sim.gcode.moves import COOLANT_FLOOD, COOLANT_MIST

#: report.c's refresh counts (config.h): reports between WCO / Ov fields, busy and idle
WCO_REFRESH_BUSY, WCO_REFRESH_IDLE = 30, 10
OVR_REFRESH_BUSY, OVR_REFRESH_IDLE = 20, 10
#: states GRBL counts as busy for the cadence (STATE_HOMING | CYCLE | HOLD | JOG | SAFETY_DOOR)
BUSY_STATES = (RunState.RUN, RunState.HOLD, RunState.JOG, RunState.HOME, RunState.DOOR)


class ReportCadence:
    """GRBL's ``report_wco_counter`` and ``report_ovr_counter``.

    A counter at 0 puts its field in the next report, which sets it to the refresh count
    less one; :meth:`flag_wco` / :meth:`flag_ovr` set it to 0 (an offset, override,
    spindle or coolant change is reported at once). Both start at 0 after a reset."""

    def __init__(self):
        self.wco = 0
        self.ovr = 0

    def flag_wco(self) -> None:
        """``system_flag_wco_change``: WCO in the next report."""
        self.wco = 0

    def flag_ovr(self) -> None:
        """An override, spindle or coolant change: Ov (and A:) in the next report."""
        self.ovr = 0

    def next_fields(self, busy: bool) -> tuple[bool, bool]:
        """Advance for one report; (report WCO, report Ov) for it."""
        with_wco = with_ov = False
        if self.wco > 0:
            self.wco -= 1
        else:
            self.wco = (WCO_REFRESH_BUSY if busy else WCO_REFRESH_IDLE) - 1
            if self.ovr == 0:
                self.ovr = 1  # Ov on the next report, not with WCO
            with_wco = True
        if self.ovr > 0:
            self.ovr -= 1
        else:
            self.ovr = (OVR_REFRESH_BUSY if busy else OVR_REFRESH_IDLE) - 1
            with_ov = True
        return with_wco, with_ov


@dataclass
class Accessories:
    """The spindle and coolant outputs as GRBL drives them (not the parser's modal words:
    a change reaches the outputs only after the planner is empty, ``spindle_sync``).

    ``direction``: 1 CW (M3), -1 CCW (M4), 0 off; ``rpm``: programmed S, rev/min;
    ``coolant``: COOLANT_FLOOD / COOLANT_MIST bits; ``stopped``: the spindle stop override
    (0x9E) holds the spindle off during a feed hold; ``killed``: a limit alarm's mc_reset
    turned the pins off (``A:`` empty) but left ``sys.spindle_speed`` (``FS:``) until the
    reset re-initialises."""

    direction: int = 0
    rpm: float = 0.0
    coolant: int = 0
    stopped: bool = False
    killed: bool = False

    def outputs(self) -> tuple[int, float, int]:
        """(direction, rpm, coolant), as the parser asks them of the outputs (rpm 0 when off)."""
        return self.direction, self.rpm if self.direction else 0.0, self.coolant

    def speed(self, override_pct: int, settings: dict[int, float]) -> float:
        """``sys.spindle_speed``: S scaled by the override, clamped to ``$31``..``$30``, rev/min;
        0 when the spindle is off (spindle_compute_pwm_value)."""
        if not self.direction or self.stopped:
            return 0.0
        rpm = self.rpm * override_pct / 100.0
        rpm_max, rpm_min = float(settings.get(30, 1000.0)), float(settings.get(31, 0.0))
        if rpm_min >= rpm_max or rpm >= rpm_max:
            return rpm_max
        if rpm <= rpm_min:
            return 0.0 if rpm == 0.0 else rpm_min
        return rpm

    def letters(self, settings: dict[int, float]) -> str:
        """The ``A:`` letters: S (CW) or C (CCW) while the spindle output is on, F flood,
        M mist; "" when all are off (S0 turns the PWM output off, and with it S/C)."""
        out = ""
        if self.killed:
            return out
        no_pwm_range = float(settings.get(31, 0.0)) >= float(settings.get(30, 1000.0))
        if self.direction and not self.stopped and (self.rpm > 0.0 or no_pwm_range):
            out += "S" if self.direction > 0 else "C"
        if self.coolant & COOLANT_FLOOD:
            out += "F"
        if self.coolant & COOLANT_MIST:
            out += "M"
        return out


def fmt(values, decimals: int) -> str:
    return ",".join(f"{v:.{decimals}f}" for v in values)


def status_report(snapshot, state_name: str, settings: dict[int, float], cadence: ReportCadence,
                  accessories: Accessories, planner_free: int, rx_free: int, line_number: int | None) -> str:
    """The ``<...>`` report (report_realtime_status); advances ``cadence``.

    ``snapshot``: the machine's :class:`~drivers.state.MachineState` (mm, mm/min);
    ``state_name``: ``Idle``, ``Hold:0`` ...; ``line_number``: the N word of the block
    being executed, or None."""
    s = snapshot
    inches = int(settings.get(13, 0)) & 1
    scale, dec = (1.0 / p.MM_PER_INCH, 4) if inches else (1.0, 3)
    mask = int(settings.get(10, 1))
    pos = np.asarray(s.mpos[:3])
    wco = np.asarray(s.wco[:3])
    fields = [state_name]
    if mask & 1:
        fields.append("MPos:" + fmt(pos * scale, dec))
    else:
        fields.append("WPos:" + fmt((pos - wco) * scale, dec))
    if mask & 2:
        fields.append(f"Bf:{planner_free},{rx_free}")
    if line_number is not None:
        fields.append(f"Ln:{line_number}")
    spindle_ovr = s.overrides[2]
    fields.append(f"FS:{s.feed * scale:.{1 if inches else 0}f},{accessories.speed(spindle_ovr, settings):.0f}")
    with_wco, with_ov = cadence.next_fields(s.state in BUSY_STATES)
    if with_wco:
        fields.append("WCO:" + fmt(wco * scale, dec))
    if with_ov:
        fields.append(f"Ov:{s.overrides[0]},{s.overrides[1]},{s.overrides[2]}")
        letters = accessories.letters(settings)
        if letters:
            fields.append("A:" + letters)
    return "<" + "|".join(fields) + ">"


def setting_text(n: int, v: float) -> str:
    """``$n`` value as ``$$`` prints it: floats with 3 decimals, flags and masks as integers."""
    if n in (11, 12, 24, 25, 27) or 100 <= n <= 132:
        return f"{v:.3f}"
    return f"{int(v)}" if float(v).is_integer() else f"{v:.3f}"


def settings_from_config(cfg) -> dict[int, float]:
    """``$n`` settings a :class:`~drivers.virtual.machine_config.MachineConfig` implies.

    ``$20`` (soft limits) is 1 only for a machine with soft limits on and a travel to check
    them against: stock Grbl reports ``$20=0``."""
    has_travel = cfg.travel_min is not None and cfg.travel_max is not None
    out: dict[int, float] = {11: cfg.junction_deviation, 20: 1.0 if cfg.soft_limits and has_travel else 0.0}
    if getattr(cfg, "arc_tolerance", None) is not None:
        out[12] = cfg.arc_tolerance
    for i in range(3):
        if i < len(cfg.max_rate):
            out[110 + i] = cfg.max_rate[i]
        if i < len(cfg.accel):
            out[120 + i] = cfg.accel[i]
        if has_travel and i < len(cfg.travel_min):
            out[130 + i] = cfg.travel_max[i] - cfg.travel_min[i]
    return out
