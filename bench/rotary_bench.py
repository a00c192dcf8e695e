"""Instances of motion per second: a 4-axis and a 5-axis finishing-like program cut by the
rotary Cutter (``Cutter(..., kinematics=...)``, :mod:`sim.cut`).

Programs (generated here, no files):

* ``4axis``: a 3 mm ball finishing a 30 mm bar on an A axis (xyza): 20 passes 1 mm
  apart along X, each a full A turn in 36 moves of 10 degrees at the finished radius
  (14.5 mm) -- what CAM posts for a wrapped finishing pass.
* ``5axis``: a 6 mm ball on a head-head (xyzbc-head, pivot 100 mm) rastering a 24 x 24 mm
  box top 0.5 mm deep, the tool tilting B = 20 sin(x / 8) degrees along each 1 mm move,
  lines 1 mm apart.

Each row: moves, instances of motion (the poses the kernel cut), seconds to plan them
(kinematics, Python) and to cut them (kernel), instances per second, and beside it the
same X Y Z path cut as 3 axes (the exact sweep, A B C ignored) in the same process:
``ratio`` = rotary seconds / 3-axis seconds, median of interleaved pairs (what turning
costs over the closed-form sweep: every instance intersects every ray under the tool
with every segment of its profile). One JSON line per program, with ``os.getloadavg()``::

    python bench/rotary_bench.py [--repeat 3] [--threads 1]
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

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sim.cut import Cutter  # noqa: E402
from sim.frame import Frame  # noqa: E402
from sim.gcode.moves import MoveKind, empty_moves  # noqa: E402
from sim.kinematics import FourthAxis, HeadHead  # noqa: E402
from sim.solids import box_grid, cylinder_grid  # noqa: E402
from sim.tools import parse_tool_spec  # noqa: E402

SPACING = 0.2


def _rows(poses: np.ndarray) -> np.ndarray:
    m = empty_moves(len(poses) - 1)
    m["kind"] = MoveKind.FEED
    m["start"] = poses[:-1]
    m["end"] = poses[1:]
    m["feed"] = 1000.0
    m["tool"] = 1
    return m


def four_axis():
    """(name, kinematics, tool, fresh grid function, moves) of the wrapped finishing pass."""
    poses = []
    for p in range(20):
        x = 15.0 + p
        for k in range(37):
            poses.append([x, 0.0, 14.5, 360.0 * p + 10.0 * k, 0.0, 0.0])
    frame = Frame.top(-5, -17, 65, 17, SPACING)
    stock = cylinder_grid(frame, (0, 0, 0), (1, 0, 0), 15.0, 60.0)
    return "4axis", FourthAxis("A"), parse_tool_spec("ball:3:L=10"), stock, _rows(np.array(poses))


def five_axis():
    """The tilting raster on a head-head machine."""
    kin = HeadHead("B", pivot_length=100.0)
    tips, rot = [], []
    for j, y in enumerate(np.arange(0.0, 24.001, 1.0)):
        xs = np.arange(0.0, 24.001, 1.0)
        if j % 2:
            xs = xs[::-1]
        for x in xs:
            tips.append([x, y, -0.5])
            rot.append([0.0, 20.0 * math.sin(x / 8.0), 0.0])
    rot = np.array(rot)
    poses = np.zeros((len(tips), 6))
    poses[:, 3:] = rot
    poses[:, :3] = kin.machine_xyz(np.array(tips), rot, 0.0)
    frame = Frame.top(-8, -8, 32, 32, SPACING)
    stock = box_grid(frame, (-5, -5, -10), (29, 29, 0))
    return "5axis", kin, parse_tool_spec("ball:6:L=20"), stock, _rows(poses)


def instance_count(cutter: Cutter, moves: np.ndarray) -> int:
    """Poses the rotary cutter plans for ``moves`` (the kernel's work)."""
    work = cutter._plan(moves, np.arange(len(moves)), np.arange(1, len(moves) + 1, dtype=np.int32),
                        cutter.tool, np.zeros(len(moves), bool))
    return int(sum(len(t) for t in work.pose_tip))


def measure(case, repeat: int, threads: int) -> dict:
    name, kin, tool, stock, moves = case
    rotary = Cutter(stock.copy(), tool, kinematics=kin, threads=threads)
    count = instance_count(rotary, moves)
    rotary.cut_moves(moves[:4], record_changes=False)  # compile
    Cutter(stock.copy(), tool, threads=threads).cut_moves(moves[:4], record_changes=False)
    plan_s, rot_s, flat_s, ratios = [], [], [], []
    for _ in range(repeat):
        c = Cutter(stock.copy(), tool, kinematics=kin, threads=threads)
        t0 = time.perf_counter()
        instance_count(c, moves)
        plan_s.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        c.cut_moves(moves, record_changes=False)
        rot_s.append(time.perf_counter() - t0)
        c3 = Cutter(stock.copy(), tool, threads=threads)
        t0 = time.perf_counter()
        c3.cut_moves(moves, record_changes=False)
        flat_s.append(time.perf_counter() - t0)
        ratios.append(rot_s[-1] / flat_s[-1])
    rot = statistics.median(rot_s)
    return {"bench": "rotary", "program": name, "kinematics": kin.name, "tool": tool.kind,
            "moves": int(len(moves)), "instances": count, "spacing_mm": SPACING,
            "plan_s": round(statistics.median(plan_s), 4), "cut_s": round(rot, 4),
            "instances_per_s": round(count / rot), "moves_per_s": round(len(moves) / rot, 1),
            "three_axis_s": round(statistics.median(flat_s), 4), "ratio": round(statistics.median(ratios), 2),
            "threads": threads, "repeat": repeat, "loadavg": [round(v, 2) for v in os.getloadavg()]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    for case in (four_axis(), five_axis()):
        print(json.dumps(measure(case, args.repeat, args.threads)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
