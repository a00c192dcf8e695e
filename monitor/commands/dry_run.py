"""``dexmon dry-run [JOB] [--speed N]``: run a job against the virtual controller.

    dexmon dry-run                      the bundled example (monitor/examples/clamp_job)
    dexmon dry-run JOB.toml --speed 20  any job, 20 x faster than real time
    dexmon dry-run --program P.nc --stock box:... --tool ball:6   a job given by flags alone

The program runs on an in-process virtual machine (no soft limits: the job's [limits]
are what the monitor checks) and the monitor follows it exactly as it follows a real
machine: same sync, cutting, look-ahead, alerts and run file. With ``--feed-hold`` dexmon
holds the virtual machine on a finding and resumes it itself after a few seconds (it has
no cycle-start button). Exit 0 clean, 1 findings, 2 error, 128 + the signal's number when
interrupted (130 Ctrl-C, 143 SIGTERM, 129 SIGHUP).

The machine starts where the job's machine would (``[machine] start``, default the top of
the Z travel above the program's first point: :mod:`monitor.start`), so a dry run and
``simulate`` judge the same first move. Its work offsets are the job's .var file's; without
one its work system is set up at the job's ``work_offset`` (a number), as the job says the
real machine is. ``--clock sim`` moves the machine ``speed / poll_hz`` seconds per poll
instead of by the wall clock: the run is then the same however busy the computer is.
With ``--web`` the virtual machine starts when the browser page has opened (a dry run is
there to be watched from its first move).
"""

from __future__ import annotations

from pathlib import Path

from monitor.commands.live import add_common_arguments, run_session
from monitor.job import job_from_args, require

HELP = "run a job against the virtual controller"

#: the bundled example job
EXAMPLE_JOB = Path(__file__).resolve().parent.parent / "examples" / "clamp_job" / "job.toml"

#: a brisk hobby-mill: 5 m/min rapids, no soft limits (the job's limits are checked instead)
VIRTUAL_MAX_RATE = (5000.0, 5000.0, 2000.0)
VIRTUAL_ACCEL = (300.0, 300.0, 200.0)
#: a dry run's virtual machine, held by dexmon's feed hold, is resumed by dexmon after this
#: long (s): it has no cycle-start button
DRY_RUN_RESUME_S = 3.0
#: the same machine as a job's [machine] table (the virtual controller states these
#: limits itself, so a dry run needs no [machine]; tests use it with other controllers)
VIRTUAL_MACHINE = {"max_rate": VIRTUAL_MAX_RATE, "acceleration": VIRTUAL_ACCEL, "junction_deviation": 0.01}


def add_arguments(parser) -> None:
    parser.add_argument("job", nargs="?", help="job file (TOML); default: the bundled example, or with --program "
                                               "the job the flags give")
    parser.add_argument("--speed", type=float, default=5.0,
                        help="simulated seconds per wall second (default 5)")
    parser.add_argument("--clock", choices=("wall", "sim"), default="wall",
                        help="wall: the machine runs by the wall clock (default); sim: it moves speed/poll_hz "
                             "seconds per poll, the same run however busy the computer is")
    add_common_arguments(parser)


def example_base(args):
    """The bundled example when the flags name no program (``dexmon dry-run`` alone, maybe
    with ``--speed`` or ``--view``), else None: a job given by flags is that job, with
    nothing of the example's (its tool table would make tool 1 a flat end mill whatever
    ``--tool`` says, its fixture and tolerances would judge a part they are not for)."""
    return None if getattr(args, "program", None) else EXAMPLE_JOB


def virtual_controller(moves, speed: float, rate: float, clock: str = "wall"):
    from drivers.virtual.controller import VirtualController
    from drivers.virtual.machine_config import MachineConfig

    # A B C as brisk as its fastest linear axis (deg/min, deg/s^2): what the timing takes
    # for rotaries the controller does not state (sim.gcode.timing.six_axes)
    config = MachineConfig(max_rate=VIRTUAL_MAX_RATE + (max(VIRTUAL_MAX_RATE),) * 3,
                           accel=VIRTUAL_ACCEL + (max(VIRTUAL_ACCEL),) * 3, soft_limits=False)
    return VirtualController(moves, speed=speed, rate=rate, clock=clock, config=config)


def virtual_moves(job, moves):
    """The table the virtual machine runs: ``moves`` (the interpreter's machine coordinates:
    work + the .var offsets) as they are when the job has a .var file or takes its work
    offset from the controller; else moved so that the machine's job work system sits at
    the job's ``work_offset``, as the job says the real machine is set up."""
    import numpy as np

    from monitor.work_coords import reference_wco

    if job.work_offset is None or job.var_file is not None:
        return moves
    shift = np.asarray(job.work_offset, np.float64) - reference_wco(job)[:3]
    out = moves.copy()
    for column in ("start", "end", "wco"):
        out[column][:, :3] += shift
    out["center"] += shift
    return out


def run(args) -> int:
    from monitor.options import number
    from monitor.program_moves import load_moves

    number(args.speed, "--speed")  # inf would run the whole program between two polls
    job = job_from_args(args, args.job or example_base(args))
    require(job, "program", "stock", "tools")
    moves, _ = load_moves(job)
    controller = virtual_controller(virtual_moves(job, moves), args.speed, job.poll_hz,
                                    clock=getattr(args, "clock", "wall"))
    return run_session(args, job, controller, done=lambda: controller.done, resume_after=DRY_RUN_RESUME_S,
                       web_waits=True)
