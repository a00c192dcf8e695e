"""Fuzz the G-code path with mutated real programs: no hang, no crash, no traceback.

Each input is a program of the corpus (``../shared/corpus/gcode`` and
``../shared/bench``) or a small built-in one, mutated by a seeded generator: flipped and
dropped bytes, duplicated lines, numbers replaced by extremes (``1e9``, ``-10**300``,
400 digits, full-width digits), and inserted runaways (endless ``while``, huge
``repeat``, cycles with ``L1e9`` or a tiny ``Q``, arcs with ``P1e5``, deep brackets,
long flat expressions, overlong lines). Each runs in a child process through
``interpret`` and, for a share of them, a short ``simulate`` cut, under a time limit.

Outcomes: ``ok`` (ran), ``refused`` (a one-line ``GCodeError``/``InputError``), ``hang``
(past the time limit), ``crash`` (the child died by a signal), ``traceback`` (any other
exception). Prints one JSON line per 1000 inputs and a final one with the counts and the
first examples of each bad outcome::

    python bench/gcode_fuzz.py --n 10000 --timeout 20 --seed 1
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import random
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

BUILTIN = [
    "G21 G90\nG0 Z5\nG0 X0 Y0\nM3 S10000\nG1 Z-1 F100\nG1 X10 F300\nG2 X20 Y0 I5 J0\nG1 Y10\nG0 Z5\nM2\n",
    "G21 G90 G0 Z5\n#1=0\no1 while [#1 LT 10]\nG1 X[#1] Y[#1*2] Z-1 F200\n#1=[#1+1]\no1 endwhile\n"
    "G81 X5 Y5 Z-3 R1 F100\nG80\nM2\n",
]

RUNAWAYS = [
    "o900 while [1]\nG1 X1 F100\no900 endwhile",
    "o901 repeat [1000000000]\nG1 X1 F100\no901 endrepeat",
    "G81 X1 Y1 Z-1 R1 L1000000000 F100",
    "G73 X1 Y1 Z-100 R1 Q0.000001 F100",
    "G2 X0 Y0 I5 J0 P100000 F100",
    "G1 X[-10**300] F100",
    "G1 X" + "9" * 400 + " F100",
    "G1 X\uff11\uff12 F100",
    "#1=[" + "+".join(["1"] * 5000) + "]",
    "#1=" + "[" * 3000 + "1" + "]" * 3000,
    "G1 X1 F100" + " " * 1_000_000,
    "T10000000000 M6",
    "o902 if [1]\nG1 X1 F100\no902 else",
]

EXTREMES = ["1e9", "-1e9", "[-10**300]", "9" * 40, "0.000001", "[1/3]", "-0", "\uff15", "nan", "[2**1023*2]"]


def corpus() -> list[str]:
    shared = Path(os.environ.get("DEXMON_SHARED", HERE.parent.parent / "shared"))
    texts = []
    for folder in (shared / "corpus" / "gcode", shared / "bench"):
        if folder.is_dir():
            for p in sorted(folder.iterdir()):
                if p.suffix.lower() in (".nc", ".ngc", ".gcode", ".tap") and p.stat().st_size < 2_000_000:
                    texts.append(p.read_text(errors="replace"))
    return texts or list(BUILTIN)


def mutate(text: str, rng: random.Random) -> str:
    lines = text.splitlines()[:3000] or [""]
    for _ in range(rng.randint(1, 4)):
        op = rng.random()
        k = rng.randrange(len(lines))
        if op < 0.25:
            lines.insert(k, rng.choice(RUNAWAYS))
        elif op < 0.45:
            s = lines[k]
            digits = [i for i, c in enumerate(s) if c.isdigit()]
            if digits:
                i = rng.choice(digits)
                j = i
                while j < len(s) and (s[j].isdigit() or s[j] == "."):
                    j += 1
                lines[k] = s[:i] + rng.choice(EXTREMES) + s[j:]
        elif op < 0.65:
            s = bytearray(lines[k].encode())
            if s:
                s[rng.randrange(len(s))] = rng.randrange(32, 127)
            lines[k] = s.decode(errors="replace")
        elif op < 0.8:
            lines.insert(k, lines[rng.randrange(len(lines))])
        elif op < 0.9:
            del lines[k]
        else:
            lines[k] = lines[k][: rng.randrange(len(lines[k]) + 1)]
    return "\n".join(lines) + "\n"


def _child(text: str, simulate: bool, out) -> None:
    from sim.errors import InputError
    from sim.gcode import GCodeError, interpret

    try:
        prog = interpret(text, filename="fuzz.ngc")
        if simulate and len(prog.moves):
            import numpy as np

            from sim.cut import Cutter
            from sim.grid import DexelGrid
            from sim.frame import Frame
            from sim.tools import parse_tool_spec

            ends = prog.moves["end"][:, :3]
            lo, hi = np.nanmin(ends, axis=0), np.nanmax(ends, axis=0)
            lo = np.maximum(lo, -200)
            hi = np.minimum(np.maximum(hi, lo + 1), lo + 200)
            frame = Frame.top(lo[0], lo[1], hi[0], hi[1], 1.0)
            grid = DexelGrid.from_intervals(frame, np.full(frame.shape, lo[2] - 1), np.full(frame.shape, hi[2]))
            Cutter(grid, parse_tool_spec("ball:6")).cut_moves(prog.moves[:2000], record_changes=False)
        out.put(("ok", ""))
    except (GCodeError, InputError) as exc:
        out.put(("refused", str(exc).splitlines()[0][:200]))
    except BaseException as exc:  # noqa: BLE001 - what the fuzz is looking for
        out.put(("traceback", f"{type(exc).__name__}: {exc}"[:300]))


def run_one(text: str, simulate: bool, timeout: float) -> tuple[str, str]:
    ctx = mp.get_context("fork")
    out = ctx.Queue()
    proc = ctx.Process(target=_child, args=(text, simulate, out))
    proc.start()
    proc.join(timeout)
    if proc.is_alive():
        proc.kill()
        proc.join()
        return "hang", f"past {timeout:g} s"
    if proc.exitcode and proc.exitcode < 0:
        return "crash", f"signal {-proc.exitcode}"
    try:
        return out.get(timeout=5)
    except Exception:  # noqa: BLE001 - a child that exited without a word
        return "crash", f"exit {proc.exitcode} with no result"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1000)
    ap.add_argument("--timeout", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--simulate-share", type=float, default=0.2, help="share of inputs also cut (default 0.2)")
    args = ap.parse_args(argv)
    import sim.gcode  # noqa: F401 - imported once in the parent; children fork with it

    rng = random.Random(args.seed)
    texts = corpus()
    counts = {"ok": 0, "refused": 0, "hang": 0, "crash": 0, "traceback": 0}
    examples: dict[str, list] = {}
    t0 = time.perf_counter()
    worst = 0.0
    for i in range(args.n):
        text = mutate(rng.choice(texts), rng)
        t = time.perf_counter()
        kind, what = run_one(text, rng.random() < args.simulate_share, args.timeout)
        worst = max(worst, time.perf_counter() - t)
        counts[kind] += 1
        if kind in ("hang", "crash", "traceback") and len(examples.setdefault(kind, [])) < 5:
            examples[kind].append({"input": i, "what": what, "head": text[:300]})
        if (i + 1) % 1000 == 0:
            print(json.dumps({"bench": "gcode_fuzz", "done": i + 1, **counts}), flush=True)
    print(json.dumps({"bench": "gcode_fuzz", "inputs": args.n, "seed": args.seed, "timeout_s": args.timeout,
                      **counts, "slowest_s": round(worst, 2), "seconds": round(time.perf_counter() - t0, 1),
                      "examples": examples}))
    return 0 if not (counts["hang"] or counts["crash"] or counts["traceback"]) else 1


if __name__ == "__main__":
    sys.exit(main())
