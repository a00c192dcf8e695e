"""SIGTERM and SIGHUP end a run as Ctrl-C does.

By default they kill the process where it stands: no summary, the run file not closed by
its writer (no row counts, the last trace chunk never written). Under :func:`interrupt_on_signals`
they raise :class:`Interrupted`, a ``KeyboardInterrupt``, so every ``except KeyboardInterrupt``
that ends a run cleanly on Ctrl-C does the same for them, and the exit status says which
signal it was (:func:`exit_status`).
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager

#: the signals that end a run as Ctrl-C does (SIGHUP: the terminal closed; not on Windows)
SIGNALS = tuple(s for s in (getattr(signal, "SIGTERM", None), getattr(signal, "SIGHUP", None)) if s is not None)


class Interrupted(KeyboardInterrupt):
    """Raised on the main thread by :data:`SIGNALS`; ``signum`` is the signal's number."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)


def signal_of(exc: BaseException) -> int:
    """The signal a ``KeyboardInterrupt`` stands for (SIGINT: Ctrl-C)."""
    return getattr(exc, "signum", signal.SIGINT)


def signal_name(exc: BaseException) -> str:
    return signal.Signals(signal_of(exc)).name


def exit_status(exc: BaseException) -> int:
    """The exit status of a run ended by ``exc``: 128 + the signal's number, as a shell
    reports a process the signal ended (130 Ctrl-C, 143 SIGTERM, 129 SIGHUP)."""
    return 128 + signal_of(exc)


def _raise(signum, frame):
    raise Interrupted(signum)


class Deferred:
    """What :func:`deferred_interrupts` hands its body: ``event`` is set by the first
    signal, ``signum`` is that signal's number (None: none came)."""

    def __init__(self):
        self.event = threading.Event()
        self.signum: int | None = None


@contextmanager
def deferred_interrupts():
    """Within: SIGINT and :data:`SIGNALS` set ``event`` of the :class:`Deferred` yielded
    instead of raising, so a loop stopping on it ends between two of its steps, never
    inside one (a finding alerted but not yet counted, a stage cut but not recorded); on
    leaving, :class:`Interrupted` is raised for that signal. A second signal raises at
    once (a loop stuck waiting must still stop). Only on the main thread; a signal the
    process ignores stays ignored."""
    d = Deferred()
    if threading.current_thread() is not threading.main_thread():
        yield d
        return

    def later(signum, frame):
        if d.signum is not None:
            raise Interrupted(signum)
        d.signum = signum
        d.event.set()

    before = {}
    for s in (signal.SIGINT, *SIGNALS):
        if signal.getsignal(s) is not signal.SIG_IGN:
            before[s] = signal.signal(s, later)
    try:
        yield d
    finally:
        for s, handler in before.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)
    if d.signum is not None:
        raise Interrupted(d.signum)


@contextmanager
def interrupt_on_signals():
    """Within: :data:`SIGNALS` raise :class:`Interrupted` on the main thread (elsewhere
    signal handlers cannot be set, and nothing changes). A signal the process was started
    ignoring stays ignored (``nohup dexmon live ...`` goes on when the terminal closes).
    The handlers before are restored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = {}
    for s in SIGNALS:
        if signal.getsignal(s) is not signal.SIG_IGN:
            before[s] = signal.signal(s, _raise)
    try:
        yield
    finally:
        for s, handler in before.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)
