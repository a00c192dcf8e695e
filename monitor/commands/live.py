"""``dexmon live JOB``: monitor a running machine.

    dexmon live JOB.toml [--controller URL] [--run FILE] [--quiet | --json]
                         [--give-up SECONDS] [--view | --frames DIR] [job flags]

Polls the job's controller, follows the program, cuts the real path into the stock,
predicts findings over the look-ahead horizon and alerts each once (terminal, JSON lines,
bell, and feed hold only when the job enables it). Everything goes to a run file (by
default a new one under ./runs/, whose path is printed first). The run ends when the
machine stands idle at the end of the program's last motion (or in alarm). Exit 0 clean,
1 findings, 2 error; interrupted (Ctrl-C, SIGTERM, SIGHUP: the run ends cleanly, its summary
says ``ended: interrupted``) 128 + the signal's number: 130, 143, 129.

Link trouble is said as it happens, one line each (JSON: ``{"event": "link", "kind":
"lost"|"back"|"reset"|"bad"|"note", "message": ...}``), and each gap once it is over
(``{"event": "gap", ...}``: when lost, when back, how long, polls missed, lines lost,
position jump, where the monitor found the machine again). While no fresh state comes the
status line says so and every few seconds a line (``{"event": "lost", "seconds": ...}``)
says "controller lost for 30 s, retrying"; after ``--give-up SECONDS`` (job ``[controller]
give_up_s``, default 600) the run ends with exit 2, one line saying why, the summary and
the run file closed. The summary counts missed, bad and disconnected polls and lists the
gaps.

A feed hold is said at once (``{"event": "feed_hold", ...}``: the finding, its line, how to
go on) and so is the machine leaving it (``{"event": "resumed"}``); dexmon follows the
machine on to the program's end. A monitor that cannot keep up says "monitor falling
behind: ..." (``{"event": "behind"}``) at most every few seconds. With the output piped, a
progress line every few seconds takes the status line's place.

``--view`` opens a window that redraws the shaded model as the machine cuts, with the
overlay of the replay pictures (axes and work origin, the tool and holder, the path near
the machine with feeds solid and rapids dashed, the findings labelled, the stage, line
and time in the strip below with a scale bar); ``--frames DIR`` writes the same frames as
numbered PNG files (no display needed). Either is drawn by a thread of its own, at most
``--view-fps`` frames a second, from the rays each state changed.

``--web [HOST:PORT]`` serves a browser page (127.0.0.1 and a free port by default, printed;
JSON: ``{"event": "web", "url": ...}``): the 3-D model as it is cut, the machine's state,
position and line, the next predicted finding with its countdown, the program listing and
the findings; after the run the page shows the run file's timeline (as ``dexmon view``)
until Ctrl-C. Another host than this computer's loopback is warned about.

With a passthrough URL (``grbl+passthrough:///dev/ttyUSB0``) dexmon opens the machine's
port and prints the pseudo-terminal (and TCP port) to point your own G-code sender at;
the lines the sender streams tell the monitor where in the program the machine is.

The run follows the stock on one Z grid (the start record's ``stock_model``); a job that
asks for another (``[stock] model = "tri-dexel"``, used by ``simulate``) is told so at the
start (JSON: ``{"event": "note", "kind": "stock_model", "text": ...}``).
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
#: live view frame rate cap, frames/s
DEFAULT_VIEW_FPS = 15.0
#: how long the main thread waits for a frame before letting the window handle events, s
WINDOW_PUMP_S = 0.05


def add_common_arguments(parser) -> None:
    """Output and run-file flags shared by ``live`` and ``dry-run``."""
    parser.add_argument("--run", metavar="FILE", help="run file to write (default: a new file under ./runs/)")
    out = parser.add_mutually_exclusive_group()
    out.add_argument("--quiet", action="store_true", help="print nothing; the exit status says it all")
    out.add_argument("--json", action="store_true", help="JSON lines on stdout: start, each finding, summary")
    view = parser.add_mutually_exclusive_group()
    view.add_argument("--view", action="store_true",
                      help="a window redrawing the shaded model, tool, path near the machine and findings as it cuts")
    view.add_argument("--frames", metavar="DIR", help="write the live view's frames as PNG files into DIR")
    view.add_argument("--web", nargs="?", const="", default=None, metavar="HOST:PORT",
                      help="serve a browser view of the run (default 127.0.0.1 and a free port; another "
                           "host is reachable by others and is warned about); it stays up after the run "
                           "until Ctrl-C")
    parser.add_argument("--view-fps", type=float, default=DEFAULT_VIEW_FPS, metavar="N",
                        help=f"frames per second at most for --view/--frames (default {DEFAULT_VIEW_FPS:g})")
    parser.add_argument("--propose", metavar="FILE", default=None,
                        help="for each predicted gouge, append the corrected lines dexmon correct would write "
                             "to FILE (a proposal for you; nothing is sent to the machine)")
    add_job_arguments(parser)


def add_arguments(parser) -> None:
    parser.add_argument("job", help="job file (TOML)")
    add_common_arguments(parser)


def _proposer(args, job: Job):
    """The ``--propose FILE`` hook (:mod:`monitor.propose`), None without it."""
    if not getattr(args, "propose", None):
        return None
    from monitor.propose import Proposer

    return Proposer(job, args.propose)


def run_session(args, job: Job, controller, done=None, default_run_dir: str | Path = "runs",
                resume_after: float | None = None, web_waits: bool = False) -> int:
    """Open the run file, connect, follow ``controller`` to the end; return the exit status.
    ``resume_after`` (s, dry runs): dexmon resumes the machine that long after its feed hold.
    ``web_waits`` (dry runs): with ``--web`` the machine starts when a page has opened.
    SIGTERM and SIGHUP end the run as Ctrl-C does (:mod:`monitor.interrupt`)."""
    from monitor.interrupt import interrupt_on_signals

    with interrupt_on_signals():
        return _run_session(args, job, controller, done, default_run_dir, resume_after, web_waits)


def _run_session(args, job: Job, controller, done, default_run_dir, resume_after, web_waits) -> int:
    from rich.console import Console

    from monitor.interrupt import exit_status, signal_name

    from monitor.alerts import RESUME_HOW, Alerter
    from monitor.runfile import RunWriter, default_run_path
    from monitor.program_moves import load_moves
    from monitor.session import Session
    from monitor.status import StatusLine

    view_opts = _view_options(args)  # before anything is opened: a bad --view is one line
    moves, program = load_moves(job)
    run_path = Path(args.run) if getattr(args, "run", None) else default_run_path(default_run_dir)
    quiet, as_json = bool(getattr(args, "quiet", False)), bool(getattr(args, "json", False))
    console = None if quiet or as_json else Console(highlight=False)
    err_console = Console(stderr=True, highlight=False)
    writer = RunWriter(run_path)
    feed = None
    web = None
    connected = False
    serving = False  # a passthrough stays open for the user's sender after the summary
    try:
        alerter = Alerter(console=console, json_stream=sys.stdout if as_json else None,
                          bell=("bell" in job.alerts) and console is not None,
                          feed_hold=controller.feed_hold if job.feed_hold else None, run=writer,
                          resume_how=RESUME_HOW if resume_after is None else
                          f"dry run: dexmon resumes the virtual machine in {resume_after:g} s "
                          f"(a real machine waits: {RESUME_HOW})",
                          propose=_proposer(args, job))
        program_text = job.program.read_text(errors="replace") if job.program else ""
        session = Session(job, moves, run=writer, alerter=alerter, program_text=program_text, program=program,
                          controller_limits=_machine_limits(controller))
        if hasattr(controller, "learned_lines"):
            from monitor.linesync import StreamedLines

            session.line_source = StreamedLines(controller, program_text, session.moves)
            if done is None:
                done = session.line_source.finished
        if view_opts is not None:
            feed = _start_view(session, *view_opts)
        if getattr(args, "web", None) is not None:
            web = _start_web(args.web, session, program_text, as_json, console, web_waits)
        status = StatusLine(console, enabled=console is not None)
        # compile before connecting (a dry run's machine starts at connect); on a first run
        # numba compiles for up to a minute, so say what is going on
        if console is not None:
            with console.status("preparing: compiling the simulation kernels (slow only the first time)"):
                session.warm_up()
        else:
            session.warm_up()
        _connect(controller)
        connected = True
        # from here on an interrupt (Ctrl-C, SIGTERM, SIGHUP) ends the run cleanly: the
        # machine's link closed, the summary said, the run file closed
        switch = sys.getswitchinterval()
        interrupted = None
        try:
            say_limits = _take_limits(session, controller, console, as_json)
            note = _stock_model_note(job)
            if as_json:
                _jsonl({"event": "start", "run": str(run_path), "program": str(job.program),
                        "controller": getattr(controller, "url", ""), "machine": _limits_record(session.in_force),
                        "stock_model": LIVE_STOCK_MODEL})
                if note is not None:
                    _jsonl({"event": "note", "kind": "stock_model", "text": note})
            elif not quiet:
                console.print(f"run file: {run_path}", soft_wrap=True)
                if note is not None:
                    console.print(f"[yellow]note:[/yellow] {_escape(note)}", soft_wrap=True)
            say_limits(session.in_force)
            _announce_endpoints(controller, console, as_json)
            # a setup that cannot be meant is said before the machine's first move is judged
            session.check_setup(inch=bool(getattr(program, "inch", False)),
                                reports_wco=getattr(controller, "reports_wco", True))
            # the setup made many long-lived objects (move table rows, meshes, tools): keep
            # the collector from walking them again during the run (no gen-2 pauses per poll)
            gc.collect()
            gc.freeze()
            # the run-file writer and driver threads share the GIL with the loop: hand it back
            # within REALTIME_SWITCH_S, not the default 5 ms, so a poll never waits that long
            sys.setswitchinterval(REALTIME_SWITCH_S)
            notify = _notifier(console, as_json, writer)
            with status:
                _follow(session, controller, 1.0 / job.poll_hz, status, done, feed, notify, job.give_up_s,
                        resume_after)
        except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM / SIGHUP (monitor.interrupt)
            session.end_reason = "interrupted"
            interrupted = exc
            _say_interrupted(err_console, exc)
        finally:
            sys.setswitchinterval(switch)
            gc.unfreeze()
            # a passthrough serves the user's sender on after the summary, unless the run
            # was interrupted or the machine is gone
            serving = (session.end_reason != "interrupted" and not session.end_reason.startswith("gave up")
                       and hasattr(controller, "wait_sender_closed"))
            if not serving:
                controller.close()
            if feed is not None:
                feed.close()
        gave_up = session.end_reason.startswith("gave up")
        summary = session.finish()
        summary["run"] = str(run_path)
        summary["ended"] = session.end_reason
        if interrupted is not None:
            summary["signal"] = signal_name(interrupted)
        if gave_up:  # one line, never wrapped
            print(f"dexmon live: {session.end_reason}", file=sys.stderr, flush=True)
        if feed is not None:
            summary["frames"] = feed.frames
            if feed.error is not None:
                err_console.print(f"live view stopped: {type(feed.error).__name__}: {feed.error}")
    except BaseException:
        if serving:
            controller.close()
        if web is not None:
            web.close()
        raise
    finally:
        writer.close()
        if feed is not None:
            feed.view.close()
        if not connected:  # nothing was followed: leave no empty run file behind
            _remove_run_file(run_path)
    if as_json:
        _jsonl(summary)
    elif not quiet:
        _print_summary(console, summary, run_path)
    if web is not None:
        _serve_web_on(web, run_path, summary, console or err_console)
    if serving:
        _serve_sender(controller, console or err_console)
    if gave_up:
        return 2
    if interrupted is not None:
        # not 0 (clean) nor 1 (findings): the job was not followed to its end, whatever it found
        return exit_status(interrupted)
    return 1 if summary["findings"] else 0


def _say_interrupted(err_console, exc: BaseException) -> None:
    """The one line an interrupted run says (the signal named unless it was Ctrl-C)."""
    from monitor.interrupt import signal_name

    name = signal_name(exc)
    try:
        err_console.print(f"interrupted{'' if name == 'SIGINT' else f' ({name})'}; "
                          "the run file keeps everything so far")
    except OSError:  # SIGHUP: the terminal may be gone; the summary and the run file matter more
        pass


def _machine_limits(controller):
    """``controller.machine_limits()``, or None when it cannot say (yet)."""
    ask = getattr(controller, "machine_limits", None)
    try:
        return ask() if ask is not None else None
    except Exception:  # noqa: BLE001 - unknown limits: the job's and the defaults hold
        return None


def _limits_record(force) -> dict:
    """The limits in force as JSON: the figures, ``sources`` and a ``message``."""
    return {"message": force.describe(), **force.to_json()}


#: the stock model a live run and a dry run follow (the session's cut, look-ahead and
#: checks are built on one grid of vertical rays)
LIVE_STOCK_MODEL = "z"


def _stock_model_note(job) -> str | None:
    """What to tell a user whose job asks for another stock model than the live one."""
    if job.stock_model == LIVE_STOCK_MODEL:
        return None
    return (f'the job\'s [stock] model = "{job.stock_model}" is used by dexmon simulate only: this run '
            f"follows the stock on one Z grid (vertical rays {job.resolution:g} mm apart), as every live run "
            f"does, where a wall thinner than that or one a tilted tool leaves may fall between the rays; "
            f"dexmon simulate checks the job on the tri-dexel model")


def _take_limits(session, controller, console, as_json: bool):
    """After connect: time the program with the limits the controller stated (GRBL read
    ``$$`` if the machine was Idle); when it has not said them yet, let the session ask
    at every step until it has (GRBL attached to a busy machine reads ``$$`` at its next
    Idle) and say them when they arrive (JSON: ``{"event": "machine", ...}``). Returns
    what says limits in force on the terminal (the start record carries them in JSON)."""

    def say_later(force) -> None:
        if as_json:
            _jsonl({"event": "machine", **_limits_record(force)})
        else:
            say(force)

    def say(force) -> None:
        if console is not None:
            console.print(_escape(force.describe()), soft_wrap=True)

    limits = _machine_limits(controller)
    session.use_controller_limits(limits)
    if limits is None:
        session.limits_from = controller.machine_limits
        session.on_limits = say_later
    return say


def _print_summary(console, summary: dict, run_path) -> None:
    """The run's summary on the terminal: findings, then the link's trouble if any."""
    n = summary["findings"]
    colour = "bold red" if n else "green"
    console.print(f"[{colour}]{n} finding(s)[/{colour}]"
                  + (f": {', '.join(summary['kinds'])}" if n else "") + f"; run file {run_path}")
    missed = {k: summary.get(k, 0) for k in ("missed", "bad", "disconnected")}
    if any(missed.values()) or summary.get("gaps"):
        console.print("[yellow]link: " + ", ".join(f"{v} {k} poll(s)" for k, v in missed.items())
                      + f", {len(summary.get('gaps', []))} gap(s)[/yellow]", soft_wrap=True)
    for gap in summary.get("gaps", []):
        console.print(f"[yellow]  {_escape(gap['message'])}[/yellow]", soft_wrap=True)


def _escape(text: str) -> str:
    from rich.markup import escape

    return escape(str(text))


def _notifier(console, as_json: bool, writer):
    """What the loop calls with each link event, gap record, "controller lost" and "monitor
    falling behind" notice: one line on the terminal or one JSON line; the lost notices
    also go to the run file (the session records the events and gaps itself, the loop the
    falling-behind notices)."""
    from monitor.jsonable import json_default

    def notify(rec: dict) -> None:
        if rec.get("event") == "lost":
            writer.append_link_event(rec.get("t"), "lost", rec)
        if as_json:
            sys.stdout.write(json.dumps(rec, default=json_default) + "\n")
            sys.stdout.flush()
        elif console is not None:
            style = "bold red" if rec.get("kind") in ("lost", "reset") or rec.get("event") == "lost" else "yellow"
            label = {"gap": "gap: ", "behind": ""}.get(rec.get("event"), "link: ")  # "monitor falling behind: ..."
            console.print(f"[{style}]{label}{_escape(rec.get('message', ''))}[/{style}]", soft_wrap=True)
    return notify


def _serve_sender(controller, console) -> None:
    """The monitor is done, the user's sender may not be: a passthrough keeps answering it
    until it disconnects (or Ctrl-C), then closes."""
    try:
        console.print("passthrough stays open for your sender until it disconnects; Ctrl-C to stop")
        controller.wait_sender_closed()
    except KeyboardInterrupt:
        pass
    finally:
        controller.close()


def _connect(controller) -> None:
    """``controller.connect()``; a failure says the operating system's reason when the
    driver's message lacks it (found in the exception chain)."""
    from drivers.errors import DriverError

    try:
        controller.connect()
    except DriverError as exc:
        why = os_reason(exc, controller)
        if why and why.lower() not in str(exc).lower():
            raise type(exc)(f"{exc}: {why}") from exc
        raise


