"""``dexmon view RUN``: a recorded run in the browser.

    dexmon view RUN [--address HOST:PORT] [--json]

Serves a local page (127.0.0.1 and a free port unless ``--address`` says otherwise; any
other address is warned about, the page has no password): an interactive 3-D view of the
model at any stage with a timeline to scrub and play, the program listing with the
current line highlighted (click a line to go there) and the findings (click to jump to
the stage where each happened). Its address is printed (JSON: ``{"event": "web", "url":
...}``); Ctrl-C stops it. Exit 0, or 2 for a run file that cannot be read.
"""

from __future__ import annotations

import threading

HELP = "show a recorded run in the browser (3-D view, timeline, listing, findings)"


def add_arguments(parser) -> None:
    parser.add_argument("run", help="run file written by live or dry-run")
    parser.add_argument("--address", default=None, metavar="HOST:PORT",
                        help="where the page listens (default 127.0.0.1 and a free port; "
                             "another host is reachable by others and is warned about)")
    parser.add_argument("--json", action="store_true", help="print the page's address as a JSON line")


def open_run_page(run_path, host: str, port: int):
    """``(WebApp, RunView)`` serving the run file ``run_path`` (close both when done)."""
    import numpy as np

    from monitor.trace_io import RunView
    from monitor.web.app import start_app
    from monitor.web.runmodel import RunModel
    from monitor.web.scene import Scene

    view = RunView(run_path)
    try:
        model = RunModel(view)
        shown = [f for f in model.findings if f["position"] is not None]
        scene = Scene(model.frame, model.heights(model.first).copy(), moves=model.moves, tool=model.tool(),
                      findings=np.asarray([f["position"] for f in shown], np.float64).reshape(-1, 3),
                      finding_labels=[f["label"] for f in shown])
        app = start_app(f"dexmon {view.path.name}", scene, host, port, model=model)
    except BaseException:
        view.close()
        raise
    return app, view


def run(args) -> int:
    from monitor.commands.replay import say_damage
    from monitor.web.address import parse_address
    from monitor.web.app import announce

    host, port = parse_address(args.address, "--address")
    app, view = open_run_page(args.run, host, port)
    try:
        say_damage("view", view)
        announce(app, host, args.json)
        try:
            threading.Event().wait()  # until Ctrl-C
        except KeyboardInterrupt:
            pass
    finally:
        app.close()
        view.close()
    return 0

