"""Program files that cannot be used: missing, unreadable, binary; escaped source lines; no motion."""

from __future__ import annotations

import pickle
from pathlib import Path

import pytest

from sim.errors import InputError
from sim.gcode import GCodeError, ProgramFileError, interpret, load_program
from sim.gcode.errors import MAX_SHOWN, printable, source_excerpt
from sim.gcode.source_file import SNIFF_BYTES, binary_offset

ELF_HEAD = b"\x7fELF\x02\x01\x01\x00" + bytes(8) + b"\x03\x00>\x00\x01\x00\x00\x00"


def _write(tmp_path, data: bytes, name="p.ngc") -> Path:
    p = tmp_path / name
    p.write_bytes(data)
    return p


# --- missing / unreadable -------------------------------------------------------------

def test_missing_file_says_so_plainly(tmp_path):
    path = tmp_path / "nonexist.nc"
    with pytest.raises(ProgramFileError) as info:
        load_program(path)
    assert str(info.value) == f"no such program file: {path}"
    assert isinstance(info.value, InputError) and isinstance(info.value, GCodeError)
    assert info.value.file == str(path) and info.value.line == 0


def test_directory_is_not_a_program(tmp_path):
    with pytest.raises(ProgramFileError, match=r"cannot read program file .*: it is a directory$"):
        load_program(tmp_path)


def test_unreadable_file_gives_os_reason(tmp_path, monkeypatch):
    path = _write(tmp_path, b"G0 X1\nM2\n")

    def refuse(self):
        raise PermissionError(13, "Permission denied", str(self))

    # chmod 000 is no test when the suite runs as root
    monkeypatch.setattr(Path, "read_bytes", refuse)
    with pytest.raises(ProgramFileError) as info:
        load_program(path)
    assert str(info.value) == f"cannot read program file {path}: Permission denied"
    assert "\n" not in str(info.value)


def test_file_errors_survive_pickling(tmp_path):
    """Errors cross process boundaries (worker pools) as the same type and text."""
    with pytest.raises(ProgramFileError) as info:
        load_program(tmp_path / "gone.nc")
    back = pickle.loads(pickle.dumps(info.value))
    assert type(back) is ProgramFileError and str(back) == str(info.value)


def test_line_zero_errors_have_no_location(tmp_path):
    """Whole-file errors (a bad .var file here) read 'file: message', not 'file:0:1:'."""
    with pytest.raises(GCodeError) as info:
        load_program(_write(tmp_path, b"G0 X1\nM2\n"), var_file=tmp_path / "missing.var")
    text = str(info.value)
    assert text.startswith(f"{tmp_path / 'missing.var'}: cannot read parameter file") and ":0:" not in text


# --- binary files -----------------------------------------------------------------------

def test_elf_binary_is_refused_before_parsing(tmp_path):
    path = _write(tmp_path, ELF_HEAD + bytes(range(256)) * 8, "binary.nc")
    with pytest.raises(ProgramFileError) as info:
        load_program(path)
    # the first NUL of the ELF header is at byte 7
    assert str(info.value) == f"{path}: not a text G-code file (binary data at byte 7)"
    assert "\x7f" not in str(info.value) and "ELF" not in str(info.value)


def test_binary_is_refused_even_with_keep_going(tmp_path):
    with pytest.raises(ProgramFileError, match="not a text G-code file"):
        load_program(_write(tmp_path, ELF_HEAD), keep_going=True)


def test_binary_without_nul_is_found_by_control_bytes():
    data = b"G0 X1\n" + b"\x01\x02\x03\x04\x05\x06" + b"G1 X2\n"
    assert binary_offset(data) == (6, "binary data")


def test_random_high_bytes_without_nul_or_controls_are_binary():
    # invalid UTF-8 everywhere (lone continuation bytes), no NUL, no control bytes
    data = b"G0 X1\n" + bytes([0x80 + (i * 37) % 64 for i in range(600)])
    offset, what = binary_offset(data)
    assert offset == 6 and what == "binary data"


def test_utf16_is_named():
    data = "G0 X1\nM2\n".encode("utf-16")
    assert binary_offset(data) == (0, "UTF-16 text; save it as ASCII or UTF-8")


