"""Benchmark of the checks: whole-model error assessment on ~1M rays against each corpus
part, and the cost of the incremental checks per move during wavy_finish.

Prints one JSON line per case. Usage: python bench/checks_bench.py [SHARED_DIR]
Times are the best of three (whole model) or summed over the run (incremental); ``cpu_s``
is this process's CPU time, steadier than wall time on a shared machine.
"""

from __future__ import annotations

import json
import resource
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from sim.checks import Checker  # noqa: E402
from sim.checks.motion import is_motion  # noqa: E402
from sim.cut import Cutter  # noqa: E402
from sim.frame import Frame  # noqa: E402
from sim.gcode import load_program  # noqa: E402
from sim.solids import box_grid  # noqa: E402
from sim.tolerance import Tolerance  # noqa: E402
from sim.tools import parse_tool_spec  # noqa: E402


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def emit(**kw):
    kw["peak_rss_mb"] = round(rss_mb(), 1)
    print(json.dumps(kw), flush=True)


PARTS = {"sphere_on_plate": (0, 0, -1, 76.4923, 76.4923, 30.8718),
         "carpet1": (0, -82, -10, 152, 66, 5.197857)}


def whole_model(shared: Path):
    for part, b in PARTS.items():
        spacing = max(b[3] - b[0], b[4] - b[1]) / 1000.0  # ~1M rays
        frame = Frame.top(b[0], b[1], b[3], b[4], spacing)
        moves = load_program(shared / "corpus/parts" / f"{part}_ball6_finish.ngc").moves.copy()
        k = np.nonzero(is_motion(moves))[0][0]
        moves["start"][k] = moves["end"][k]
        for spec, tol in (("ball:6", Tolerance(gouge=0.002, undercut=0.05)),
                          ("ball:8", Tolerance(gouge=0.002, undercut=0.002))):
            t0 = time.perf_counter()
            ch = Checker(box_grid(frame, b[:3], b[3:]), parse_tool_spec(spec),
                         design=shared / "corpus/parts" / f"{part}.stl", tol=tol)
            t_design = time.perf_counter() - t0
            Cutter(ch.grid, ch.tool).cut_moves(moves, record_changes=False)
            ch._remember_lines(moves, np.arange(1, len(moves) + 1))
            ch.assess_model()  # warm-up (JIT cache load, bins)
            walls, cpus = [], []
            for _ in range(3):
                t0, c0 = time.perf_counter(), time.process_time()
                found = ch.assess_model()
                walls.append(time.perf_counter() - t0)
                cpus.append(time.process_time() - c0)
            emit(case=f"assess_model/{part}/{spec}", rays=frame.n_rays, spacing=round(spacing, 5),
                 tol_gouge=tol.gouge, tol_undercut=tol.undercut, design_cast_s=round(t_design, 3),
                 seconds=round(min(walls), 3), cpu_s=round(min(cpus), 3),
                 gouges=sum(f.kind == "gouge" for f in found), undercuts=sum(f.kind == "undercut" for f in found),
                 target_s=1.0)


def incremental(shared: Path):
    """Cut-only and cut-and-check run in lock-step, batch by batch, on two copies of the
    stock, so that both see the same machine load; CPU time of this process (the
    kernels are single-threaded) is what the added percentage compares."""
    moves = load_program(shared / "bench/wavy_finish.nc").moves
    frame = Frame.top(0, 0, 100, 100, 0.1)
    tool = parse_tool_spec("ball:6")
    batch = 50  # moves per call, as the live session feeds them
    configs = (("default", {}), ("depth_of_cut", {"max_depth_of_cut": 5.0}),
               ("limits", {"limits": {"X": (-10, 110), "Y": (-10, 110), "Z": (-10, 60)}}))
    # warm-up every path on a small copy
    for _, kw in configs:
        Checker(box_grid(frame, (0, 0, 0), (100, 100, 20)), tool, **kw).cut_and_check(moves[:200])
    for label, kw in configs:
        cutter = Cutter(box_grid(frame, (0, 0, 0), (100, 100, 20)), tool)
        ch = Checker(box_grid(frame, (0, 0, 0), (100, 100, 20)), tool, **kw)
        t_cut = t_chk = c_cut = c_chk = 0.0
        for a in range(0, len(moves), batch):
            part = moves[a:a + batch]
            ids = np.arange(a + 1, a + len(part) + 1)
            t0, c0 = time.perf_counter(), time.process_time()
            cutter.cut_moves(part, move_ids=ids)
            t1, c1 = time.perf_counter(), time.process_time()
            ch.cut_and_check(part, move_ids=ids)
            t2, c2 = time.perf_counter(), time.process_time()
            t_cut += t1 - t0
            t_chk += t2 - t1
            c_cut += c1 - c0
            c_chk += c2 - c1
        emit(case=f"incremental/wavy_finish/{label}", moves=len(moves), batch=batch,
             cut_s=round(t_cut, 3), cut_and_check_s=round(t_chk, 3),
             cut_cpu_s=round(c_cut, 3), cut_and_check_cpu_s=round(c_chk, 3),
             added_pct=round(100.0 * (c_chk - c_cut) / c_cut, 1),
             added_pct_wall=round(100.0 * (t_chk - t_cut) / t_cut, 1),
             us_per_move=round(1e6 * (c_chk - c_cut) / len(moves), 2), target_pct=25.0,
             findings=len(ch.all_findings()))


def main():
    shared = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT.parent / "shared"
    if not shared.is_dir():
        print(json.dumps({"case": "skipped", "reason": f"{shared} not found"}))
        return
    whole_model(shared)
    incremental(shared)


if __name__ == "__main__":
    main()
