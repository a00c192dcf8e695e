"""Reading a program file: plain OS errors, binary files refused up front, BOM dropped.

``read_program(path) -> bytes`` is what :func:`sim.gcode.load_program` and o-word
subroutine files go through, so a missing file, a directory or an executable handed
over by mistake gets one plain line instead of a parse error at ``1:1`` with binary
bytes echoed to the terminal.
"""

from __future__ import annotations

import re
from pathlib import Path

from sim.gcode.errors import ProgramFileError

#: how much of the start of a file is examined for binary data (bytes)
SNIFF_BYTES = 1024
#: control bytes (not tab, LF, VT, FF, CR, ^Z) a text file may carry before it counts as binary
MAX_STRAY_CONTROLS = 4
#: invalid UTF-8 bytes tolerated per sniffed byte: a Latin-1 file with a few accented
#: letters in its comments is text; random or compressed data is far above this
MAX_INVALID_UTF8_FRACTION = 1 / 16

_UTF8_BOM = b"\xef\xbb\xbf"
# C0 controls other than tab, LF, VT, FF, CR and ^Z (DOS end-of-file, seen in old files), and DEL
_CONTROL = re.compile(rb"[\x01-\x08\x0e-\x19\x1b-\x1f\x7f]")


def _invalid_utf8_offsets(head: bytes) -> list[int]:
    """Offsets of bytes in ``head`` that are not valid UTF-8 (a sequence cut by the end is not counted)."""
    bad: list[int] = []
    pos = 0
    while pos < len(head):
        try:
            head[pos:].decode("utf-8")
            break
        except UnicodeDecodeError as exc:
            if exc.reason == "unexpected end of data" and pos + exc.end == len(head):
                break  # a multi-byte character cut by the sniff window
            bad.extend(range(pos + exc.start, pos + exc.end))
            pos += exc.end
    return bad


def binary_offset(data: bytes) -> tuple[int, str] | None:
    """Where the first :data:`SNIFF_BYTES` of ``data`` stop looking like a text program.

    Returns ``(byte offset (0-based), what was found)`` or ``None`` for text. Text is
    ASCII or UTF-8 with at most a few stray bytes: a NUL byte, more than
    :data:`MAX_STRAY_CONTROLS` control bytes or more than
    :data:`MAX_INVALID_UTF8_FRACTION` invalid UTF-8 bytes mean binary data.
    """
    head = bytes(data[:SNIFF_BYTES])
    if head.startswith((b"\xff\xfe", b"\xfe\xff")):
        return 0, "UTF-16 text; save it as ASCII or UTF-8"
    nul = head.find(b"\0")
    if nul >= 0:
        return nul, "binary data"
    controls = [m.start() for m in _CONTROL.finditer(head)]
    if len(controls) > MAX_STRAY_CONTROLS:
        return controls[0], "binary data"
    if head.isascii():
        return None
    invalid = _invalid_utf8_offsets(head)
    if len(invalid) > max(MAX_STRAY_CONTROLS, len(head) * MAX_INVALID_UTF8_FRACTION):
        return invalid[0], "binary data"
    return None


def check_text(data: bytes, name: str) -> bytes:
    """``data`` without a leading UTF-8 BOM; :class:`ProgramFileError` when it is not text."""
    found = binary_offset(data)
    if found is not None:
        offset, what = found
        raise ProgramFileError(f"{name}: not a text G-code file ({what} at byte {offset})", name)
    if data.startswith(_UTF8_BOM):
        # Windows editors and some CAM post-processors write one; it is no G-code character
        data = data[len(_UTF8_BOM):]
    return data


def read_program(path) -> bytes:
    """The bytes of the program file ``path`` (checked by :func:`check_text`).

    Raises :class:`ProgramFileError` naming the file and the OS reason when it cannot be
    read, or when it is not a text file.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise ProgramFileError(f"no such program file: {path}", str(path)) from None
    except IsADirectoryError:
        raise ProgramFileError(f"cannot read program file {path}: it is a directory", str(path)) from None
    except OSError as exc:
        raise ProgramFileError(f"cannot read program file {path}: {exc.strerror or exc}", str(path)) from None
    return check_text(data, str(path))
