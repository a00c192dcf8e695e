"""Damaged run files: a one-line error naming what is damaged, or a replay of what is intact
with a warning naming what was skipped -- never a traceback (issue 12)."""

from __future__ import annotations

import shutil
import sqlite3

import pytest

from monitor.cli import main
from tests.monitor.run_helpers import PATH, STEPS, record_run

LAST = (len(PATH) - 1) * STEPS


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    path = tmp_path_factory.mktemp("run") / "job.dexrun"
    record_run(path, chunk_every=5)
    return path


def damaged_copy(recorded, tmp_path, *sql, params=()) -> str:
    """A copy of the recorded run with ``sql`` statements applied to it."""
    copy = tmp_path / "damaged.dexrun"
    shutil.copy(recorded, copy)
    con = sqlite3.connect(copy)
    for s in sql:
        con.execute(s, params if "?" in s else ())
    con.commit()
    con.close()
    return str(copy)


def one_line(text: str) -> str:
    lines = [x for x in text.splitlines() if x.strip()]
    assert len(lines) == 1, text
    assert "Traceback" not in text
    return lines[0]


def test_flipped_byte_in_a_finding_text_is_named_and_the_rest_replays(recorded, tmp_path, capsys):
    """Issue 12: a flipped byte in stored text gave ``UnicodeDecodeError``."""
    js = sqlite3.connect(recorded).execute("SELECT json FROM findings WHERE id = 1").fetchone()[0]
    raw = bytearray(js.encode())
    raw[3] ^= 0xC0  # no longer UTF-8
    run = damaged_copy(recorded, tmp_path, "UPDATE findings SET json = ? WHERE id = 1", params=(bytes(raw),))
    assert main(["replay", run, "--findings"]) == 1
    out, err = capsys.readouterr()
    assert "Rapid into stock" in out and "Gouge" not in out  # finding 2 kept, finding 1 skipped
    warning = one_line(err)
    assert "damaged" in warning and "findings row 1" in warning and run in warning


def test_wrong_type_in_a_state_cell_is_named_and_the_report_is_written(recorded, tmp_path, capsys):
    """Issue 12: a wrong type in a table cell gave ``ValueError`` in monitor/runfile.py."""
    run = damaged_copy(recorded, tmp_path, "INSERT INTO states(t, mx, state) VALUES (1.0, 2.0, 'Run')",
                       "INSERT INTO states(t, mx, state) VALUES (1.1, 2.0, 'Run')",
                       "UPDATE states SET t = 'soon' WHERE id = 1")
    out_html = tmp_path / "r.html"
    assert main(["report", run, "-o", str(out_html)]) == 0
    out, err = capsys.readouterr()
    assert out_html.is_file() and "wrote" in out
    warning = one_line(err)
    assert "states row 1" in warning and run in warning


def trace_row_bytes(path, row: int) -> bytes:
    return sqlite3.connect(path).execute("SELECT data FROM trace WHERE id = ?", (row,)).fetchone()[0]


