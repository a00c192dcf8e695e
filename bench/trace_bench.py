"""Blasquez & Poiraudeau's tables 1-2 on our data: the cost of recording traces.

    python bench/trace_bench.py [--program PATH] [--resolution 0.1] [--limit N] [--live N]

For wavy_finish (6 mm ball, box 0,0,0,100,100,20) at 0.1 mm, one stage per move, prints
JSON lines:

* ``trace_record``: plain simulation (one batch cut recording nothing) against the
  traced one (one batch cut writing straight into a ``Trace``: ``cut_moves(...,
  trace=tr)``, keyframes included), 5 of each interleaved; the extra time in per cent
  from the best of each, and the median of the side-by-side ratios. Target <= 20 %.
  ``*_sys_s``: the kernel time of each run (page faults on new memory, see
  ``fresh_memory``), which is most of what the traced runs vary by.
* ``trace_bytes``: trace bytes (serialised and in memory, keyframes apart) vs the
  model's bytes. Target <= 5x. The time-trace shares the z-trace's events (its own
  bytes are 0).
* ``trace_rebuild``: rebuilding stages 1/4, 1/2, 3/4, the end and back, into a grid (and
  heights arrays) the caller reuses, and into fresh ones. Target <= 20 ms per stage.
* ``trace_live``: the per-call cost of recording one move at a time (the live session's
  pattern: a few rows per poll), with keyframe work amortised: p50 / p99 / max ms, and
  the keyframes' bytes.
* ``live_view``: frames per second of the live view on the 1M-ray grid. Target >= 10.
* ``fresh_memory``: what writing 100 MB of fresh memory costs here, on pages the process
  freed just before and on pages left free for 3 s. A traced batch writes about 110 MB
  of new trace and keyframes where the plain one writes nothing new: on a virtual machine
  whose host takes back pages the guest leaves free (virtio-balloon free page reporting),
  that first write costs ten times more, and the traced runs vary with it.
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


def model_after(stock, tool, moves, ids, upto: int):
    """Reference model after move ``upto``: a fresh simulation of the first moves."""
    from sim.cut import Cutter

    g = stock.copy()
    Cutter(g, tool).cut_moves(moves[:upto], move_ids=ids[:upto], record_changes=False)
    return g


def fresh_memory(mb: int = 100, idle_s: float = 3.0) -> dict:
    """ms to fill ``mb`` MB of new numpy memory: right after freeing as much (pages the
    kernel hands back at once) and after ``idle_s`` s with it freed (pages a host that
    reclaims free guest memory has taken back)."""
    n = mb << 20
    out = {}
    for label, wait in (("recycled_ms", 0.0), ("after_idle_ms", idle_s)):
        a = np.empty(n, np.uint8)
        a[:] = 1
        del a
        time.sleep(wait)
        t0 = time.perf_counter()
        a = np.empty(n, np.uint8)
        a[:] = 1
        out[label] = round(1e3 * (time.perf_counter() - t0), 1)
        del a
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--program", default=str(SHARED / "bench" / "wavy_finish.nc"))
    ap.add_argument("--resolution", type=float, default=0.1)
    ap.add_argument("--limit", type=int, default=0, help="only the first N moves (0 = all)")
    ap.add_argument("--live", type=int, default=3000, help="moves recorded one at a time")
    args = ap.parse_args(argv)
    if not Path(args.program).is_file():
        emit(case="trace", skipped=f"no program at {args.program}")
        return 0

    from monitor.commands.simulate import build_stock
    from monitor.render.live import LiveView
    from sim.cut import Cutter
    from sim.gcode import load_program
    from sim.tools import parse_tool_spec
    from sim.trace import Trace, same_model

    moves = load_program(args.program).moves
    if args.limit:
        moves = moves[:args.limit]
    tool = parse_tool_spec("ball:6")
    stock = "box:0,0,0,100,100,20"
    n = len(moves)
    ids = np.arange(1, n + 1)

    # warm the JIT on a small piece
    g = build_stock(stock, args.resolution)
    tr = Trace(g)
    Cutter(g, tool).cut_moves(moves[:50], move_ids=ids[:50], record_changes=False, trace=tr)
    Cutter(g, tool).cut_moves(moves[50:60], move_ids=ids[50:60], record_changes=False)
    tr.record(g, np.arange(10), 60)
    tr.grid_at(10, out=g)
    tr.state_at(10, out=(np.empty(g.frame.n_rays, np.float32), np.empty(g.frame.n_rays, np.int32)))

    stock_grid = build_stock(stock, args.resolution)
    model_bytes = stock_grid.nbytes()
    # and the band kernels (sim.bands: large batches cut on every core)
    g = stock_grid.copy()
    Cutter(g, tool).cut_moves(moves[:2000], move_ids=ids[:2000], record_changes=False, trace=Trace(g))
    Cutter(stock_grid.copy(), tool).cut_moves(moves[:2000], move_ids=ids[:2000], record_changes=False)
    # plain and traced runs interleaved, 5 of each: the best of each, and the median of the
    # five side-by-side ratios (this machine's speed drifts between runs; a pair shares it)
    # (and the kernel time each spent on page faults: new memory, see fresh_memory)
    plain, traced, plain_sys, traced_sys = [], [], [], []
    for _ in range(5):
        g = stock_grid.copy()
        s0, t0 = os.times().system, time.perf_counter()
        Cutter(g, tool).cut_moves(moves, move_ids=ids, record_changes=False)
        plain.append(time.perf_counter() - t0)
        plain_sys.append(os.times().system - s0)
        final_ref = g
        g = stock_grid.copy()
        tr = None
        s0, t0 = os.times().system, time.perf_counter()
        tr = Trace(g)
        Cutter(g, tool).cut_moves(moves, move_ids=ids, record_changes=False, trace=tr)
        tr.maintain(None)
        traced.append(time.perf_counter() - t0)
        traced_sys.append(os.times().system - s0)
    t_plain, t_traced = min(plain), min(traced)
    assert same_model(g, final_ref, ids=False)
    emit(case="trace_record", program=Path(args.program).name, moves=n, rays=g.frame.n_rays,
         resolution=args.resolution, plain_s=round(t_plain, 3), traced_s=round(t_traced, 3),
         plain_runs_s=[round(x, 3) for x in plain], traced_runs_s=[round(x, 3) for x in traced],
         plain_sys_s=[round(x, 3) for x in plain_sys], traced_sys_s=[round(x, 3) for x in traced_sys],
         extra_pct=round(100 * (t_traced - t_plain) / t_plain, 1),
         extra_pct_pairs_median=round(100 * (float(np.median(np.array(traced) / np.array(plain))) - 1), 1),
         z_changes=tr.z.n_changes, z_far_events=tr.z._f_val.n, z_general_events=tr.z._g_ray.n,
         keyframes=len(tr.z._keyframes), threads=Cutter(g, tool).threads,
         load_avg=[round(x, 2) for x in os.getloadavg()], target_extra_pct=20)

    emit(case="fresh_memory", mb=100, **fresh_memory())

    z, t = tr.z, tr.t
    z_arr = {**z.header_arrays(), **z.chunk_since(None)}
    t_arr = {**t.header_arrays(), **t.chunk_since(None)}
    z_ser = sum(v.nbytes for v in z_arr.values())
    t_ser = sum(v.nbytes for v in t_arr.values())
    emit(case="trace_bytes", model_bytes=model_bytes,
         z_serialised_bytes=z_ser, z_vs_model=round(z_ser / model_bytes, 2),
         t_serialised_bytes=t_ser, t_vs_model=round(t_ser / model_bytes, 2),
         z_memory_bytes=z.nbytes(), t_memory_bytes=t.nbytes(),
         z_keyframe_bytes=z.keyframe_nbytes(), z_keyframes=len(z._keyframes),
         t_keyframe_bytes=t.keyframe_nbytes(), t_keyframes=len(t._keyframes),
         mirror_bytes=z._mirror.nbytes() if z._mirror is not None else 0, target_vs_model=5)

    marks = [(n // 4, "1/4"), (n // 2, "1/2"), (3 * n // 4, "3/4"), (n, "end")]
    refs = {s: model_after(stock_grid, tool, moves, ids, s) for s, _ in marks}
    out = stock_grid.copy()
    nr = g.frame.n_rays
    hbuf = (np.empty(nr, np.float32), np.empty(nr, np.int32))
    seq = marks + [(n // 2, "1/2 back"), (n // 2 + 7, "1/2 + 7"), (n // 4 - 3, "1/4 - 3 back"),
                   (n, "end"), (n - 1, "end - 1 back")]
    worst = 0.0
    for stage, label in seq:
        a = time.perf_counter()
        z.grid_at(stage, out=out)
        b = time.perf_counter()
        t.state_at(stage, out=hbuf)
        c = time.perf_counter()
        a2 = time.perf_counter()
        fresh = z.grid_at(stage)
        b2 = time.perf_counter()
        fresh_h = t.heights_at(stage)
        c2 = time.perf_counter()
        ok = True
        if stage in refs:
            ok = same_model(out, refs[stage]) and same_model(fresh, refs[stage]) \
                and np.array_equal(hbuf[0], refs[stage].top().reshape(-1), equal_nan=True) \
                and np.array_equal(fresh_h, refs[stage].top(), equal_nan=True)
        worst = max(worst, b - a, c - b)
        emit(case="trace_rebuild", stage=label, stage_n=stage, z_reuse_ms=round(1e3 * (b - a), 2),
             t_reuse_ms=round(1e3 * (c - b), 2), z_fresh_ms=round(1e3 * (b2 - a2), 2),
             t_fresh_ms=round(1e3 * (c2 - b2), 2), equal=bool(ok), target_ms=20)
    emit(case="trace_rebuild_worst", reuse_ms=round(1e3 * worst, 2), target_ms=20)
    t0 = time.perf_counter()
    frames = sum(1 for _ in t.frames(0, n, step=max(1, n // 200)))
    emit(case="trace_animation", frames=frames, seconds=round(time.perf_counter() - t0, 3))

    # the live pattern: one move cut and recorded per call (keyframes due on the way)
    m = min(args.live, n)
    if m:
        g = stock_grid.copy()
        cut = Cutter(g, tool)
        # as monitor.session does: keyframes never built in a poll, a slice per chunk written
        live = Trace(g, keyframe_every=g.frame.n_rays // 8, auto_maintain=False).ready_for_records()
        rec = np.empty(m)
        upkeep = []
        for k in range(m):
            r = cut.cut_moves(moves[k:k + 1], move_ids=ids[k:k + 1])
            a = time.perf_counter()
            live.record_cut(g, r, k + 1)
            rec[k] = time.perf_counter() - a
            if (k + 1) % 50 == 0:
                a = time.perf_counter()
                live.maintain(1 << 20)
                upkeep.append(time.perf_counter() - a)
        upkeep = np.asarray(upkeep or [0.0])
        emit(case="trace_live", calls=m, record_p50_ms=round(1e3 * float(np.median(rec)), 3),
             record_p99_ms=round(1e3 * float(np.quantile(rec, 0.99)), 3),
             record_max_ms=round(1e3 * float(rec.max()), 3), keyframes=len(live.z._keyframes),
             keyframe_bytes=live.z.keyframe_nbytes(),
             maintain_per_50_calls_max_ms=round(1e3 * float(upkeep.max()), 3),
             rays_changed_per_call=round(live.z.n_changes / m, 1))

    import tempfile
    view = LiveView(final_ref.frame, tool=tool, out_dir=tempfile.mkdtemp(prefix="dexmon-bench-"), max_size=None)
    h = final_ref.top()
    path = np.asarray(moves["end"][:200, :3], np.float64)
    view.render(h, (50, 50, 10), path, [{"position": [20, 20, 10]}])
    reps = 30
    t0 = time.perf_counter()
    for k in range(reps):
        view.render(h, (50 + 0.1 * k, 50, 10), path, [{"position": [20, 20, 10]}])
    fps = reps / (time.perf_counter() - t0)
    emit(case="live_view", rays=final_ref.frame.n_rays,
         picture=list(view.last_image.shape[:2]) if view.last_image is not None
         else [final_ref.frame.nv, final_ref.frame.nu], fps=round(fps, 1), target_fps=10)
    return 0


if __name__ == "__main__":
    sys.exit(main())
