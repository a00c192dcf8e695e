"""How long ``dexmon`` takes to start: help, a failing command, a 10-line simulation.

Each case runs as its own process (the installed ``dexmon`` beside this Python). *Warm*
is the median of ``--repeat`` runs with the numba cache in place; *cold* is one run with
``NUMBA_CACHE_DIR`` pointed at an empty folder, as on a machine that never ran dexmon
(the kernels compile). Prints one JSON line per case::

    python bench/startup_bench.py [--repeat 5] [--no-cold]

Target (issue 12): warm ``simulate`` of a 10-line program under 2 s on a 2-core machine;
``--help`` and argument errors well under a second.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TEN_LINES = "G21 G90\nG0 Z5\nG0 X0 Y0\nM3 S10000\nG1 Z-1 F100\nG1 X10 F300\nG1 Y10\nG1 X0\nG0 Z5\nM2\n"


def dexmon() -> list[str]:
    exe = Path(sys.executable).with_name("dexmon")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "monitor.cli"]


def timed(argv: list[str], env: dict | None = None) -> tuple[float, int]:
    t0 = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, env=env, timeout=600)
    return time.perf_counter() - t0, proc.returncode


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--no-cold", action="store_true", help="skip the cold runs (each compiles the kernels)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        prog = Path(tmp, "ten.nc")
        prog.write_text(TEN_LINES)
        cases = {
            "help": ["--help"],
            "failing_command": ["simulate", str(Path(tmp, "missing.nc")), "--stock", "box:0,0,0,1,1,1",
                                "--tool", "ball:6"],
            "simulate_10_lines": ["simulate", str(prog), "--stock", "box:-5,-5,-5,15,15,0",
                                  "--tool", "ball:6:L=20", "--json"],
        }
        for name, case in cases.items():
            cmd = dexmon() + case
            timed(cmd)  # fill the OS file cache and the numba cache
            runs = [timed(cmd) for _ in range(args.repeat)]
            out = {"bench": "startup", "case": name, "warm_s": round(statistics.median(t for t, _ in runs), 3),
                   "warm_min_s": round(min(t for t, _ in runs), 3), "exit": runs[0][1]}
            if not args.no_cold:
                with tempfile.TemporaryDirectory() as cache:
                    out["cold_s"] = round(timed(cmd, dict(os.environ, NUMBA_CACHE_DIR=cache))[0], 3)
            out["load_average"] = [round(v, 2) for v in os.getloadavg()]
            print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
