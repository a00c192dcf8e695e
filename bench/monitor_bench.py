"""Monitor benchmarks (JSON lines).

1. live-loop latency per MachineState (p50, p99, max; ms) at 50 Hz with a 5 s horizon on
   ../shared/bench/wavy_finish.nc at 0.1 mm (stock box 0..100 x 0..100 x 0..20, ball 6 mm),
   the states coming from the virtual machine stepped in simulated time (clock=sim), so
   the figure is the session's own work per state;
2. dry-run speed: the bundled example at full speed (simulated s per wall s, the session
   processing every state of a 50 Hz poll as fast as it can).

    python bench/monitor_bench.py [--resolution 0.1] [--seconds 60]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
SHARED = Path(os.environ.get("DEXMON_SHARED", ROOT.parent / "shared"))


def latency(resolution: float, seconds: float) -> dict:
    from monitor.commands.dry_run import virtual_controller
    from monitor.job import Job, Solid, ToolDef
    from monitor.session import Session, load_moves

    program = SHARED / "bench" / "wavy_finish.nc"
    if not program.is_file():
        return {"bench": "live_latency", "skipped": f"{program} not found"}
    job = Job(program=program, stock=Solid("box", box=(0, 0, 0, 100, 100, 20)),
              default_tool=ToolDef(0, "ball:6:L=20"), resolution=resolution, horizon_s=5.0, poll_hz=50)
    moves, _ = load_moves(job)
    t0 = time.perf_counter()
    session = Session(job, moves)
    setup = time.perf_counter() - t0
    vc = virtual_controller(moves, speed=1.0, rate=50, clock="sim")
    vc.connect()
    lat = []
    for _ in range(int(seconds * 50)):
        st = vc.poll()
        lat.append(session.step(st).seconds)
        if vc.done:
            break
    vc.close()
    lat = np.array(lat[1:]) * 1e3  # the first state anchors the model (one-off)
    return {"bench": "live_latency", "program": program.name, "resolution_mm": resolution, "poll_hz": 50,
            "horizon_s": 5.0, "rays": int(session.live.frame.n_rays), "states": int(lat.size),
            "p50_ms": round(float(np.percentile(lat, 50)), 3), "p99_ms": round(float(np.percentile(lat, 99)), 3),
            "max_ms": round(float(lat.max()), 3), "setup_s": round(setup, 3),
            "target_p99_ms": 10.0, "ok": bool(np.percentile(lat, 99) <= 10.0)}


def dry_run_speed() -> dict:
    from monitor.commands.dry_run import EXAMPLE_JOB, virtual_controller
    from monitor.job import load_job
    from monitor.session import Session, load_moves, run_controller

    job = load_job(EXAMPLE_JOB)
    moves, _ = load_moves(job)
    session = Session(job, moves)
    vc = virtual_controller(moves, speed=1.0, rate=job.poll_hz, clock="sim")
    vc.connect()
    t0 = time.perf_counter()
    n = run_controller(session, vc, 0.0, done=lambda: vc.done)
    wall = time.perf_counter() - t0
    vc.close()
    sim_s = n / job.poll_hz
    return {"bench": "dry_run_speed", "job": "clamp_job", "states": n, "simulated_s": round(sim_s, 2),
            "wall_s": round(wall, 3), "sim_s_per_wall_s": round(sim_s / wall, 1),
            "findings": len(session.findings)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--resolution", type=float, default=0.1)
    ap.add_argument("--seconds", type=float, default=60.0, help="simulated seconds of wavy_finish to follow")
    a = ap.parse_args()
    print(json.dumps(latency(a.resolution, a.seconds)), flush=True)
    print(json.dumps(dry_run_speed()), flush=True)


if __name__ == "__main__":
    main()