def os_reason(exc: BaseException, controller=None) -> str | None:
    """The OS error behind a failed connect: the first ``OSError`` in ``exc``'s chain
    (``__cause__``/``__context__``); None when nothing is known (drivers that cannot
    chain it put the reason in their own message)."""
    seen = set()
    e = exc
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, OSError) and e is not exc:
            return e.strerror or str(e)
        e = e.__cause__ or e.__context__
    return None


def _remove_run_file(path: Path) -> None:
    for p in (path, path.with_name(path.name + "-wal"), path.with_name(path.name + "-shm"),
              path.with_name(path.name + "-journal")):
        try:
            p.unlink()
        except OSError:
            pass


def _view_options(args):
    """``(frames dir or None, fps)`` when ``--view``/``--frames`` was given, else None;
    InputError when ``--view`` has no display."""
    from sim.errors import InputError

    want_window, frames = bool(getattr(args, "view", False)), getattr(args, "frames", None)
    if not want_window and not frames:
        return None
    from monitor.options import number

    fps = number(getattr(args, "view_fps", DEFAULT_VIEW_FPS), "--view-fps")
    if want_window:
        from monitor.render.view3d import has_display

        if not has_display():
            raise InputError("no display for a window ($DISPLAY is not set); use --frames DIR to write "
                             "the frames as PNG files instead", "--view")
    return frames, float(fps)


