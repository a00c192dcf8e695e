"""Replay and report pictures: what they cost on the corpus parts and the bundled job.

    PYVISTA_OFF_SCREEN=true python bench/render_bench.py [--part carpet1] [--resolution 0.25] [--repeat 3]

Records the part's finishing pass into a run file straight from the simulator (as the
corpus picture tests do), then prints JSON lines:

* ``setup``: RunPictures of the run (the design cast on the cropped frame, the stock top);
* ``picture``: one top-view picture of the last stage at ``--size`` 800 and 1600 (the
  deviation of every top, shading, overlay, strip), median seconds;
* ``frames``: an animation's frames per second (``RunPictures.frames``);
* ``view3d``: one 3-D picture 800 x 800 offscreen, median seconds;
* ``report``: the whole HTML report of the bundled job's dry run, seconds.
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

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
PARTS = ROOT.parent / "shared" / "corpus" / "parts"
CORPUS = {
    "sphere_on_plate": ("sphere_on_plate_ball6_finish.ngc", "sphere_on_plate.stl",
                        (0.0, 0.0, -1.0, 76.4923, 76.4923, 30.8718)),
    "carpet1": ("carpet1_ball6_finish.ngc", "carpet1.stl", (0.0, -82.0, -10.0, 152.0, 66.0, 5.1979)),
}


def emit(**kw) -> None:
    print(json.dumps(kw), flush=True)


def timed(fn, repeat: int) -> tuple[float, object]:
    out, times = None, []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", default="carpet1", choices=sorted(CORPUS))
    ap.add_argument("--resolution", type=float, default=0.25)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
    from monitor.render import view3d
    from monitor.render.runpicture import RunPictures
    from monitor.trace_io import RunView
    from tests.monitor.run_helpers import record_program

    with tempfile.TemporaryDirectory() as tmp:
        if PARTS.is_dir():
            prog, design, stock = CORPUS[args.part]
            run = Path(tmp) / f"{args.part}.dexrun"
            t0 = time.perf_counter()
            record_program(run, PARTS / prog, PARTS / design, stock, resolution=args.resolution, stages=60)
            emit(bench="record", part=args.part, resolution_mm=args.resolution,
                 seconds=round(time.perf_counter() - t0, 2))
            with RunView(run) as view:
                last = view.last_stage
                view.state_at(last)   # the trace read once: what follows is the pictures' own cost
                sec, pics = timed(lambda: RunPictures(view, size=800), args.repeat)
                emit(bench="setup", part=args.part, rays=int(pics.frame.n_rays), seconds=round(sec, 3))
                for size in (800, 1600):
                    p = RunPictures(view, size=size)
                    sec, img = timed(lambda: p.picture(last), args.repeat)
                    emit(bench="picture", part=args.part, size=size, shape=list(img.shape[:2]),
                         seconds=round(sec, 3))
                t0 = time.perf_counter()
                n = sum(1 for _ in pics.frames(0, last, 30))
                emit(bench="frames", part=args.part, frames=n,
                     frames_per_s=round(n / (time.perf_counter() - t0), 2))
                sec, _ = timed(lambda: view3d.stage_png(pics, last, window_size=(800, 800)), args.repeat)
                emit(bench="view3d", part=args.part, size=800, seconds=round(sec, 3))
        else:
            emit(bench="corpus", skipped="../shared/corpus/parts not present")
        from monitor.cli import main as dexmon
        from monitor.commands.report import build_report

        run = Path(tmp) / "example.dexrun"
        dexmon(["dry-run", "--clock", "sim", "--speed", "20", "--quiet", "--run", str(run)])
        with RunView(run) as view:
            t0 = time.perf_counter()
            text = build_report(view)
            emit(bench="report", job="bundled example", findings=len(view.findings), html_kb=len(text) // 1024,
                 seconds=round(time.perf_counter() - t0, 2))


if __name__ == "__main__":
    main()
