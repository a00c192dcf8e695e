"""Blasquez & Poiraudeau's tables 1-2 on our data: the cost of recording traces.

    python bench/trace_bench.py [--program PATH] [--resolution 0.1] [--limit N]

For wavy_finish (6 mm ball, box 0,0,0,100,100,20) at 0.1 mm, one stage per move, prints
JSON lines: plain simulation time (one batch, and move by move), the extra time to
record the z-trace and time-trace, trace bytes vs model bytes (serialised and in memory),
the time to rebuild stages 1/4, 1/2, 3/4 and the end from each trace, and the live-view
frames per second on the 1M-ray grid. Targets: <= 20 % extra time, <= 5x the model's
bytes, <= 20 ms per rebuilt stage, >= 10 frames/s.
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


def emit(**kw):
    print(json.dumps(kw), flush=True)


def best_of(fn, n=5):
    t = []
    out = None
    for _ in range(n):
        t0 = time.perf_counter()
        out = fn()
        t.append(time.perf_counter() - t0)
    return min(t), out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--program", default=str(SHARED / "bench" / "wavy_finish.nc"))
    ap.add_argument("--resolution", type=float, default=0.1)
    ap.add_argument("--limit", type=int, default=0, help="only the first N moves (0 = all)")
    args = ap.parse_args(argv)
    if not Path(args.program).is_file():
        emit(case="trace", skipped=f"no program at {args.program}")
        return 0

    from monitor.commands.simulate import build_stock
    from monitor.render.live import LiveView
    from sim.cut import Cutter
    from sim.gcode import load_program
    from sim.tools import parse_tool_spec
    from sim.trace import TimeTrace, ZTrace, changed_rays_of, same_model

    moves = load_program(args.program).moves
    if args.limit:
        moves = moves[:args.limit]
    tool = parse_tool_spec("ball:6")
    stock = "box:0,0,0,100,100,20"
    n = len(moves)
    ids = np.arange(1, n + 1)

    # warm the JIT on a small piece
    g = build_stock(stock, args.resolution)
    Cutter(g, tool).cut_moves(moves[:50], move_ids=ids[:50])
    ZTrace(g).record(g, np.arange(10), 1)
    TimeTrace(g).record(g, np.arange(10), 1)

    g = build_stock(stock, args.resolution)
    model_bytes = g.nbytes()
    t0 = time.perf_counter()
    Cutter(g, tool).cut_moves(moves, move_ids=ids, record_changes=False)
    t_batch = time.perf_counter() - t0
    final_ref = g

    # move by move, no trace (the same loop the traced run does)
    g = build_stock(stock, args.resolution)
    cut = Cutter(g, tool)
    t0 = time.perf_counter()
    for k in range(n):
        cut.cut_moves(moves[k:k + 1], move_ids=ids[k:k + 1])
    t_plain = time.perf_counter() - t0

    # move by move with both traces; the trace time is measured around record()
    g = build_stock(stock, args.resolution)
    cut = Cutter(g, tool)
    z, t = ZTrace(g), TimeTrace(g)
    t_z = t_t = 0.0
    quarter = {}
    marks = {n // 4: "1/4", n // 2: "1/2", 3 * n // 4: "3/4"}
    t0 = time.perf_counter()
    for k in range(n):
        res = cut.cut_moves(moves[k:k + 1], move_ids=ids[k:k + 1])
        rays = changed_rays_of(res)
        a = time.perf_counter()
        z.record(g, rays, k + 1)
        b = time.perf_counter()
        t.record(g, rays, k + 1)
        t_t += time.perf_counter() - b
        t_z += b - a
        if k + 1 in marks:
            quarter[k + 1] = g.copy()
    t_traced = time.perf_counter() - t0
    quarter[n] = g.copy()
    assert same_model(g, final_ref, ids=False)

    z_arr = {**z.header_arrays(), **z.chunk_since(None)}
    t_arr = {**t.header_arrays(), **t.chunk_since(None)}
    z_ser = sum(v.nbytes for v in z_arr.values())
    t_ser = sum(v.nbytes for v in t_arr.values())
    emit(case="trace_record", program=Path(args.program).name, moves=n, rays=g.frame.n_rays,
         resolution=args.resolution, plain_batch_s=round(t_batch, 3), plain_per_move_s=round(t_plain, 3),
         traced_per_move_s=round(t_traced, 3), z_record_s=round(t_z, 3), t_record_s=round(t_t, 3),
         z_extra_pct=round(100 * t_z / t_plain, 1), t_extra_pct=round(100 * t_t / t_plain, 1),
         z_changes=z.n_changes, t_changes=t.n_changes, target_extra_pct=20)
    emit(case="trace_bytes", model_bytes=model_bytes,
         z_serialised_bytes=z_ser, z_vs_model=round(z_ser / model_bytes, 2),
         t_serialised_bytes=t_ser, t_vs_model=round(t_ser / model_bytes, 2),
         z_memory_bytes=z.nbytes(), t_memory_bytes=t.nbytes(),
         z_keyframe_bytes=z.keyframe_nbytes(), z_keyframes=len(z._keyframes), t_keyframes=len(t._keyframes),
         target_vs_model=5)
    for stage, label in list(marks.items()) + [(n, "end")]:
        tz, grid = best_of(lambda: z.grid_at(stage), 3)
        tt, h = best_of(lambda: t.heights_at(stage), 5)
        ok = same_model(grid, quarter[stage]) and np.array_equal(h, quarter[stage].top(), equal_nan=True)
        emit(case="trace_rebuild", stage=label, stage_n=stage, z_rebuild_ms=round(1e3 * tz, 2),
             t_rebuild_ms=round(1e3 * tt, 2), equal=bool(ok), target_ms=20)
    # animation through the time-trace, and the live view frame rate
    t0 = time.perf_counter()
    frames = sum(1 for _ in t.frames(0, n, step=max(1, n // 200)))
    emit(case="trace_animation", frames=frames, seconds=round(time.perf_counter() - t0, 3))
    import tempfile
    view = LiveView(g.frame, tool=tool, out_dir=tempfile.mkdtemp(prefix="dexmon-bench-"), max_size=None)
    h = g.top()
    path = np.asarray(moves["end"][:200, :3], np.float64)
    view.render(h, (50, 50, 10), path, [{"position": [20, 20, 10]}])
    reps = 30
    t0 = time.perf_counter()
    for k in range(reps):
        view.render(h, (50 + 0.1 * k, 50, 10), path, [{"position": [20, 20, 10]}])
    fps = reps / (time.perf_counter() - t0)
    emit(case="live_view", rays=g.frame.n_rays, picture=list(view.last_image.shape[:2]) if view.last_image is not None
         else [g.frame.nv, g.frame.nu], fps=round(fps, 1), target_fps=10)
    return 0


if __name__ == "__main__":
    sys.exit(main())