def _start_view(session, frames, fps: float):
    """A LiveView of the session's live model fed from its own thread (kernels compiled
    here, before the machine is followed)."""
    from monitor.render.feed import ViewFeed
    from monitor.render.live import LiveView

    wp = session.wp
    tool = wp.tool(int(session.moves["tool"][0])) if len(session.moves) else wp.default_tool
    # the overlay of the replay pictures: axes and work origin, the path near the machine
    view = LiveView(wp.frame, tool=tool, out_dir=frames, title=f"dexmon {session.job.program or ''}",
                    fixtures=wp.fixtures, axes=True)
    heights = session.live.top()
    view.render(heights, session.path.point_at(0.0) if len(session.path) else None)  # compile the shading
    feed = ViewFeed(view, heights, path=session.path, horizon=session.lookahead.horizon_end, fps=fps,
                    moves=session.moves)
    session.attach_view(feed)
    return feed.start()


def _start_web(address, session, program_text: str, as_json: bool, console, wait: bool):
    """The browser view of the session (:mod:`monitor.web.live`); with ``wait`` the
    machine starts only when a page has opened (a dry run is there to be watched)."""
    from monitor.web.live import start_live_page

    web = start_live_page(address, session, program_text, as_json, console)
    if wait:
        if not as_json:
            print("waiting for the browser view to open before starting the dry run (Ctrl-C to stop)",
                  file=sys.stderr, flush=True)
        try:
            while not web.app.page.opened.wait(0.5):
                pass
        except KeyboardInterrupt:
            web.close()
            raise
    return web