@pytest.mark.parametrize("data", [
    b"",
    b"G0 X1\nM2\n",
    "(Fr\u00e4se \u00d86 mm, Schlichten) G0 X1\nM2\n".encode("utf-8"),
    # Latin-1 comments: a few stray invalid bytes are still a text file
    "(Fr\u00e4se \u00d86 mm, Stufenbohrung \u00fcber Teil)\nG0 X1\nM2\n".encode("latin-1"),
    # a DOS end-of-file marker and form feeds are old but honest text
    b"G0 X1\n\x0cM2\n\x1a",
    # a multi-byte character cut by the sniff window is not an error
    b"(" + b"x" * (SNIFF_BYTES - 2) + "\u00e4)".encode("utf-8") + b"\nM2\n",
])
def test_text_files_pass_the_sniff(data):
    assert binary_offset(data) is None


def test_nul_after_the_sniff_window_is_a_parse_error_with_escaped_source(tmp_path):
    body = b"G0 X1\n" * (SNIFF_BYTES // 6 + 10)
    path = _write(tmp_path, body + b"G1 X2\x00 F100\nM2\n")
    with pytest.raises(GCodeError) as info:
        load_program(path)
    err = info.value
    assert not isinstance(err, ProgramFileError)
    assert err.line == SNIFF_BYTES // 6 + 11 and err.column == 6
    shown = str(err).splitlines()
    assert shown[1] == "    G1 X2\\x00 F100" and shown[2] == "    " + " " * 5 + "^"
    assert "\x00" not in str(err)


def test_utf8_bom_is_dropped(tmp_path):
    prog = load_program(_write(tmp_path, b"\xef\xbb\xbfG21 G0 X1\nM2\n"))
    assert prog.moves["kind"].tolist() == [0, 8]
    assert interpret("\ufeffG0 X2\nM2\n").moves["kind"].tolist() == [0, 8]


def test_binary_subroutine_file_is_an_error_at_the_call(tmp_path):
    _write(tmp_path, ELF_HEAD, "blob.ngc")
    main = _write(tmp_path, b"G0 X0\no<blob> call\nM2\n")
    with pytest.raises(GCodeError) as info:
        load_program(main)
    err = info.value
    assert err.line == 2 and "not a text G-code file (binary data at byte 7)" in err.message
    assert "blob.ngc" in err.message


# --- escaping the source-line display ---------------------------------------------------

def test_escape_sequences_are_shown_escaped_with_the_caret_in_place():
    with pytest.raises(GCodeError) as info:
        interpret("G0 X1 \x1b[2J Y1\nM2\n")
    lines = str(info.value).splitlines()
    assert "\x1b" not in str(info.value)
    assert lines[1] == "    G0 X1 \\x1b[2J Y1"
    caret = lines[2].index("^")
    assert lines[1][caret:caret + 4] == "\\x1b"


def test_invisible_unicode_is_escaped():
    # right-to-left override and a no-break space: both hide what the line really says
    text, caret = source_excerpt("G0\u202e X1\u00a0Y2", 7)
    assert text == "G0\\u202e X1\\xa0Y2" and text[caret:caret + 4] == "\\xa0"
    assert printable("ok\x07") == "ok\\x07" and printable("plain") == "plain"


def test_tabs_keep_the_caret_under_the_column():
    text, caret = source_excerpt("G0\tX1\tQ5", 7)
    assert text == "G0 X1 Q5" and text[caret] == "Q"


def test_long_lines_are_cut_around_the_column():
    line = "(" + "a" * 1000 + ") G0 X1 Q5 " + "b" * 1000
    col = line.index("Q") + 1
    text, caret = source_excerpt(line, col)
    assert len(text) <= MAX_SHOWN + 6 and text.startswith("...") and text.endswith("...")
    assert text[caret] == "Q"
    short, c0 = source_excerpt("G0 X1", 6)  # a column just past the end
    assert short == "G0 X1" and c0 == 5


# --- programs with no motion --------------------------------------------------------------

def test_empty_program_warns_no_motion_only(tmp_path):
    prog = load_program(_write(tmp_path, b"\n  \n"))
    assert len(prog.moves) == 0
    assert prog.warnings == [f"{tmp_path / 'p.ngc'}: no motion in program (the file is empty)"]


def test_program_without_motion_warns(tmp_path):
    prog = load_program(_write(tmp_path, b"(setup only)\nG21 G90 M3 S1000\nG4 P1\nM2\n"))
    assert prog.moves["kind"].tolist() == [4, 8]
    assert prog.warnings == [f"{tmp_path / 'p.ngc'}: no motion in program"]


def test_program_with_motion_has_no_such_warning():
    assert interpret("G0 X1\nM2\n").warnings == []
    assert interpret("G38.2 Z-5 F100\nM2\n").warnings == []  # a probe move moves the machine
