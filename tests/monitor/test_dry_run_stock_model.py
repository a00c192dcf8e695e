"""A job that asks for a tri-dexel stock (``[stock] model = "tri-dexel"``) gets one from
``simulate`` only: a live run and a dry run follow the stock on one Z grid, as the live
look-ahead and checks are built on it. Before, they did so without a word: a machinist
who had set the model in the job was never told the run did not use it. Now the run says
so at its start, on the terminal and in JSON, and a job without the setting hears
nothing."""

from __future__ import annotations

import json

from monitor.cli import main

PROGRAM = """G21 G90 G17 G94 G54
T1 M6
S10000 M3
G0 Z5
G0 X-5 Y10
G1 Z-1 F300
G1 X45 F1200
G0 Z5
M5
M30
"""


def write_job(tmp_path, model_line: str):
    (tmp_path / "slot.nc").write_text(PROGRAM)
    job = tmp_path / "job.toml"
    job.write_text(f"""resolution = 0.5
work_offset = "controller"
[controller]
url = "virtual://"
[program]
path = "slot.nc"
[stock]
box = [0, 0, -10, 40, 20, 0]
{model_line}
[tools.1]
spec = "flat:6"
""")
    return job


def dry_run(tmp_path, capsys, job, *flags):
    run = tmp_path / f"r{len(list(tmp_path.glob('r*.sqlite')))}.sqlite"
    rc = main(["dry-run", str(job), "--clock", "sim", "--speed", "50", "--run", str(run), *flags])
    return rc, capsys.readouterr()


def test_a_dry_run_of_a_tri_dexel_job_says_it_follows_a_z_grid(tmp_path, capsys):
    job = write_job(tmp_path, 'model = "tri-dexel"')
    rc, out = dry_run(tmp_path, capsys, job, "--json")
    events = [json.loads(x) for x in out.out.splitlines()]
    assert rc == 0, events
    notes = [e for e in events if e["event"] == "note"]
    assert len(notes) == 1 and notes[0]["kind"] == "stock_model", events
    assert 'model = "tri-dexel"' in notes[0]["text"] and "Z grid" in notes[0]["text"]
    assert "simulate" in notes[0]["text"]
    start = next(e for e in events if e["event"] == "start")
    assert start["stock_model"] == "z"
    # on the terminal: the same words, before the run's first move is judged
    rc, out = dry_run(tmp_path, capsys, job)
    assert rc == 0
    text = " ".join(out.out.split())
    assert 'model = "tri-dexel"' in text and "Z grid" in text, out.out


def test_a_dry_run_of_a_z_grid_job_has_no_note(tmp_path, capsys):
    job = write_job(tmp_path, "")
    rc, out = dry_run(tmp_path, capsys, job, "--json")
    events = [json.loads(x) for x in out.out.splitlines()]
    assert rc == 0 and [e for e in events if e["event"] == "note"] == [], events
    assert next(e for e in events if e["event"] == "start")["stock_model"] == "z"
