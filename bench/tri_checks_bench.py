"""The checks on a tri-dexel model beside the checks on one Z grid, same program, same
process (:class:`sim.checks.Checker` on a :class:`sim.tridexel.TriDexel` vs a DexelGrid).

Programs (generated here, no files), with a shank and a holder (probed on every row that
can reach the stock) and a design box for the gouge map:

* ``3axis``: a 6 mm flat end mill clearing a 40 x 30 mm pocket 6 mm deep in 2 mm steps
  (a raster of 1 mm moves, 4 mm stepover) in a 60 x 40 x 20 block; the design is the
  block below Z15, so the last step gouges it 1 mm, and the first row is a rapid down
  into the stock; then the whole-model assessment.
* ``5axis``: the same raster on a head-head (xyzbc-head) with the tool tilting
  B = 15 sin(x / 6) degrees along each move.

One JSON line per program: ``z_s`` / ``tri_s`` the seconds of ``check_program`` plus
``assess_model`` (medians), ``ratio`` = tri / Z, the median of interleaved pairs, with
``os.getloadavg()`` and the findings each found::

    python bench/tri_checks_bench.py [--repeat 3] [--spacing 0.25] [--only z]

``--only z`` times the Z grid alone (``z_s``), to compare two checkouts of the code.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sim.checks import Checker  # noqa: E402
from sim.frame import Frame  # noqa: E402
from sim.gcode.moves import MoveKind, empty_moves  # noqa: E402
from sim.kinematics import HeadHead  # noqa: E402
from sim.solids import box_grid  # noqa: E402
from sim.tools import parse_tool_spec  # noqa: E402

LO, HI = (0.0, 0.0, 0.0), (60.0, 40.0, 20.0)
TOOL = "flat:6:L=12:S=6:SL=10:H=30:HL=20"


def raster(tilt: bool) -> np.ndarray:
    """Machine poses (n, 6) of the pocket raster (see the module docstring)."""
    poses = [(10.0, 5.0, 30.0, 0, 0, 0)]
    for z in (18.0, 16.0, 14.0):
        for k, y in enumerate(np.arange(8.0, 33.0, 4.0)):
            xs = np.arange(13.0, 47.01, 1.0)
            for x in (xs if k % 2 == 0 else xs[::-1]):
                b = 15.0 * math.sin(x / 6.0) if tilt else 0.0
                poses.append((x, y, z, 0.0, b, 0.0))
    poses.append((10.0, 5.0, 30.0, 0, 0, 0))
    return np.array(poses)


def moves_of(poses: np.ndarray) -> np.ndarray:
    m = empty_moves(len(poses) - 1)
    m["line"] = np.arange(1, len(poses))
    m["kind"] = MoveKind.FEED
    m["kind"][0] = m["kind"][-1] = MoveKind.RAPID
    m["start"], m["end"] = poses[:-1], poses[1:]
    m["spindle"], m["spindle_dir"], m["feed"], m["tool"] = 12000.0, 1, 1000.0, 1
    return m


def design():
    """The block below Z15 (the raster's last step, to Z14, gouges it)."""
    return trimesh.creation.box(bounds=[LO, (60.0, 40.0, 15.0)])


def model(kind: str, spacing: float):
    if kind == "z":
        return box_grid(Frame.top(LO[0], LO[1], HI[0], HI[1], spacing), LO, HI)
    from sim.tridexel import TriDexel

    return TriDexel.build(LO, HI, spacing, lambda f: box_grid(f, LO, HI))


def run(kind: str, moves, kin, spacing: float) -> tuple[float, list]:
    stock = model(kind, spacing)
    ch = Checker(stock, parse_tool_spec(TOOL), design=design(), kinematics=kin)
    t0 = time.perf_counter()
    ch.check_program(moves)
    found = ch.all_findings() + ch.assess_model(undercut=False)
    return time.perf_counter() - t0, sorted({(f.kind, f.line) for f in found})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--spacing", type=float, default=0.25)
    ap.add_argument("--only", choices=("z",), default=None)
    args = ap.parse_args()
    for name, tilt in (("3axis", False), ("5axis", True)):
        moves = moves_of(raster(tilt))
        kin = HeadHead("B") if tilt else None
        kinds = ("z",) if args.only else ("z", "tri")
        for k in kinds:  # compile and warm up
            run(k, moves, kin, args.spacing)
        times = {k: [] for k in kinds}
        found = {}
        for _ in range(args.repeat):
            for k in kinds:
                t, found[k] = run(k, moves, kin, args.spacing)
                times[k].append(t)
        row = {"bench": "tri_checks", "program": name, "moves": int(len(moves)), "spacing": args.spacing,
               "z_s": round(statistics.median(times["z"]), 4), "loadavg": [round(v, 2) for v in os.getloadavg()],
               "z_found": found["z"]}
        if not args.only:
            row["tri_s"] = round(statistics.median(times["tri"]), 4)
            row["ratio"] = round(statistics.median([t / z for t, z in zip(times["tri"], times["z"])]), 2)
            row["tri_found"] = found["tri"]
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
