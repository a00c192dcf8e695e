"""Byte pipes a GRBL sender opens: a raw pseudo-terminal or a TCP socket.

Each endpoint calls ``receive(endpoint, data)`` from its own thread for every chunk the
sender writes, and offers ``write(data)`` (atomic per call) and ``close()``. Used by the
GRBL peer (the emulator's port) and by the passthrough (the port offered to a sender).
"""

from __future__ import annotations

import os
import select
import socket
import threading
import tty
from typing import Callable


class Endpoint:
    """One byte pipe to a sender; ``write`` is atomic per call."""

    def __init__(self, name: str):
        self.name = name
        self.lock = threading.Lock()
        self.closed = False

    def write(self, data: bytes) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def close(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError


class PtyEndpoint(Endpoint):
    """A raw pseudo-terminal; ``path`` is what the sender opens (the slave, or ``link``).

    The slave stays open on this side too, so a sender closing and reopening the port
    does not end the endpoint; ``link`` is a symlink replaced atomically, a stable name
    across close/reopen as udev's ``/dev/serial/by-id`` is.
    """

    def __init__(self, receive: Callable[["Endpoint", bytes], None], link: str | None = None):
        master, slave = os.openpty()
        tty.setraw(slave)
        super().__init__(os.ttyname(slave))
        self.master, self.slave = master, slave
        self.link = link
        if link:
            tmp = f"{link}.{os.getpid()}.tmp"
            if os.path.lexists(tmp):
                os.unlink(tmp)
            os.symlink(self.name, tmp)
            os.replace(tmp, link)  # atomic: a driver reopening the link finds old or new
        self.path = link or self.name
        self._receive = receive
        # a pipe to wake the reader out of select() on close
        self._wake_r, self._wake_w = os.pipe()
        self.thread = threading.Thread(target=self._run, name=f"grbl pty {self.name}", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.closed:
            try:
                ready, _, _ = select.select([self.master, self._wake_r], [], [])
                if self._wake_r in ready or self.closed:
                    return
                data = os.read(self.master, 4096)
            except OSError:
                return
            if data:
                self._receive(self, data)

    def write(self, data: bytes) -> None:
        if self.closed:
            return
        with self.lock:
            view = memoryview(data)
            while view and not self.closed:
                try:
                    n = os.write(self.master, view)
                except BlockingIOError:
                    select.select([], [self.master], [], 0.1)
                    continue
                except OSError:
                    return
                view = view[n:]

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        os.write(self._wake_w, b"x")
        self.thread.join(1.0)
        for fd in (self.master, self.slave, self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass
        if self.link and os.path.islink(self.link) and os.readlink(self.link) == self.name:
            os.unlink(self.link)


class TcpEndpoint(Endpoint):
    """A listening socket; one client at a time (a serial port has one user)."""

    def __init__(self, receive: Callable[["Endpoint", bytes], None], host: str = "127.0.0.1", port: int = 0):
        self.server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.server.bind((host, port))
        self.server.listen(2)
        self.port = self.server.getsockname()[1]
        super().__init__(f"tcp:{host}:{self.port}")
        self._receive = receive
        self.client: socket.socket | None = None
        self.thread = threading.Thread(target=self._accept, name=f"grbl {self.name}", daemon=True)
        self.thread.start()

    def _accept(self) -> None:
        while not self.closed:
            try:
                conn, _ = self.server.accept()
            except OSError:
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            old, self.client = self.client, conn
            if old is not None:
                _close_socket(old)
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
                self._receive(self, data)
        if self.client is conn:
            self.client = None
        _close_socket(conn)

    def write(self, data: bytes) -> None:
        conn = self.client
        if conn is None or self.closed:
            return
        with self.lock:
            try:
                conn.sendall(data)
            except OSError:
                pass

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self.server.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.server.close()
        if self.client is not None:
            _close_socket(self.client)
        self.thread.join(1.0)


def _close_socket(conn: socket.socket) -> None:
    try:
        conn.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass
    conn.close()