def test_a_flipped_byte_in_a_trace_chunk_is_detected_not_drawn(recorded, tmp_path, capsys):
    """Chunks carry a checksum: the damaged chunk and those after it are skipped, the run
    replays up to the stage before it, and the warning names the row."""
    rows = sqlite3.connect(recorded).execute("SELECT id, stage_from FROM trace ORDER BY id").fetchall()
    bad_row, bad_from = rows[3]
    data = bytearray(trace_row_bytes(recorded, bad_row))
    data[len(data) // 2] ^= 0x01  # one bit: the arrays still decode, only the checksum sees it
    run = damaged_copy(recorded, tmp_path, f"UPDATE trace SET data = ? WHERE id = {bad_row}", params=(bytes(data),))
    assert main(["replay", run, "--json"]) == 0
    out, err = capsys.readouterr()
    import json
    summary = json.loads(out)
    assert summary["last_stage"] < bad_from and summary["truncated"]
    warning = one_line(err)
    assert f"trace row {bad_row} (checksum mismatch)" in warning and f"trace rows {bad_row + 1}.." in warning


def test_a_first_trace_chunk_damaged_is_a_one_line_error_and_findings_still_list(recorded, tmp_path, capsys):
    run = damaged_copy(recorded, tmp_path, "UPDATE trace SET stage_to = 'later' WHERE id = 1")
    assert main(["replay", run, "--stage", "end", "--png", str(tmp_path / "x.png")]) == 2
    line = one_line(capsys.readouterr().err)
    assert run in line and "trace row 1 (checksum mismatch)" in line and "no stage can be rebuilt" in line
    assert "states" in line and "2 findings readable" in line
    assert main(["replay", run, "--findings"]) == 1
    out, err = capsys.readouterr()
    assert "Gouge" in out and err == ""


def test_rows_deleted_at_the_end_are_missing_not_unseen(recorded, tmp_path, capsys):
    """The writer counts the rows of each table when it closes: a lost last trace chunk or
    finding is named, not replayed as if the run had ended there."""
    run = damaged_copy(recorded, tmp_path, "DELETE FROM trace WHERE id = (SELECT MAX(id) FROM trace)",
                       "DELETE FROM findings WHERE id = 2")
    assert main(["replay", run, "--findings"]) == 1
    out, err = capsys.readouterr()
    assert "findings row 2 (missing)" in one_line(err)
    assert main(["replay", run]) == 0
    out, err = capsys.readouterr()
    assert "(cut short)" in out and "trace row" in one_line(err) and "(missing)" in err


def test_a_file_damaged_beyond_opening_is_one_line(recorded, tmp_path, capsys):
    run = tmp_path / "zeroed.dexrun"
    raw = bytearray(recorded.read_bytes())
    raw[:100] = bytes(100)  # the SQLite header
    run.write_bytes(bytes(raw))
    assert main(["report", str(run), "-o", str(tmp_path / "r.html")]) == 2
    line = one_line(capsys.readouterr().err)
    assert str(run) in line and "damaged beyond opening" in line


def test_byte_flips_anywhere_never_give_a_traceback(recorded, tmp_path, capsys):
    """A small seeded sweep (bench/runfile_fuzz.py runs the big one): every outcome is a
    one-line error, a clean replay, or a replay with a one-line warning."""
    import random

    rng = random.Random(12)
    base = recorded.read_bytes()
    run = tmp_path / "flipped.dexrun"
    for k in range(40):
        raw = bytearray(base)
        for _ in range(1 + k % 3):
            raw[rng.randrange(len(raw))] ^= rng.randrange(1, 256)
        run.write_bytes(bytes(raw))
        rc = main(["replay", str(run), "--stage", "end", "--png", str(tmp_path / "f.png")])
        err = capsys.readouterr().err
        assert rc in (0, 2) and len(err.splitlines()) <= 1, err
        assert rc == 0 or "error:" in err


def test_old_run_files_without_checksums_open_and_say_so(recorded, tmp_path, capsys):
    tables = ("meta", "arrays", "states", "findings", "alerts", "cuts", "trace", "link_events")
    run = damaged_copy(recorded, tmp_path, *[f"ALTER TABLE {t} DROP COLUMN crc" for t in tables])
    assert main(["replay", run, "--stage", "end", "--png", str(tmp_path / "o.png")]) == 0
    line = one_line(capsys.readouterr().err)
    assert "note:" in line and "no checksums" in line
    from monitor.runreader import RunReader
    assert not RunReader(run).checked and RunReader(recorded).checked


def test_row_checksums_hold_for_what_sqlite_gives_back():
    """The writer stores numbers as SQLite gives them back (2 in a REAL column as 2.0, 3.0
    in an INTEGER column as 3, NaN as NULL, -0.0 as 0.0), so their checksums match; a
    number that became text does not."""
    import numpy as np

    from monitor.runfile import normal_row, row_crc
    written = normal_row("findings", (2, "gouge", np.float64(3.0), float("nan"), "{}"))
    assert written == (2.0, "gouge", 3, None, "{}") and row_crc(written) == row_crc((2.0, "gouge", 3, None, "{}"))
    assert normal_row("cuts", (1, -0.0, 2**70, np.int64(5), "[]", b"x")) == (1, 0.0, 2.0**70, 5, "[]", b"x")
    assert row_crc((1.5,)) != row_crc(("1.5",)) and row_crc((3,)) != row_crc((3.0,))


def test_unpack_refuses_headers_that_would_overflow():
    import json
    import numpy as np
    from monitor.runfile import RunFileError, pack_arrays, unpack_arrays

    header, data = pack_arrays({"a": np.arange(4, dtype=np.int32)})
    for change in ({"shape": [1e999]}, {"shape": [[1]]}, {"dtype": [["x", "<i4", [1e999]]]},
                   {"dtype": 7}, {"nbytes": "many"}, {"dtype": "|V0", "shape": [2**62], "nbytes": 0}):
        bad = json.loads(header)
        bad[0].update(change)
        with pytest.raises(RunFileError):
            unpack_arrays(json.dumps(bad), data, "x")
    with pytest.raises(RunFileError, match="not JSON"):
        unpack_arrays("[" * 100000, data, "x")


def test_a_schema_whose_names_are_not_utf8_is_one_line(recorded, tmp_path, capsys):
    """Found by bench/runfile_fuzz.py: a damaged schema made sqlite3 raise UnicodeDecodeError
    (for the text of its error message)."""
    bad = b"CREATE TABLE alerts(a) \x84\xff"  # the error message quotes it: not UTF-8
    run = damaged_copy(recorded, tmp_path, "PRAGMA writable_schema = 1",
                       "UPDATE sqlite_master SET sql = CAST(? AS TEXT) WHERE name = 'alerts'", params=(bad,))
    assert main(["replay", run, "--findings"]) == 2
    line = one_line(capsys.readouterr().err)
    assert run in line and "damaged beyond opening" in line


def test_an_intact_run_file_reads_without_damage(tmp_path):
    """No false alarms: odd values a controller made up, NaN, -0.0, ints in REAL columns,
    and findings updated after they were appended all keep their checksums."""
    import numpy as np

    from drivers.state import MachineState, RunState
    from monitor.runfile import RunWriter
    from monitor.runreader import RunReader

    path = tmp_path / "r.sqlite"
    with RunWriter(path) as w:
        w.append_state(MachineState(t=0, mpos=(1, -0.0, float("nan")), state=RunState.RUN, line=2**64,
                                    feed=np.float32(600), raw=b"<Run>"))
        w.append_state(MachineState(t=0.5, mpos=(1, 2, 3), state=RunState.HOLD, line=np.int64(7), raw="<Hold>"))
        w.append_finding({"kind": "gouge", "line": 3, "lead_time_s": 2.0}, t=np.float64(0.25))
        w.update_finding(1, {"kind": "gouge", "line": 3, "lead_time_s": 1.5, "status": "happened"})
        w.append_alert("terminal", "gouge", t=1, finding_id=1)
        w.append_cut(1, {"p1": np.ones(3)}, t=np.float64(0.5), move_id=np.int64(2), line=3)
        w.append_link_event(0.5, "note", {"message": "ok", "n": float("inf")})
        w.put_meta("limits", {"x": [0, 1]})
        w.put_array("moves", np.zeros(2, [("line", "<i4"), ("end", "<f8", 3)]))
    r = RunReader(path)
    assert len(r.states()) == 2 and r.findings()[0]["status"] == "happened" and len(r.alerts()) == 1
    assert len(list(r.cuts())) == 1 and r.link_events()[0]["message"] == "ok"
    assert r.get_array("moves").size == 2 and r.meta()["limits"]
    assert r.damage == [] and r.damage_line() is None


def test_resume_from_a_damaged_run_names_the_damage_past_its_intact_stages(recorded, tmp_path):
    from monitor.resume import resume_grid
    from sim.errors import InputError

    last_row = sqlite3.connect(recorded).execute("SELECT MAX(id) FROM trace").fetchone()[0]
    run = damaged_copy(recorded, tmp_path, f"UPDATE trace SET header = header || ' ' WHERE id = {last_row}")
    grid, stage = resume_grid(f"{run}:end")
    assert 0 < stage < LAST
    with pytest.raises(InputError, match=rf"beyond the run's last recorded stage {stage} .*trace row {last_row} "
                                         r"\(checksum mismatch\)"):
        resume_grid(f"{run}:{LAST}")


UNCHECKED = [f"ALTER TABLE {t} DROP COLUMN crc" for t in
             ("meta", "arrays", "states", "findings", "alerts", "cuts", "trace", "link_events")]


def test_an_unchecked_finding_with_fields_of_the_wrong_type_is_skipped(recorded, tmp_path, capsys):
    """Without checksums only the types guard the commands: a finding whose position is
    not numbers gave ``ValueError`` in format_finding."""
    odd = '{"kind": "gouge", "position": ["a", "b", "c"], "depth": "x"}'
    run = damaged_copy(recorded, tmp_path, *UNCHECKED, f"UPDATE findings SET json = '{odd}' WHERE id = 1")
    assert main(["replay", run, "--findings"]) == 1
    out, err = capsys.readouterr()
    assert "Rapid into stock" in out and "Gouge" not in out
    assert "findings row 1 (position is ['a', 'b', 'c'], expected a list of numbers)" in one_line(err)


def test_an_unchecked_integer_cell_beyond_64_bits_is_skipped(recorded, tmp_path, capsys):
    """Found by bench/runfile_fuzz.py: a stage of 1e308 in an unchecked file gave OverflowError."""
    run = damaged_copy(recorded, tmp_path, *UNCHECKED, "UPDATE cuts SET stage = 1e308 WHERE id = 3")
    assert main(["replay", run, "--stage", "end", "--png", str(tmp_path / "o.png")]) == 0
    assert "cuts row 3 (stage holds 1e+308, expected an integer)" in one_line(capsys.readouterr().err)


def test_control_characters_in_sqlite_messages_stay_on_one_line(recorded, tmp_path, capsys):
    """Found by bench/runfile_fuzz.py: SQLite quoted a damaged schema's \\x1e, which
    splits lines for Python."""
    run = damaged_copy(recorded, tmp_path, "PRAGMA writable_schema = 1",
                       "UPDATE sqlite_master SET sql = 'CREATE TABLE alerts(a) \x1e' WHERE name = 'alerts'")
    assert main(["replay", run, "--findings"]) == 2
    assert "\\x1e" in one_line(capsys.readouterr().err)
