"""Link-fault benchmark of the live loop (JSON lines): the bundled example followed on the
virtual controller with seeded random faults -- dropped, garbled and non-finite replies, a
link drop of random length, a controller that comes back reset -- to count what issue 11
forbids: tracebacks, silent stops (a run that ends other than at the program's end or in
alarm), and a live model that differs from a clean run's after a gap the machine ran
through.

One line per session (its faults, how it ended, polls missed/bad/disconnected, gaps, the
largest model difference from the clean run in mm) and a summary line.

    python bench/link_fault_bench.py [--sessions 20] [--seed 1]
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import time
import traceback
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def fault_spec(rng: random.Random, seed: int) -> str:
    """Random faults: per-reply drop/garble/bad probabilities, one link drop of 0.05..5 s
    (machine time) somewhere in the first 40 s, a reset on it one time in four."""
    spec = {"drop": round(rng.uniform(0, 0.1), 3), "garble": round(rng.uniform(0, 0.1), 3),
            "bad": round(rng.uniform(0, 0.05), 3), "disconnect": round(rng.uniform(1, 40), 2),
            "disconnect_for": round(rng.uniform(0.05, 5), 2), "reset": int(rng.random() < 0.25), "seed": seed}
    return ",".join(f"{k}={v}" for k, v in spec.items())


def follow(job, moves, program, faults: str | None):
    """One session over the virtual controller (stepped: 0.1 s of machine time a poll)."""
    from drivers.virtual.faults import FaultInjector
    from monitor.commands.dry_run import virtual_controller
    from monitor.loop import run_controller
    from monitor.session import Session

    vc = virtual_controller(moves, speed=5.0, rate=50, clock="sim")
    vc.faults = FaultInjector(faults)
    s = Session(job, moves, program=program)
    vc.connect()
    try:
        run_controller(s, vc, 0.0, max_seconds=300)
    finally:
        vc.close()
    return s


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sessions", type=int, default=20)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    from monitor.commands.dry_run import EXAMPLE_JOB
    from monitor.job import load_job
    from monitor.program_moves import load_moves

    job = load_job(EXAMPLE_JOB)
    moves, program = load_moves(job)
    clean = follow(job, moves, program, None)
    clean_top = np.nan_to_num(clean.live.top())
    rng = random.Random(a.seed)
    totals = {"sessions": 0, "tracebacks": 0, "silent_stops": 0, "gaps": 0, "missed": 0, "bad": 0,
              "disconnected": 0, "model_diff_max_mm": 0.0}
    for k in range(a.sessions):
        faults = fault_spec(rng, a.seed * 1000 + k)
        t0 = time.perf_counter()
        rec = {"bench": "link_faults", "session": k, "faults": faults}
        try:
            s = follow(job, moves, program, faults)
        except Exception:  # noqa: BLE001 - counted, that is the point
            totals["tracebacks"] += 1
            rec["traceback"] = traceback.format_exc(limit=3)
        else:
            reset = any(g.get("reset") or g.get("came_back") for g in s.gaps)
            diff = None if reset else float(np.abs(np.nan_to_num(s.live.top()) - clean_top).max())
            rec.update(ended=s.end_reason, **s.counts, gaps=len(s.gaps), model_diff_mm=diff,
                       findings=sorted({(f["kind"], f["line"]) for f in s.findings}))
            totals["silent_stops"] += s.end_reason not in ("program end", "alarm")
            totals["gaps"] += len(s.gaps)
            for key in ("missed", "bad", "disconnected"):
                totals[key] += s.counts[key]
            if diff is not None:
                totals["model_diff_max_mm"] = max(totals["model_diff_max_mm"], diff)
        totals["sessions"] += 1
        rec["seconds"] = round(time.perf_counter() - t0, 2)
        print(json.dumps(rec), flush=True)
    print(json.dumps({"bench": "link_faults_summary", **totals}), flush=True)


if __name__ == "__main__":
    main()