def _serve_web_on(web, run_path, summary: dict, console) -> None:
    """After the run: the page shows the run file's timeline until Ctrl-C."""
    try:
        web.finished(run_path, summary)
        console.print(f"browser view stays open at {web.app.url} on the run file; Ctrl-C to stop", soft_wrap=True)
        _wait_for_ctrl_c()
    except KeyboardInterrupt:
        pass
    finally:
        web.close()


def _wait_for_ctrl_c() -> None:
    import threading

    threading.Event().wait()


def _announce_endpoints(controller, console, as_json: bool) -> None:
    """Tell the user where to point their own G-code sender (passthrough controllers)."""
    ends = getattr(controller, "sender_endpoints", None)
    if not ends:
        return
    if as_json:
        _jsonl({"event": "passthrough", **ends})
    elif console is not None:
        where = []
        if ends.get("pty"):
            where.append(f"serial port {ends['pty']}")
        if ends.get("tcp"):
            where.append(f"TCP {ends.get('host', '127.0.0.1')}:{ends['tcp']}")
        console.print(f"[bold]point your G-code sender at {' or '.join(where)}[/bold] "
                      f"(the machine is on {ends.get('machine', '?')})")


def _follow(session, controller, period: float, status, done, feed, notify=None, give_up_s=None,
            resume_after=None) -> None:
    """Run the loop; with a window the loop runs on a worker thread, since the window
    belongs to the main thread (GUI toolkits are not thread-safe)."""
    import threading

    from monitor.loop import run_controller

    kw = {"status": status, "done": done, "notify": notify, "give_up_s": give_up_s, "resume_after": resume_after}
    if feed is None or not feed.view.is_window:
        from monitor.interrupt import deferred_interrupts

        # an interrupt stops the loop between two states (then raised here), never inside a
        # step: a finding alerted is counted, a stage cut is recorded
        with deferred_interrupts() as interrupt:
            run_controller(session, controller, period, stop=interrupt.event, **kw)
        return
    stop = threading.Event()
    failed: list[BaseException] = []

    def loop():
        try:
            run_controller(session, controller, period, stop=stop, **kw)
        except BaseException as exc:  # noqa: BLE001 - re-raised on the main thread
            failed.append(exc)

    # the window's thread takes the interrupt; the loop's thread ends between two states
    worker = threading.Thread(target=loop, name="dexmon session", daemon=True)
    worker.start()
    try:
        while worker.is_alive():
            feed.pump(WINDOW_PUMP_S)
    except KeyboardInterrupt:
        stop.set()
        worker.join()
        raise
    worker.join()
    if failed:
        raise failed[0]


def _jsonl(obj) -> None:
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def run(args) -> int:
    from drivers.registry import open_controller

    job = job_from_args(args, args.job)
    require(job, "program", "stock", "controller", "tools")
    controller = open_controller(job.controller)
    controller.preflight()  # a missing device is said now, not after the kernels compiled
    return run_session(args, job, controller)
