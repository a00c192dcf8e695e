"""Errors a driver raises. Each message says where (port, line, register) and what was expected."""


class DriverError(Exception):
    """Base class for driver failures a user should see as one clear line."""


class ProtocolError(DriverError):
    """The controller sent bytes that do not parse as its protocol.

    ``raw`` keeps the offending bytes/text for the run log.
    """

    def __init__(self, message: str, raw: str | bytes | None = None):
        super().__init__(message)
        self.raw = raw


class ConnectionLost(DriverError):
    """The port or socket went away (cable pulled, server stopped)."""
