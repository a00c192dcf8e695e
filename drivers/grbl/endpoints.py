"""Byte pipes a GRBL sender opens: a raw pseudo-terminal or a TCP socket.

Each endpoint calls ``receive(endpoint, data)`` from its own reader thread for every
chunk the sender writes, and offers ``write(data)`` and ``close()``. Used by the GRBL
peer (the emulator's port) and by the passthrough (the port offered to a sender).

``write`` never blocks its caller (the thread reading the machine must never wait for a
sender): the bytes are queued for the endpoint's own writer thread, in order, each call
kept whole. As a USB serial adapter does, an endpoint

* discards what it is given while no sender has it open (counted in ``unheard``): a
  sender that opens it later gets fresh output, not stale replies;
* holds at most ``max_buffered`` bytes for a sender that reads slower than the machine
  writes, dropping the oldest beyond that (counted in ``dropped``).

``on_event(endpoint, kind, message)``, when given, hears (from the endpoint's threads):
``"present"`` / ``"absent"`` (a sender opened / closed it), ``"dropping"`` (once per
sender connection, when its output starts being dropped) and ``"error"`` (an exception
in ``receive`` or in the endpoint's own I/O; the thread goes on).
"""

from __future__ import annotations

import collections
import logging
import os
import select
import socket
import threading
import time
import tty
from typing import Callable

log = logging.getLogger(__name__)

#: bytes an endpoint holds for a sender that reads slower than the machine writes (about
#: 6 s of GRBL output at 115200 baud); the oldest are dropped beyond this
MAX_BUFFERED = 64 * 1024
#: kernel send buffer of a sender's TCP connection, bytes (Linux doubles it)
SOCKET_SNDBUF = 32 * 1024
#: how often a pty nobody has open is checked for a sender opening it, s
PRESENCE_CHECK_S = 0.02

Receive = Callable[["Endpoint", bytes], None]
OnEvent = Callable[["Endpoint", str, str], None]


