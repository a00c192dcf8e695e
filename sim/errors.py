"""Errors of the simulation layer."""

from __future__ import annotations


class SimError(Exception):
    """Base class for errors a user should see as one clear line (no traceback)."""


class InputError(SimError):
    """Bad input: a file, spec or value that is not what was expected.

    ``where`` names the place (``file:line:column`` or an option name); the message
    says what was expected.
    """

    def __init__(self, message: str, where: str | None = None):
        self.where = where
        super().__init__(f"{where}: {message}" if where else message)
