"""``dexmon moves`` through monitor.cli.main(argv)."""

from __future__ import annotations

import csv
import io
import json

import pytest

from monitor.cli import main


def _write(tmp_path, text, name="p.ngc"):
    p = tmp_path / name
    p.write_text(text)
    return str(p)


def test_jsonl_rows(tmp_path, capsys):
    prog = _write(tmp_path, "G21 G90 G10 L2 P1 X100\nG0 X1 Y2 Z3\nG2 X3 Y2 I1 J0 F100\nM2\n")
    assert main(["moves", prog]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [r["kind"] for r in rows] == ["rapid", "arc_cw", "end"]
    assert rows[0]["line"] == 2 and rows[0]["end"] == [1, 2, 3] and rows[0]["end_machine"] == [101, 2, 3]
    assert rows[1]["center"] == [2, 2, 3] and rows[1]["plane"] == "xy" and rows[1]["turns"] == 1
    assert rows[1]["start"] == [1, 2, 3]


def test_csv_inch_program(tmp_path, capsys):
    prog = _write(tmp_path, "G20 G1 X1 F10\nM30\n")
    assert main(["moves", prog, "--format", "csv"]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert rows[0]["kind"] == "feed" and float(rows[0]["end_x"]) == 25.4 and float(rows[0]["feed"]) == 254


def test_tool_table_var_and_machine_units(tmp_path, capsys):
    tbl = _write(tmp_path, "T1 P1 D0.25 Z1.0 ;quarter inch\n", "t.tbl")
    var = _write(tmp_path, "5221 1.0\n", "p.var")
    prog = _write(tmp_path, "G21 T1 M6 G43 H1\nG0 X0 Z0\nM2\n")
    assert main(["moves", prog, "--tool-table", tbl, "--var", var, "--machine-units", "inch"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    rapid = next(r for r in rows if r["kind"] == "rapid")
    assert rapid["end_machine"] == [25.4, 0, 25.4] and rapid["tool_length"] == 25.4


def test_grbl_dialect_error_exits_2_with_location(tmp_path, capsys):
    prog = _write(tmp_path, "G21\nG81 X1 Z-1 R1 F100\n")
    assert main(["moves", prog, "--dialect", "grbl"]) == 2
    err = capsys.readouterr().err
    assert "p.ngc:2:1" in err and "error:20" in err and "Traceback" not in err


def test_keep_going_lists_all(tmp_path, capsys):
    prog = _write(tmp_path, "G0 X1\nG2 X3 F1\nG0 Y[\nM2\n")
    assert main(["moves", prog, "--keep-going"]) == 2
    captured = capsys.readouterr()
    assert ":2:" in captured.err and ":3:" in captured.err and "2 error(s)" in captured.err
    assert json.loads(captured.out.splitlines()[0])["kind"] == "rapid"


def test_missing_file_is_one_line(tmp_path, capsys):
    path = tmp_path / "nope.ngc"
    assert main(["moves", str(path)]) == 2
    err = capsys.readouterr().err
    assert err == f"dexmon moves: error: no such program file: {path}\n"


def test_binary_program_is_refused_without_echoing_bytes(tmp_path, capsys):
    path = tmp_path / "binary.nc"
    path.write_bytes(b"\x7fELF\x02\x01\x01\x00" + bytes(range(256)) * 4)
    assert main(["moves", str(path)]) == 2
    captured = capsys.readouterr()
    assert captured.err == f"dexmon moves: error: {path}: not a text G-code file (binary data at byte 7)\n"
    assert captured.out == ""


def test_control_characters_are_escaped_in_the_error(tmp_path, capsys):
    prog = _write(tmp_path, "G21\nG0 X1 \x1b]0;pwned\x07\nM2\n")
    assert main(["moves", prog]) == 2
    err = capsys.readouterr().err
    assert "p.ngc:2:7" in err and "\\x1b]0;pwned\\x07" in err
    assert not any(c in err for c in "\x1b\x07")


@pytest.mark.parametrize("text, warning", [
    ("", "no motion in program (the file is empty)"),
    ("(nothing to cut)\nG21 M3 S1000\nM2\n", "no motion in program"),
])
def test_no_motion_warns_and_exits_0(tmp_path, capsys, text, warning):
    prog = _write(tmp_path, text)
    assert main(["moves", prog]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err[0] == f"warning: {prog}: {warning}"
    if not text:
        assert len(err) == 1  # no "no M2" warning on top for an empty file


def test_time_and_linearize(tmp_path, capsys):
    prog = _write(tmp_path, "G21 G0 X10\nG3 X-10 I-10 F500\nM2\n")
    assert main(["moves", prog, "--linearize", "0.01", "--time"]) == 0
    captured = capsys.readouterr()
    rows = [json.loads(line) for line in captured.out.splitlines()]
    assert all(r["kind"] != "arc_ccw" for r in rows) and len(rows) > 10
    assert "cycle time" in captured.err and all("time" in r for r in rows)


@pytest.mark.parametrize("bad", [["--format", "xml"], ["--dialect", "fanuc"], ["--machine-units", "cm"]])
def test_bad_options(tmp_path, bad):
    prog = _write(tmp_path, "G0 X1\n")
    assert main(["moves", prog, *bad]) == 2


def test_subroutine_path(tmp_path, capsys):
    """o<name> call finds <name>.ngc in --subroutine-path directories (':'-separated or repeated)."""
    subs = tmp_path / "subs"
    subs.mkdir()
    (subs / "square.ngc").write_text("o<square> sub\nG1 X#1 F100\nY#1\nX0\nY0\no<square> endsub\nM2\n")
    prog_dir = tmp_path / "prog"
    prog_dir.mkdir()
    prog = _write(prog_dir, "G21 G0 X0 Y0\no<square> call [5]\nM2\n")
    assert main(["moves", prog]) == 2
    assert "no osquare sub" in capsys.readouterr().err.replace("<", "").replace(">", "")
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["moves", prog, "--subroutine-path", f"{empty}:{subs}"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    feeds = [r["end"][:2] for r in rows if r["kind"] == "feed"]
    assert feeds == [[5, 0], [5, 5], [0, 5], [0, 0]]
    assert {r.get("file") for r in rows if r["kind"] == "feed"} == {str(subs / "square.ngc")}
    assert main(["moves", prog, "--subroutine-path", str(empty), "--subroutine-path", str(subs)]) == 0
    capsys.readouterr()
    assert main(["moves", prog, "--subroutine-path", str(tmp_path / "nope")]) == 2
    assert "not a directory" in capsys.readouterr().err