class Endpoint:
    """One byte pipe to a sender: a non-blocking, bounded ``write`` (see the module
    docstring); subclasses deliver with ``_deliver`` and say who is there with
    ``_set_present``."""

    def __init__(self, name: str, receive: Receive, on_event: OnEvent | None = None,
                 max_buffered: int = MAX_BUFFERED):
        self.name = name
        self.closed = False
        self.max_buffered = int(max_buffered)
        #: bytes dropped (oldest first) because the connected sender did not read them in time
        self.dropped = 0
        #: bytes discarded because no sender had the endpoint open
        self.unheard = 0
        #: a sender has the endpoint open now (and the event says so to waiters)
        self.sender_present = False
        self._present = threading.Event()
        self._receive = receive
        self._on_event = on_event
        self._out: collections.deque[bytes] = collections.deque()
        self._out_bytes = 0
        self._out_cond = threading.Condition()
        self._dropping = False
        self._writer = threading.Thread(target=self._write_loop, name=f"grbl writer {name}", daemon=True)

    # ------------------------------------------------------------------ output

    def write(self, data: bytes) -> None:
        """Queue ``data`` for the sender; never blocks (see the module docstring)."""
        if self.closed or not data:
            return
        started_dropping = False
        if not self.sender_present and self._opened_meanwhile():
            self._set_present(True)  # before the reader thread's next look: keep these bytes
        with self._out_cond:
            if not self.sender_present:
                self.unheard += len(data)
                return
            self._out.append(bytes(data))
            self._out_bytes += len(data)
            while self._out_bytes > self.max_buffered and len(self._out) > 1:
                old = self._out.popleft()
                self._out_bytes -= len(old)
                self.dropped += len(old)
                if not self._dropping:
                    self._dropping = started_dropping = True
            self._out_cond.notify()
        if started_dropping:
            self._event("dropping", f"{self.name}: the sender does not read its output; the oldest "
                                    f"is dropped beyond {self.max_buffered} bytes held")

    def wait_sender(self, timeout: float) -> bool:
        """Wait until a sender has the endpoint open; True if one has."""
        return self._present.wait(timeout)

    @property
    def buffered(self) -> int:
        """Bytes queued for the sender, not yet handed to the pty or socket."""
        return self._out_bytes

    def _write_loop(self) -> None:
        while True:
            with self._out_cond:
                self._out_cond.wait_for(lambda: self._out or self.closed)
                if self.closed:
                    return
                chunk = self._out.popleft()
                self._out_bytes -= len(chunk)
            try:
                left = self._deliver(chunk)
            except Exception as exc:  # noqa: BLE001 - the writer must outlive any one chunk
                self._event("error", f"{self.name}: writing to the sender failed: {type(exc).__name__}: {exc}")
                left = len(chunk)
            if left:
                with self._out_cond:
                    self.unheard += left

    def _opened_meanwhile(self) -> bool:
        """True when a sender has opened the endpoint since the reader last looked."""
        return False

    def _deliver(self, chunk: bytes) -> int:  # pragma: no cover - overridden
        """Hand ``chunk`` to the sender (may block; returns at close); return the bytes
        not delivered because the sender went away."""
        raise NotImplementedError

    # ------------------------------------------------------------------ events

    def _set_present(self, present: bool) -> None:
        with self._out_cond:
            if present == self.sender_present:
                return
            self.sender_present = present
            (self._present.set if present else self._present.clear)()
            self._dropping = False
            if not present:  # what was queued for the sender that left is nobody's
                self.unheard += self._out_bytes
                self._out.clear()
                self._out_bytes = 0
        self._event("present" if present else "absent",
                    f"{self.name}: a sender {'opened' if present else 'closed'} it")

    def _received(self, data: bytes) -> None:
        """Hand the sender's bytes on; an exception there is reported, never fatal."""
        try:
            self._receive(self, data)
        except Exception as exc:  # noqa: BLE001 - the reader outlives any one chunk
            self._event("error", f"{self.name}: handling {len(data)} bytes from the sender failed: "
                                 f"{type(exc).__name__}: {exc}")

    def _event(self, kind: str, message: str) -> None:
        if self._on_event is None:
            if kind == "error":
                log.error("%s", message)
            return
        try:
            self._on_event(self, kind, message)
        except Exception:  # noqa: BLE001 - a listener's bug must not stop the endpoint
            log.exception("%s: the endpoint's listener failed on %r", self.name, kind)

    def close(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def _stop_writer(self) -> None:
        with self._out_cond:
            self.closed = True
            self._out_cond.notify_all()


class PtyEndpoint(Endpoint):
    """A raw pseudo-terminal; ``path`` is what the sender opens (the slave, or ``link``).

    This side holds only the master, so it sees a sender close the slave (the master
    hangs up) and open it again: ``sender_present`` follows, and the endpoint serves any
    number of opens. ``link`` is a symlink replaced atomically, a stable name across
    close/reopen as udev's ``/dev/serial/by-id`` is.
    """

    def __init__(self, receive: Receive, link: str | None = None, on_event: OnEvent | None = None,
                 max_buffered: int = MAX_BUFFERED):
        master, slave = os.openpty()
        tty.setraw(slave)  # the line discipline keeps raw mode for the sender's opens
        name = os.ttyname(slave)
        os.close(slave)
        os.set_blocking(master, False)
        super().__init__(name, receive, on_event, max_buffered)
        self.master = master
        self.link = link
        if link:
            tmp = f"{link}.{os.getpid()}.tmp"
            if os.path.lexists(tmp):
                os.unlink(tmp)
            os.symlink(self.name, tmp)
            os.replace(tmp, link)  # atomic: a driver reopening the link finds old or new
        self.path = link or self.name
        # a pipe to wake the threads out of poll() on close
        self._wake_r, self._wake_w = os.pipe()
        self.thread = threading.Thread(target=self._run, name=f"grbl pty {self.name}", daemon=True)
        self.thread.start()
        self._writer.start()

    def _master_events(self, mask: int, timeout_ms: int | None) -> tuple[int, bool]:
        """poll() the master for ``mask``: (its events, woken for close)."""
        poller = select.poll()
        poller.register(self.master, mask)
        poller.register(self._wake_r, select.POLLIN)
        events = dict(poller.poll(timeout_ms))
        return events.get(self.master, 0), self._wake_r in events or self.closed

    def _run(self) -> None:
        while not self.closed:
            try:
                if self._serve_once():
                    return
            except Exception as exc:  # noqa: BLE001 - the reader must not die quietly
                self._event("error", f"{self.name}: reading from the sender failed: {type(exc).__name__}: {exc}")
                if self._wait_wake(0.05):
                    return

    def _serve_once(self) -> bool:
        """Wait for the sender's bytes or its coming and going; True once closed."""
        if not self.sender_present:
            ev, woken = self._master_events(select.POLLIN, 0)
            if woken:
                return True
            if ev & select.POLLHUP and not ev & select.POLLIN:
                # nobody has the slave open: a hung-up master polls ready at once, so look
                # again a little later for a sender opening it
                return self._wait_wake(PRESENCE_CHECK_S)
            self._set_present(True)
        ev, woken = self._master_events(select.POLLIN, None)
        if woken:
            return True
        data = b""
        if ev & select.POLLIN:
            try:
                data = os.read(self.master, 4096)
            except BlockingIOError:
                return False
            except OSError:  # EIO: the last holder of the slave closed it
                data = b""
        if data:
            self._received(data)
        elif ev & (select.POLLHUP | select.POLLERR | select.POLLIN):
            self._set_present(False)
        return False

    def _opened_meanwhile(self) -> bool:
        # a master whose slave nobody holds polls as hung up
        ev, _ = self._master_events(select.POLLIN, 0)
        return bool(ev & select.POLLIN) or not ev & select.POLLHUP

    def _wait_wake(self, timeout: float) -> bool:
        """Sleep up to ``timeout`` s unless closed; True if closed."""
        ready, _, _ = select.select([self._wake_r], [], [], timeout)
        return bool(ready) or self.closed

    def _deliver(self, chunk: bytes) -> int:
        view = memoryview(chunk)
        while view:
            if self.closed:
                return len(view)
            try:
                view = view[os.write(self.master, view):]
                continue
            except BlockingIOError:
                pass
            except OSError:
                return len(view)
            # the sender's input is full: wait for room, for it to go, or for close
            ev, woken = self._master_events(select.POLLOUT, 100)
            if woken or ev & (select.POLLHUP | select.POLLERR):
                return len(view)
        return 0

    def close(self) -> None:
        if self.closed:
            return
        self._stop_writer()
        os.write(self._wake_w, b"x")
        self.thread.join(1.0)
        self._writer.join(1.0)
        for fd in (self.master, self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass
        if self.link and os.path.islink(self.link) and os.readlink(self.link) == self.name:
            os.unlink(self.link)


class TcpEndpoint(Endpoint):
    """A listening socket; one client at a time (a serial port has one user: a new
    client replaces the old one)."""

    def __init__(self, receive: Receive, host: str = "127.0.0.1", port: int = 0,
                 on_event: OnEvent | None = None, max_buffered: int = MAX_BUFFERED):
        self.server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.server.bind((host, port))
        self.server.listen(2)
        self.port = self.server.getsockname()[1]
        super().__init__(f"tcp:{host}:{self.port}", receive, on_event, max_buffered)
        self.client: socket.socket | None = None
        self.thread = threading.Thread(target=self._accept, name=f"grbl {self.name}", daemon=True)
        self.thread.start()
        self._writer.start()

    def _accept(self) -> None:
        while not self.closed:
            try:
                conn, _ = self.server.accept()
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                # the kernel's share of what a client has not read is bounded too (it
                # grows to megabytes of stale replies otherwise)
                conn.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SOCKET_SNDBUF)
            except OSError as exc:
                if self.closed:
                    return
                # a client that reset before it was accepted, or out of descriptors
                self._event("error", f"{self.name}: accepting a sender failed: {exc}")
                time.sleep(0.05)  # pacing retries of a failing accept, not synchronisation
                continue
            old, self.client = self.client, conn
            if old is not None:
                self._set_present(False)
                _close_socket(old)
            self._set_present(True)
            threading.Thread(target=self._serve, args=(conn,), name=f"grbl client {self.name}",
                             daemon=True).start()

    def _serve(self, conn: socket.socket) -> None:
        while not self.closed:
            try:
                data = conn.recv(4096)
            except OSError:
                break
            if not data:
                break
            if conn is self.client:
                self._received(data)
        if self.client is conn:
            self.client = None
            self._set_present(False)
        _close_socket(conn)

    def _deliver(self, chunk: bytes) -> int:
        conn = self.client
        if conn is None or self.closed:
            return len(chunk)
        try:
            conn.sendall(chunk)  # blocks while the client does not read: only this thread waits
        except OSError:
            return len(chunk)
        return 0

    def close(self) -> None:
        if self.closed:
            return
        self._stop_writer()
        try:
            self.server.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.server.close()
        if self.client is not None:
            _close_socket(self.client)
        self.thread.join(1.0)
        self._writer.join(1.0)


def _close_socket(conn: socket.socket) -> None:
    try:
        conn.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass
    conn.close()
