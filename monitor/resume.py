"""Carry on from any stage of a recorded run: ``dexmon simulate PROGRAM --resume RUN:STAGE``.

The z-trace rebuilds the model as it was at that stage (Blasquez & Poiraudeau's reason
for keeping the complete trace: try a corrected path without re-running the first part).
"""

from __future__ import annotations

from pathlib import Path

from sim.errors import InputError
from sim.grid import DexelGrid


def parse_resume(spec: str) -> tuple[Path, str]:
    """``RUN:STAGE`` -> (run path, stage text); the stage is after the last colon."""
    path, sep, stage = str(spec).rpartition(":")
    if not sep or not path or not stage.strip():
        raise InputError(f"expected RUN:STAGE (e.g. job.dexrun:1200 or job.dexrun:end), got {spec!r}",
                         "--resume")
    return Path(path), stage.strip()


def resume_grid(spec: str) -> tuple[DexelGrid, int]:
    """The model rebuilt at ``RUN:STAGE`` and the stage number it is at."""
    from monitor.commands.replay import parse_stage
    from monitor.trace_io import RunView

    path, stage_text = parse_resume(spec)
    if not path.is_file():
        raise InputError("no such run file", f"--resume {path}")
    # the stages replay shows: 'end' is the same model here and there, also for a run cut short
    with RunView(path) as view:
        trace = view.trace
        first, last, short = view.first_stage, view.last_stage, view.cut_short
        damage = view.damage_line
    if trace.z is None:
        raise InputError("the run has no z-trace, so its model cannot be rebuilt", f"--resume {path}")
    stage = parse_stage(stage_text, last, first, "--resume")
    if stage > last:
        why = [x for x in (damage, short and f"the run was {short}") if x]
        raise InputError(f"stage {stage} is beyond the run's last recorded stage {last}"
                         + (f" ({'; '.join(why)})" if why else ""), f"--resume {spec}")
    return trace.grid_at(stage), stage
