"""Exceptions that end any thread during a block of a test: no driver thread may die quietly."""

from __future__ import annotations

import contextlib
import threading


@contextlib.contextmanager
def thread_errors():
    """Collect the ``threading.ExceptHookArgs`` of every thread that dies of an exception
    inside the ``with`` block. Use it inside the test body: pytest installs its own hook
    around each test phase, so one set by a fixture would be replaced before the test runs."""
    errors = []
    old = threading.excepthook
    threading.excepthook = errors.append
    try:
        yield errors
    finally:
        threading.excepthook = old
