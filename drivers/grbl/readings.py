"""What GRBL's reports and settings say, in mm: status reports as :class:`MachineState`,
the report units (``$13``, the report's format), the work offset in force (``WCO:``,
``$#`` and ``$G``), the machine's limits (``$$``), and the limit alarms Grbl leaves
unreported. The wire itself (messages, parsing, line assembly) is :mod:`.protocol`.
"""

from __future__ import annotations

import dataclasses
import math
import re

from drivers.grbl.protocol import (ALARM_MEANINGS, MM_PER_INCH, OFFSET_TAGS, ParserState,
                                   StatusReport)
from drivers.state import ControllerLimits, MachineState, RunState, stale_state


def status_to_state(
    report: StatusReport,
    settings: dict[int, float] | None,
    last_wco,
    t: float,
    prev: MachineState | None = None,
    alarm: int | None = None,
) -> MachineState:
    """Turn a status report into a :class:`MachineState` in mm and mm/min.

    Parameters
    ----------
    report : StatusReport
    settings : dict int -> float or None
        GRBL ``$$`` settings; ``$13=1`` means the report is in inches (converted to mm).
        Without a ``$13`` of 0 or 1 (not read yet, or garbage), the report's format
        decides (:func:`report_in_inches`).
    last_wco : sequence of float or None
        Work coordinate offset, mm, remembered from an earlier report (GRBL sends
        ``WCO:`` only every 10th-30th report); used when ``report`` carries none.
    t : float
        ``time.monotonic()`` at which the report's bytes arrived, s.
    prev : MachineState or None
        The previous state: overrides and accessories carry over when the report has no
        ``Ov:`` (GRBL sends ``A:`` only along with ``Ov:``).
    alarm : int or None
        Last ``ALARM:N`` code, kept when the state is Alarm.

    The returned state's ``wco`` is the offset in force, so callers remember it as the
    next ``last_wco``. With no offset known yet (neither in the report nor remembered)
    raises :class:`OffsetUnknown`: a work position is then no position at all, and a
    machine position without its offset would put the tool elsewhere in the work
    system (see :func:`offset_in_force` for the offset a driver can know from ``$#``).
    """
    inches = inch_setting(settings)
    if inches is None:
        inches = report_in_inches(report)
    scales = _axis_scales(settings, inches)
    if report.wco is not None:
        wco = tuple(v * k for v, k in zip(report.wco, scales))
    elif last_wco is not None:
        wco = tuple(float(v) for v in last_wco)
    else:
        raise OffsetUnknown(f"{'work' if report.mpos is None else 'machine'} position reported and the work "
                            "offset (WCO) not known yet: Grbl sends it in every 10th to 30th report")
    wco6 = (tuple(wco) + (0.0,) * 6)[:6]
    if report.mpos is not None:
        mpos = tuple(v * k for v, k in zip(report.mpos, scales))
    else:
        mpos = tuple(w * k + o for w, k, o in zip(report.wpos, scales, wco6))
    if report.overrides is not None:
        overrides = report.overrides
        accessories = report.accessories or ""
    elif prev is not None:
        overrides, accessories = prev.overrides, prev.accessories
    else:
        overrides, accessories = (100, 100, 100), ""
    spindle = report.spindle if report.spindle is not None else (prev.spindle if prev else 0.0)
    spindle = abs(spindle)
    if "C" in accessories:
        spindle = -spindle
    feed = (report.feed or 0.0) * (MM_PER_INCH if inches else 1.0)
    state = report.run_state
    return MachineState(
        t=t,
        mpos=mpos,
        wco=wco6,
        state=state,
        substate=report.substate,
        feed=feed,
        spindle=spindle,
        line=report.line,
        overrides=overrides,
        alarm=alarm if state is RunState.ALARM else None,
        buffer=report.buffer,
        pins=report.pins,
        accessories=accessories,
        raw=report.raw,
    )


#: ALARM codes after which Grbl 1.1h spins until Ctrl-X (hard and soft limit, protocol.c):
#: it answers no ``?`` meanwhile, so a driver knows the state only from the ALARM line
CRITICAL_ALARMS = (1, 2)


class OffsetUnknown(ValueError):
    """A status report converted before the work offset (WCO) in force is known."""


def _axis_scales(settings: dict[int, float] | None, inches: bool) -> tuple[float, ...]:
    """mm per reported unit of each axis: 25.4 in inches but for the axes grblHAL's
    ``$376`` calls rotary, which stay in degrees."""
    rotary = rotary_axes(settings)
    return tuple(1.0 if i in rotary or not inches else MM_PER_INCH for i in range(6))


