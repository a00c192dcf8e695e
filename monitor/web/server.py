"""The trame server on a thread of its own (its own asyncio loop), started on a chosen
address; port 0 lets the system pick a free port, read back from :attr:`WebServer.port`."""

from __future__ import annotations

import asyncio
import threading

from sim.errors import InputError

#: how long starting may take before it is an error (s): importing and binding only
START_TIMEOUT_S = 60.0


class WebServer:
    """Serve one trame ``server`` (``trame.app.get_server``) on ``host``:``port``.

    Everything the page calls back runs on the server's thread; other threads hand it
    work with :meth:`call_soon`.
    """

    def __init__(self, server, host: str, port: int, where: str = "--address"):
        self.server = server
        self.where = where
        self.host = host
        self.asked_port = int(port)
        self._ready = threading.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._failed: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="dexmon web", daemon=True)
        _ignore_argv(server)
        server.controller.on_server_ready.add(lambda **_: self._ready.set())

    def start(self) -> "WebServer":
        """Start listening; InputError naming the address when it cannot bind."""
        _check_free(self.host, self.asked_port, self.where)
        self._thread.start()
        if not self._ready.wait(START_TIMEOUT_S) or self._failed is not None:
            why = self._failed or f"not listening after {START_TIMEOUT_S:g} s"
            raise InputError(f"cannot serve the browser view on {self.host}:{self.asked_port}: {why}",
                             self.where)
        return self

    @property
    def port(self) -> int:
        return int(self.server.port)

    def _run(self) -> None:
        self._loop = loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        try:
            task = self.server.start(port=self.asked_port, host=self.host, thread=True, exec_mode="task",
                                     open_browser=False, show_connection_info=False, timeout=0,
                                     disable_logging=True)
            task.add_done_callback(self._on_done)
            loop.run_forever()
        except BaseException as exc:  # noqa: BLE001 - said by start()
            self._failed = exc
            self._ready.set()
        finally:
            _cancel_pending(loop)
            loop.close()

    def _on_done(self, task) -> None:
        if not task.cancelled() and task.exception() is not None and not self._ready.is_set():
            self._failed = task.exception()
            self._ready.set()

    def call_soon(self, fn, *args) -> None:
        """Run ``fn(*args)`` on the server's thread."""
        if self._loop is not None and not self._loop.is_closed():
            self._loop.call_soon_threadsafe(fn, *args)

    def close(self) -> None:
        """Stop serving and end the server's thread."""
        loop = self._loop
        if loop is None or loop.is_closed() or not self._thread.is_alive():
            return

        async def stop():
            try:
                await self.server.stop()
            finally:
                loop.stop()
        asyncio.run_coroutine_threadsafe(stop(), loop)
        self._thread.join(10.0)


def _ignore_argv(server) -> None:
    """trame reads its own options from ``sys.argv``; dexmon's are not trame's, so it
    gets none (its address is passed to ``start``)."""
    cli = server.cli
    parse = cli.parse_known_args
    cli.parse_known_args = lambda args=None, namespace=None: parse([], namespace)


def _check_free(host: str, port: int, where: str) -> None:
    """InputError (one line) when ``host``:``port`` cannot be listened on, said before
    the server tries (its own failure comes with a traceback in its log)."""
    import socket

    if port == 0:
        return
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except OSError as exc:
        raise InputError(f"cannot serve the browser view on {host}:{port}: {exc.strerror or exc}", where) from None
    family, kind, proto, _, address = infos[0]
    with socket.socket(family, kind, proto) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(address)
        except OSError as exc:
            raise InputError(f"cannot serve the browser view on {host}:{port}: {exc.strerror or exc}",
                             where) from None


def _cancel_pending(loop: asyncio.AbstractEventLoop) -> None:
    """Cancel what is still scheduled on the stopped ``loop`` and let it finish, so that
    closing it leaves no task pending (trame's server task, a playback)."""
    pending = [t for t in asyncio.all_tasks(loop) if not t.done()]
    for t in pending:
        t.cancel()
    if pending:
        loop.run_until_complete(asyncio.gather(*pending, return_exceptions=True))
