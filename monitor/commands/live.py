"""``dexmon live JOB``: monitor a running machine.

    dexmon live JOB.toml [--controller URL] [--run FILE] [--quiet | --json] [job flags]

Polls the job's controller, follows the program, cuts the real path into the stock,
predicts findings over the look-ahead horizon and alerts each once (terminal, JSON lines,
bell, and feed hold only when the job enables it). Everything goes to a run file (by
default a new one under ./runs/, whose path is printed first). Exit 0 clean, 1 findings,
2 error.
"""

from __future__ import annotations

import gc
import json
import sys
from pathlib import Path

from monitor.job import Job, add_job_arguments, job_from_args, require

HELP = "monitor a running machine from a job file"

#: GIL switch interval during a run, s (Python's default is 0.005)
REALTIME_SWITCH_S = 0.0005


def add_common_arguments(parser) -> None:
    """Output and run-file flags shared by ``live`` and ``dry-run``."""
    parser.add_argument("--run", metavar="FILE", help="run file to write (default: a new file under ./runs/)")
    out = parser.add_mutually_exclusive_group()
    out.add_argument("--quiet", action="store_true", help="print nothing; the exit status says it all")
    out.add_argument("--json", action="store_true", help="JSON lines on stdout: start, each finding, summary")
    add_job_arguments(parser)


def add_arguments(parser) -> None:
    parser.add_argument("job", help="job file (TOML)")
    add_common_arguments(parser)


def run_session(args, job: Job, controller, done=None, default_run_dir: str | Path = "runs") -> int:
    """Open the run file, connect, follow ``controller`` to the end; return the exit status."""
    from rich.console import Console

    from monitor.alerts import Alerter
    from monitor.runfile import RunWriter, default_run_path
    from monitor.session import Session, load_moves, run_controller
    from monitor.status import StatusLine

    moves, program = load_moves(job)
    run_path = Path(args.run) if getattr(args, "run", None) else default_run_path(default_run_dir)
    quiet, as_json = bool(getattr(args, "quiet", False)), bool(getattr(args, "json", False))
    console = None if quiet or as_json else Console(highlight=False)
    err_console = Console(stderr=True, highlight=False)
    writer = RunWriter(run_path)
    try:
        if as_json:
            _jsonl({"event": "start", "run": str(run_path), "program": str(job.program),
                    "controller": getattr(controller, "url", "")})
        elif not quiet:
            console.print(f"run file: {run_path}")
        alerter = Alerter(console=console, json_stream=sys.stdout if as_json else None,
                          bell=("bell" in job.alerts) and console is not None,
                          feed_hold=controller.feed_hold if job.feed_hold else None, run=writer)
        program_text = job.program.read_text(errors="replace") if job.program else ""
        session = Session(job, moves, run=writer, alerter=alerter, program_text=program_text, program=program)
        status = StatusLine(console, enabled=console is not None)
        # compile before connecting (a dry run's machine starts at connect); on a first run
        # numba compiles for up to a minute, so say what is going on
        if console is not None:
            with console.status("preparing: compiling the simulation kernels (slow only the first time)"):
                session.warm_up()
        else:
            session.warm_up()
        controller.connect()
        # the setup made many long-lived objects (move table rows, meshes, tools): keep
        # the collector from walking them again during the run (no gen-2 pauses per poll)
        gc.collect()
        gc.freeze()
        # the run-file writer and driver threads share the GIL with the loop: hand it back
        # within REALTIME_SWITCH_S, not the default 5 ms, so a poll never waits that long
        switch = sys.getswitchinterval()
        sys.setswitchinterval(REALTIME_SWITCH_S)
        try:
            with status:
                run_controller(session, controller, 1.0 / job.poll_hz, status=status, done=done)
        except KeyboardInterrupt:
            err_console.print("interrupted; the run file keeps everything so far")
        finally:
            sys.setswitchinterval(switch)
            gc.unfreeze()
            controller.close()
        summary = session.finish()
        summary["run"] = str(run_path)
    finally:
        writer.close()
    if as_json:
        _jsonl(summary)
    elif not quiet:
        n = summary["findings"]
        colour = "bold red" if n else "green"
        console.print(f"[{colour}]{n} finding(s)[/{colour}]"
                      + (f": {', '.join(summary['kinds'])}" if n else "") + f"; run file {run_path}")
    return 1 if summary["findings"] else 0


def _jsonl(obj) -> None:
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def run(args) -> int:
    from drivers.registry import open_controller

    job = job_from_args(args, args.job)
    require(job, "program", "stock", "controller", "tools")
    controller = open_controller(job.controller)
    return run_session(args, job, controller)
