"""Tool path correction speed: corrected positions per second on the whole carpet1 path
(../shared/corpus/parts, 65,484 points made for a 6 mm ball) run with an 8 mm ball, which
gouges it by about 0.34 mm.

Prints one JSON line per resolution: positions (rows looked at) per second of the
correction alone (median of ``--repeat`` runs), the poses it moved, splits and lifts, the
lines changed and inserted, and the check of the written program through ``dexmon
simulate``'s checks (gouges left, undercut left) with its wall time, and ``finer_check``:
the same check on rays twice as dense (what lies between the rays the correction saw);
``load`` is ``os.getloadavg()`` beside the figures (this machine is shared: absolute
speeds drift).

Usage: python bench/correct_bench.py [SHARED_DIR] [--resolution 0.4,0.2] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

STOCK = "box:0,-82,-10,152,66,5.197857"


def one_resolution(parts: Path, resolution: float, repeat: int) -> dict:
    from monitor.commands.correct import _program_setup, verify
    from sim.correct.gouge import GougeProbe
    from sim.correct.path import correct_moves
    from sim.correct.rewrite import rewrite_program
    from monitor.commands.correct import _to_program
    from monitor.cli import build_parser

    program = parts / "carpet1_ball6_finish.ngc"
    args = build_parser("correct").parse_args(
        ["correct", str(program), "--stock", STOCK, "--tool", "ball:8", "--design", str(parts / "carpet1.stl"),
         "--resolution", str(resolution), "--tolerance", "0.002"])
    setup = _program_setup(args)
    prog, _, moves = setup.load(program)
    probe = GougeProbe(setup.design, setup.tol)
    correct_moves(moves[:50], probe, setup.tools, setup.tool, setup.tol)  # compile / warm
    rates = []
    corr = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        corr = correct_moves(moves, probe, setup.tools, setup.tool, setup.tol, min_segment=args.min_segment)
        rates.append(corr.poses / (time.perf_counter() - t0))
    written = rewrite_program(program.read_bytes(), str(program), prog, corr, _to_program(prog.moves, moves))
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "fixed.ngc"
        out.write_bytes(written.text)
        t0 = time.perf_counter()
        verified, undercut = verify(setup, out, moves)
        check_s = time.perf_counter() - t0
        finer = finer_check(parts, out, resolution / 2)
    return {"case": "correct carpet1 ball:8 (whole path)", "resolution": resolution, "positions": corr.poses,
            "positions_per_s": round(statistics.median(rates), 1), "runs": [round(r, 1) for r in rates],
            "poses_moved": corr.corrected, "guide_steps": corr.guide_steps, "splits": corr.splits, "lifts": corr.lifts,
            "lines_changed": len(written.changed), "lines_inserted": written.inserted,
            "gouge_before_mm": round(corr.worst_gouge, 4), "largest_shift_mm": round(corr.largest_shift, 4),
            "added_length_mm": round(corr.added_length, 3),
            "gouges_after": verified["gouges"], "undercut_left": undercut, "check_s": round(check_s, 2),
            "finer_check": finer,
            "load": [round(v, 2) for v in os.getloadavg()]}


def finer_check(parts: Path, program: Path, resolution: float) -> dict:
    """``dexmon simulate --design`` of the corrected program on rays twice as dense as the
    correction's: the deepest gouge left between the rays it saw."""
    import contextlib
    import io

    from monitor.cli import main as cli

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        cli(["simulate", str(program), "--stock", STOCK, "--tool", "ball:8", "--resolution", str(resolution),
             "--design", str(parts / "carpet1.stl"), "--tolerance", "0.002", "--json"])
    gouges = [f for f in json.loads(buf.getvalue())["findings"] if f["kind"] == "gouge"]
    return {"resolution": resolution, "gouges": len(gouges), "worst_mm": max((f["depth"] for f in gouges), default=0.0)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("shared", nargs="?", default=str(ROOT.parent / "shared"))
    ap.add_argument("--resolution", default="0.4,0.2")
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    parts = Path(os.environ.get("DEXMON_SHARED", a.shared)) / "corpus" / "parts"
    if not (parts / "carpet1_ball6_finish.ngc").is_file():
        print(json.dumps({"skipped": f"no corpus at {parts}"}))
        return 0
    for res in (float(r) for r in a.resolution.split(",")):
        print(json.dumps(one_resolution(parts, res, a.repeat)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
