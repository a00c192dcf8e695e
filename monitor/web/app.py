"""Start the browser view: a trame server with one :class:`Page` on one :class:`Scene`,
listening where asked, and say where (and warn when others can reach it)."""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass

from monitor.web.address import exposure_warning, url


@dataclass
class WebApp:
    """A page being served: ``server`` (WebServer), ``page`` (Page), ``url`` (str)."""

    server: object
    page: object
    url: str

    def close(self) -> None:
        """Stop serving (the server's thread ends), then free the scene; twice is once."""
        self.server.close()
        if self.page.scene is not None:
            self.page.scene.close()
            self.page.scene = None


def start_app(title: str, scene, host: str, port: int, model=None, program_lines=None,
              where: str = "--address") -> WebApp:
    """Build the page on ``scene`` (and ``model``'s run) and serve it on ``host``:``port``
    (``where``: the option that named it, for errors)."""
    from trame.app import get_server

    from monitor.web.page import Page
    from monitor.web.server import WebServer

    trame_server = get_server("dexmon", client_type="vue3")
    page = Page(trame_server, scene, title, model=model, program_lines=program_lines)
    web = WebServer(trame_server, host, port, where).start()
    return WebApp(web, page, url(host, web.port))


def announce(app: WebApp, host: str, as_json: bool, console=None) -> None:
    """Say the page's address (a JSON line ``{"event": "web", "url": ...}`` or a line of
    text) and, on stderr, the warning when other computers can reach it."""
    warning = exposure_warning(host, app.server.port)
    if warning:
        print(f"dexmon: warning: {warning}", file=sys.stderr, flush=True)
    if as_json:
        sys.stdout.write(json.dumps({"event": "web", "url": app.url, "host": host, "port": app.server.port}) + "\n")
        sys.stdout.flush()
    elif console is not None:
        console.print(f"browser view: {app.url}", soft_wrap=True, highlight=False)
    else:
        print(f"browser view: {app.url}", flush=True)
