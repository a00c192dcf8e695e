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
