"""A dry run polled far more coarsely than the program's rows (``--speed 500`` at 50 Hz:
10 s of machine time, hundreds of rows, between two polls) judges the path the tool took,
and records the machine's own time.

Between two polls the tool followed the program's rows (the live cut inserts the corners
passed), not the chord between the polled tips: over a convex dome that chord would cut
into the design, a gouge the program does not make. And the virtual machine keeps its
planner fed while it runs a poll's step, so the recorded run lasts as long as the program
(before: 15 rows per poll and the rest of the step idle; the corpus dome at ``--speed
2000`` recorded 65,080 s against 280 s programmed)."""

from __future__ import annotations

import json

import numpy as np

from monitor.cli import main
from monitor.runreader import RunReader
from tests.monitor.test_dry_run_flags import CX, CY, R, dome_design, dome_program

SPEED, POLL_HZ = 500.0, 50.0


def test_raster_over_a_dome_polled_coarsely_is_clean_and_takes_the_programs_time(tmp_path, capsys):
    prog, design, run = tmp_path / "dome.ngc", tmp_path / "dome.stl", tmp_path / "r.sqlite"
    dome_program(prog, ys=np.arange(CY - 12, CY + 12.01, 1.0))
    dome_design(design)
    main(["dry-run", "--program", str(prog), "--stock", f"box:0,0,0,{2 * CX},{2 * CY},{R + 1}",
          "--design", str(design), "--tool", "ball:6", "--resolution", "0.5",
          "--clock", "sim", "--speed", f"{SPEED:g}", "--json", "--run", str(run)])
    events = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    summary = events[-1]
    assert summary["event"] == "summary" and summary["progress_s"] == summary["program_s"]
    found = [e for e in events if e["event"] == "finding"]
    assert [f for f in found if f["kind"] == "gouge"] == [], found[:1]
    moves = RunReader(run).get_array("moves")
    step_s = SPEED / POLL_HZ
    times = [float(s["t"]) for s in RunReader(run).states()]
    # one state per poll step of machine time, the last within a step of the program's end
    assert np.allclose(np.diff(times), step_s)
    assert times[-1] <= summary["program_s"] + 2 * step_s
    assert len(moves) / len(times) > 100, "the polls must be coarse for this test to mean anything"
