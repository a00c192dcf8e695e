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
        super().__init__(message, file if self.line <= 0 else f"{file}:{self.line}:{self.column}")

    def __str__(self) -> str:
        if self.line <= 0:
            # a whole-file problem (unreadable file, bad option): no line or column to point at
            return f"{self.file}: {printable(self.message)}"
        text = f"{self.file}:{self.line}:{self.column}: {printable(self.message)}"
        if self.grbl_code is not None:
            text += f" (GRBL error:{self.grbl_code})"
        if self.source_line is not None:
            src, caret = source_excerpt(self.source_line, self.column)
            text += f"\n    {src}\n    {' ' * caret}^"
        return text

    def __reduce__(self):
        return (
            type(self),
            (self.message, self.file, self.line, self.column, self.source_line, self.grbl_code),
        )


class ProgramFileError(GCodeError):
    """A program file that cannot be used at all: missing, unreadable or not text.

    ``message`` is the whole line and names the file (``no such program file: PATH``);
    ``line`` is 0.
    """

    def __init__(self, message: str, file: str = "<string>", line: int = 0, column: int = 1,
                 source_line: str | None = None, grbl_code: int | None = None):
        super().__init__(message, file, 0, 1, None, None)

    def __str__(self) -> str:
        return printable(self.message)


#: longest source line shown in full; longer ones are cut to a window around the column
MAX_SHOWN = 160


def _escape(c: str) -> str:
    if c == "\t":
        return " "  # one column, so the caret below stays under the right character
    if c.isprintable():
        return c
    o = ord(c)
    return f"\\x{o:02x}" if o < 0x100 else f"\\u{o:04x}" if o < 0x10000 else f"\\U{o:08x}"


def printable(text: str) -> str:
    """``text`` with control and other invisible characters escaped (``\\x1b``, ``\\u202e``).

    Keeps a terminal safe from bytes of a broken or binary file (escape sequences,
    bidi overrides) and makes an invisible stray character visible.
    """
    return text if text.isprintable() else "".join(map(_escape, text))


def source_excerpt(line: str, column: int) -> tuple[str, int]:
    """(the source line as shown, offset of the caret under 1-based ``column`` in it).

    Invisible characters are escaped (see :func:`printable`); a line longer than
    :data:`MAX_SHOWN` characters is cut to a window around the column, marked ``...``.
    """
    line = line.rstrip("\r\n")
    col = min(max(column, 1), len(line) + 1) - 1  # 0-based, may point just past the end
    lead = trail = ""
    if len(line) > MAX_SHOWN:
        a = max(0, min(col - MAX_SHOWN // 2, len(line) - MAX_SHOWN))
        b = a + MAX_SHOWN
        lead = "..." if a > 0 else ""
        trail = "..." if b < len(line) else ""
        line, col = line[a:b], col - a
    before = lead + "".join(map(_escape, line[:col]))
    return before + "".join(map(_escape, line[col:])) + trail, len(before)


class LineError(Exception):
    """Raised inside the parser/executor with a column only; the caller adds file/line."""

    def __init__(self, message: str, column: int = 1, grbl_code: int | None = None):
        super().__init__(message)
        self.message = message
        self.column = column
        self.grbl_code = grbl_code
