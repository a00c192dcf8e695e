"""One cause, one finding through ``simulate`` and ``dry-run`` (issue 14): a program that
never starts the spindle is one ``spindle_stopped_cutting`` finding with its lines, in the
command's JSON and in the dry run's run file."""

from __future__ import annotations

import json
from pathlib import Path

from monitor.cli import main
from monitor.runreader import RunReader


def no_spindle_job(tmp_path: Path) -> Path:
    """Ten slots 10 mm apart, 1 mm deep, a rapid up and over between them, no M3."""
    rows = ["G21 G90 G54", "G0 Z10"]
    for k in range(10):
        x = 5 + 10 * k
        rows += [f"G0 X{x} Y5", "G1 Z-1 F300", "G1 Y25 F600", "G0 Z10"]
    rows += ["M30"]
    (tmp_path / "slots.ngc").write_text("\n".join(rows) + "\n")
    job = tmp_path / "slots.toml"
    job.write_text("""resolution = 0.5
[program]
path = "slots.ngc"
[stock]
box = [0, 0, -10, 100, 30, 0]
[tools]
default = "flat:4:L=20"
""")
    return job


def test_simulate_tells_a_spindle_never_started_once(tmp_path, capsys):
    job = no_spindle_job(tmp_path)
    assert main(["simulate", str(job), "--json"]) == 1
    found = json.loads(capsys.readouterr().out)["findings"]
    stopped = [f for f in found if f["kind"] == "spindle_stopped_cutting"]
    assert len(stopped) == 1, found
    f = stopped[0]
    # every plunge and slot (lines 4, 5, 8, 9 ... 40, 41) is in it, and it starts at the first
    assert {4 + 4 * k for k in range(10)} | {5 + 4 * k for k in range(10)} <= set(f["lines"])
    assert f["line"] == 4 and f["line_range"] == [f["lines"][0], f["lines"][-1]]
    assert "lines 4-41" in f["message"] and "spindle off" in f["message"]


def test_dry_run_tells_a_spindle_never_started_once(tmp_path, capsys):
    job = no_spindle_job(tmp_path)
    run = tmp_path / "r.sqlite"
    main(["dry-run", str(job), "--clock", "sim", "--speed", "20", "--quiet", "--run", str(run)])
    found = RunReader(run).findings()
    stopped = [f for f in found if f["kind"] == "spindle_stopped_cutting"]
    assert len(stopped) == 1, [(f["kind"], f["line"], f.get("message")) for f in found]
    assert {f["kind"] for f in found} == {"spindle_stopped_cutting"}