def offset_in_force(offsets: dict[str, tuple[float, ...]], parser: ParserState | None,
                    settings: dict[int, float] | None) -> tuple[float, ...] | None:
    """The WCO a status report would carry, mm (6,), from the ``$#`` lines ``offsets``
    (name -> values as sent) and the ``$G`` state ``parser``: the active work system's
    offset plus G92, plus the tool length offset on Z (report.c); None until all of them
    are known. In inches when ``$13`` says so, as ``$#`` prints them."""
    if parser is None:
        return None
    system = next((w for w in parser.words if w in OFFSET_TAGS[:6]), None)
    if system is None or system not in offsets or "G92" not in offsets or "TLO" not in offsets:
        return None
    scales = _axis_scales(settings, bool(inch_setting(settings)))
    wco = [0.0] * 6
    for values in (offsets[system], offsets["G92"]):
        for i, v in enumerate(values[:6]):
            wco[i] += v * scales[i]
    wco[2] += offsets["TLO"][0] * scales[2]
    return tuple(wco)


def critical_alarm_state(last: MachineState | None, code: int, t: float) -> MachineState:
    """The state at ``t`` after critical ``ALARM:code`` (:data:`CRITICAL_ALARMS`), which
    Grbl will not report: Alarm, at the last position reported (the machine stopped
    there or just past it), feed 0."""
    why = (f"ALARM:{code} ({ALARM_MEANINGS.get(code, 'unknown alarm')}): GRBL answers no status report "
           "until it is reset (Ctrl-X); position as last reported")
    return dataclasses.replace(stale_state(last, RunState.ALARM, t, why), alarm=code, feed=0.0)


def inch_setting(settings: dict[int, float] | None) -> bool | None:
    """``$13`` (report inches) from ``settings``: True/False, or None when it is absent or
    not one of the 0/1 GRBL prints (a garbled value must not decide the units)."""
    value = (settings or {}).get(13)
    if value in (0, 1):  # NaN, inf and 1e5 are not
        return value == 1
    return None


def settings_limits(settings: dict[int, float] | None, source: str, option_codes: str = "") -> ControllerLimits | None:
    """The machine's limits from GRBL ``$$`` settings: ``$110-$112`` max rates (mm/min),
    ``$120-$122`` accelerations (mm/s^2), ``$11`` junction deviation (mm), ``$130-$132``
    travel (mm), ``$20`` soft limits, ``$13`` report inches. GRBL keeps all of them in mm
    whatever ``$13`` says. The travel is ``[-$13x, 0]`` (GRBL's soft-limit check), or
    ``[0, $13x]`` for an axis homing to its negative end (``$23`` bit set) on a firmware
    built with HOMING_FORCE_SET_ORIGIN (``Z`` among ``option_codes``, from ``$I``'s
    ``[OPT:]``). A group missing or not positive and finite is None; None when no limit
    at all is known (``$$`` not read yet)."""
    settings = settings or {}

    def axes(first: int) -> tuple[float, float, float] | None:
        vals = [settings.get(first + i) for i in range(3)]
        if all(v is not None and math.isfinite(v) and v > 0 for v in vals):
            return tuple(float(v) for v in vals)
        return None

    rate, accel, travel = axes(110), axes(120), axes(130)
    jd = settings.get(11)
    jd = float(jd) if jd is not None and math.isfinite(jd) and jd > 0 else None
    if rate is None and accel is None and jd is None and travel is None:
        return None
    soft = settings.get(20)
    if travel is not None:
        dir_mask = int(settings.get(23, 0)) if math.isfinite(settings.get(23, 0)) else 0
        positive = ["Z" in option_codes and bool(dir_mask >> i & 1) for i in range(3)]
        travel = tuple((0.0, v) if up else (-v, 0.0) for v, up in zip(travel, positive))
    return ControllerLimits(max_rate=rate, acceleration=accel, junction_deviation=jd, travel=travel,
                            soft_limits=None if soft not in (0, 1) else soft == 1,
                            report_inches=inch_setting(settings), source=source)


_POSITION_DECIMALS = re.compile(r"[MW]Pos:[+-]?\d*\.(\d*)")


#: grblHAL's $376: the mask of axes that are rotary (bit 3 A, 4 B, 5 C)
ROTARY_AXES_SETTING = 376


def rotary_axes(settings: dict[int, float] | None) -> frozenset[int]:
    """Columns (3 A, 4 B, 5 C) of the axes that are rotary, in degrees whatever ``$13``.

    grblHAL's ``$376`` mask says which (its inch reports leave those axes in degrees,
    report.c get_axis_values_inches); without a ``$376`` it can mean (not read, Grbl
    1.1h's 3 axes, garbage), A B C are rotary, as their letters say.
    """
    value = (settings or {}).get(ROTARY_AXES_SETTING)
    if isinstance(value, (int, float)) and float(value).is_integer() and 0 <= value < 256:
        return frozenset(i for i in (3, 4, 5) if int(value) >> i & 1)
    return frozenset((3, 4, 5))


def report_in_inches(report: StatusReport) -> bool:
    """Whether a report's format says inches: Grbl 1.1h prints positions with 4 decimals
    in inches and 3 in mm (``N_DECIMAL_COORDVALUE_INCH``/``_MM``). Used until ``$13`` is
    known."""
    m = _POSITION_DECIMALS.search(report.raw)
    return bool(m) and len(m.group(1)) == 4
