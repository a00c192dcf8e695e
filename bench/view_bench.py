"""Live view on a 1M-ray grid: frames per second and what drawing costs the session loop.

    python bench/view_bench.py [--rays-side 1000] [--seconds 3]

Prints JSON lines:

* ``render``: LiveView.render (shading + tool + path + findings) frames/s;
* ``frames_png``: the same written as PNG (``--frames``) frames/s;
* ``window_agg``: the picture pushed through a matplotlib figure (set_data + a full Agg
  draw, what a window redraw costs before the screen blit) frames/s;
* ``feed``: a ViewFeed at its default cap, fed by a loop thread that posts the rays a
  step changed; frames/s reached and the loop's step latency (p50/p99/max ms) with the
  feed drawing, against the same loop without it.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time

import numpy as np


def emit(**kw) -> None:
    print(json.dumps(kw), flush=True)


def make_grid(side: int):
    from sim.frame import Frame
    from sim.grid import DexelGrid

    sp = 0.1
    f = Frame.top(0.0, 0.0, (side - 1) * sp, (side - 1) * sp, sp)
    x = np.arange(f.nu) * sp
    y = np.arange(f.nv) * sp
    top = 10.0 - 0.5 * np.sin(x[None, :] / 7.0) * np.cos(y[:, None] / 5.0)  # some relief to shade
    return DexelGrid.from_intervals(f, np.zeros(f.shape), top)


def cut_ball(grid, cx, cy, cz, r, move_id) -> np.ndarray:
    """Remove a ball at (cx, cy, cz) and the column above it; return the flat rays changed."""
    f = grid.frame
    sp = f.spacing
    i0, i1 = max(int((cx - r) / sp), 0), min(int((cx + r) / sp) + 2, f.nu)
    j0, j1 = max(int((cy - r) / sp), 0), min(int((cy + r) / sp) + 2, f.nv)
    rays = []
    for j in range(j0, j1):
        for i in range(i0, i1):
            d2 = (i * sp - cx) ** 2 + (j * sp - cy) ** 2
            if d2 < r * r:
                grid.subtract(i, j, cz - np.sqrt(r * r - d2), 1e3, move_id)
                rays.append(j * f.nu + i)
    return np.asarray(rays, np.int64)


def percentiles(ms: list[float]) -> dict:
    a = np.asarray(ms)
    return {"p50_ms": round(float(np.percentile(a, 50)), 3), "p99_ms": round(float(np.percentile(a, 99)), 3),
            "max_ms": round(float(a.max()), 3)}


def loop_latency(grid, feed, seconds: float, period: float = 0.02) -> tuple[list[float], int]:
    """A stand-in for the session loop: every ``period`` s one step (a small cut, its rays'
    tops, a post). Returns the step times (ms) and the number of steps."""
    from monitor.render.feed import tops_of

    times = []
    t_end = time.monotonic() + seconds
    k = 0
    next_t = time.monotonic()
    while time.monotonic() < t_end:
        t0 = time.perf_counter()
        x = 10 + (k * 0.3) % 80
        rays = cut_ball(grid, x, 50.0, 9.0, 1.5, k + 1)
        tops = tops_of(grid, rays)
        if feed is not None:
            feed.post(rays, tops, tip=np.array([x, 50.0, 9.0]), progress=None, findings=())
        times.append((time.perf_counter() - t0) * 1e3)
        k += 1
        next_t += period
        time.sleep(max(next_t - time.monotonic(), 0.0))  # pacing the stand-in loop
    return times, k


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rays-side", type=int, default=1000)
    ap.add_argument("--seconds", type=float, default=3.0)
    args = ap.parse_args(argv)

    from monitor.render.feed import ViewFeed
    from monitor.render.live import LiveView

    g = make_grid(args.rays_side)
    n = g.frame.n_rays
    h = g.top()
    path = np.array([[20.0 + 0.5 * k, 50 + 20 * np.sin(k / 10), 9.0] for k in range(120)])
    findings = [{"kind": "gouge", "line": 22, "position": [60.0, 60.0, 9.0]},
                {"kind": "rapid_into_stock", "line": 5, "position": [30.0, 70.0, 9.0]}]
    out = tempfile.mkdtemp(prefix="dexmon-view-bench-")
    view = LiveView(g.frame, tool=3.0, out_dir=out)
    view.render(h, (50, 50, 9.0), path, findings)  # compile
    reps = 30
    t0 = time.perf_counter()
    for k in range(reps):
        img = view.render(h, (50 + 0.1 * k, 50, 9.0), path, findings)
    dt = (time.perf_counter() - t0) / reps
    emit(case="render_full", rays=n, picture=list(img.shape[:2]), ms=round(dt * 1e3, 2), fps=round(1 / dt, 1),
         target_fps=10)
    # what the feed does: only the rays a few states cut (a 6 mm tool moving 2 mm) shaded again
    sp = g.frame.spacing
    box = (int(47 / sp), int(53 / sp), int(47 / sp), int(55 / sp))
    t0 = time.perf_counter()
    for k in range(reps):
        img = view.render(h, (50 + 0.1 * k, 50, 9.0), path, findings, changed=box)
    dt = (time.perf_counter() - t0) / reps
    emit(case="render_changed", rays=n, changed_rays=(box[1] - box[0]) * (box[3] - box[2]),
         ms=round(dt * 1e3, 2), fps=round(1 / dt, 1), target_fps=10)
    t0 = time.perf_counter()
    for k in range(10):
        view.update(h, (50 + 0.1 * k, 50, 9.0), path, findings)
    dt = (time.perf_counter() - t0) / 10
    emit(case="frames_png", rays=n, ms=round(dt * 1e3, 2), fps=round(1 / dt, 1), target_fps=10)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from monitor.render.live import WINDOW_MAX_SIZE

    # the window's striding and no enlarging (matplotlib scales the picture to the window)
    wview = LiveView(g.frame, tool=3.0, out_dir=out, max_size=WINDOW_MAX_SIZE, min_size=0)
    wimg = wview.render(h, (50, 50, 9.0), path, findings)
    fig, ax = plt.subplots(figsize=(8, 8), dpi=100)
    ax.set_axis_off()
    im = ax.imshow(wimg, interpolation="nearest")
    fig.canvas.draw()
    t0 = time.perf_counter()
    for k in range(10):
        im.set_data(wview.render(h, (50 + 0.1 * k, 50, 9.0), path, findings, changed=box))
        fig.canvas.draw()
    dt = (time.perf_counter() - t0) / 10
    plt.close(fig)
    emit(case="window_agg", rays=n, picture=list(wimg.shape[:2]), figure_px=[800, 800], ms=round(dt * 1e3, 2),
         fps=round(1 / dt, 1), target_fps=10)

    # the loop's step latency, without and with a feed drawing PNG frames beside it, with
    # the GIL switch interval the CLI sets during a run
    from monitor.commands.live import REALTIME_SWITCH_S

    sys.setswitchinterval(REALTIME_SWITCH_S)
    cut_ball(g, 5.0, 5.0, 9.0, 1.5, 1)
    emit(case="load", loadavg_1min=round(__import__("os").getloadavg()[0], 2), cpus=__import__("os").cpu_count())
    base, steps0 = loop_latency(g, None, args.seconds)
    emit(case="loop_alone", steps=steps0, **percentiles(base))
    for fps in (10.0, 15.0):
        feed = ViewFeed(LiveView(g.frame, tool=3.0, out_dir=tempfile.mkdtemp(prefix="dexmon-view-bench-")),
                        g.top(), fps=fps).start()
        t0 = time.monotonic()
        with_feed, steps = loop_latency(g, feed, args.seconds)
        feed.close()
        wall = time.monotonic() - t0
        emit(case="loop_with_feed_png", fps_cap=fps, frames=feed.frames, fps=round(feed.frames / wall, 1),
             frame_ms=round(1e3 * float(np.median(feed.frame_seconds)), 2), steps=steps, **percentiles(with_feed))
    return 0


if __name__ == "__main__":
    sys.exit(main())
