"""G-code interpreter throughput: lines/s and peak memory on large programs.

Builds programs by repeating the body of ``../shared/bench/wavy_finish.nc`` (1,000,000
lines; simple G1 raster lines, the fast path) and ``pocket_rough.nc`` (arcs and explicit
G words), interprets each in a fresh child process and prints one JSON line per run:
``{"bench": ..., "lines": N, "seconds": s, "lines_per_s": ..., "peak_rss_mb": ..., "rows": ...}``.
Targets: >= 300,000 lines/s and <= 300 MB for the 1,000,000-line program.

``peak_rss_mb`` is ru_maxrss (MiB) of the fresh child, so it includes the interpreter's
imports (~38 MiB: Python + numpy) and the move table itself (226 bytes a row);
``numba_loaded`` says whether the run imported numba (it must not: ~170 MiB by itself).

    python bench/gcode_bench.py [--lines 1000000] [--shared ../shared]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def build(src: Path, n_lines: int, out: Path) -> int:
    lines = src.read_text().splitlines()
    body_start = next(i for i, s in enumerate(lines) if s.startswith("F") or s.startswith("G1 X"))
    head, body = lines[:body_start], [s for s in lines[body_start:] if not s.startswith(("M30", "M2", "M5"))]
    written = 0
    with out.open("w") as f:
        for s in head:
            f.write(s + "\n")
        written += len(head)
        while written < n_lines - 1:
            chunk = body[: n_lines - 1 - written]
            f.write("\n".join(chunk) + "\n")
            written += len(chunk)
        f.write("M30\n")
    return written + 1


def child(path: str, fast: bool) -> None:
    sys.path.insert(0, str(ROOT))
    from sim.gcode import load_program

    load_program(ROOT / "tests" / "data" / "gcode" / "comp_square.ngc",
                 tool_table=str(ROOT / "tests" / "data" / "gcode" / "comp.tbl"))  # warm numba caches
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    prog = load_program(path, fast=fast)
    dt = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    n = sum(1 for _ in open(path))
    print(json.dumps({"lines": n, "seconds": round(dt, 3), "lines_per_s": round(n / dt),
                      "peak_rss_mb": round(peak / 1024, 1), "rss_before_mb": round(base / 1024, 1),
                      "rows": int(len(prog.moves)), "row_bytes": prog.moves.dtype.itemsize,
                      "errors": len(prog.errors), "numba_loaded": "numba" in sys.modules}))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lines", type=int, default=1_000_000)
    ap.add_argument("--shared", default=str(ROOT.parent / "shared"))
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--slow", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.child, not args.slow)
        return 0
    bench = Path(args.shared) / "bench"
    if not (bench / "wavy_finish.nc").is_file():
        print(json.dumps({"bench": "gcode", "skipped": f"{bench}/wavy_finish.nc not found"}))
        return 0
    runs = [("wavy_finish_x_repeat", "wavy_finish.nc", args.lines, False),
            ("pocket_rough_x_repeat", "pocket_rough.nc", max(args.lines // 10, 1000), False),
            ("wavy_finish_slow_path", "wavy_finish.nc", max(args.lines // 10, 1000), True)]
    with tempfile.TemporaryDirectory() as tmp:
        for name, src, n, slow in runs:
            path = Path(tmp) / f"{name}.nc"
            build(bench / src, n, path)
            cmd = [sys.executable, __file__, "--child", str(path)] + (["--slow"] if slow else [])
            res = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
            if res.returncode != 0:
                print(json.dumps({"bench": name, "error": res.stderr.strip().splitlines()[-1:]}))
                continue
            out = json.loads(res.stdout.strip().splitlines()[-1])
            print(json.dumps({"bench": name, **out}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
