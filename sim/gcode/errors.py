"""The one error type of the G-code interpreter."""

from __future__ import annotations

from sim.errors import InputError


class GCodeError(InputError):
    """A G-code program (or one streamed line) that the controller would refuse.

    ``str()`` is ``file:line:col: message`` followed by the source line and a caret
    under the column, so a user sees at once what is wrong and where. ``grbl_code`` is
    GRBL 1.1's ``error:N`` number when the grbl dialect refuses the line.
    """

    def __init__(
        self,
        message: str,
        file: str = "<string>",
        line: int = 0,
        column: int = 1,
        source_line: str | None = None,
        grbl_code: int | None = None,
    ):
        self.message = message
        self.file = file
        self.line = int(line)
        self.column = max(1, int(column))
        self.source_line = source_line
        self.grbl_code = grbl_code
        super().__init__(message, f"{file}:{self.line}:{self.column}")

    def __str__(self) -> str:
        text = f"{self.file}:{self.line}:{self.column}: {self.message}"
        if self.grbl_code is not None:
            text += f" (GRBL error:{self.grbl_code})"
        if self.source_line is not None:
            src = self.source_line.rstrip("\r\n").expandtabs(1)
            text += f"\n    {src}\n    {' ' * (self.column - 1)}^"
        return text

    def __reduce__(self):
        return (
            GCodeError,
            (self.message, self.file, self.line, self.column, self.source_line, self.grbl_code),
        )


class LineError(Exception):
    """Raised inside the parser/executor with a column only; the caller adds file/line."""

    def __init__(self, message: str, column: int = 1, grbl_code: int | None = None):
        super().__init__(message)
        self.message = message
        self.column = column
        self.grbl_code = grbl_code
