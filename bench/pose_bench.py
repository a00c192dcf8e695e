"""The instance-of-motion ray kernel (``sim.sweep_kernels.pose_intervals``) beside the same
kernel solving every profile piece (no skip of the pieces a ray passes beside), on the
poses of the rotary benchmark's programs (bench/rotary_bench.py) and every ray under each.

Both are called on the same rays in one compiled loop, interleaved per repeat; ``ratio``
= skip-free seconds / pose_intervals seconds, median of the pairs; ``same`` says both
gave the same intervals bit for bit. One JSON line per program, with ``os.getloadavg()``::

    python bench/pose_bench.py [--repeat 5]
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

import numba as nb
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from rotary_bench import five_axis, four_axis  # noqa: E402
from sim import sweep  # noqa: E402
from sim import sweep_kernels as K  # noqa: E402
from sim.cut import Cutter  # noqa: E402


# every_piece is a copy of K.pose_intervals less its piece skip, and the copy of its
# insert-sorted/merge tail is on purpose: that tail is inline in pose_intervals (no
# kernel of sim.sweep_kernels holds it alone, nor does the split package), and
# sim.dexel_store's add/subtract_interval merge into a ray of the store, whose writes
# would then be timed too. The bench times the skip alone, so the two kernels must
# differ in it only: keep this tail the kernel's, bit for bit (``same`` turns false when
# they part). Were the tail a kernel of its own, both would call it.
@nb.njit(cache=True)
def every_piece(prof, tip, axis, px, py, out, buf):
    """pose_intervals as it was: every piece solved."""
    wx = px - tip[0]
    wy = py - tip[1]
    h0 = wx * axis[0] + wy * axis[1]
    wx2wy2 = wx * wx + wy * wy
    az = axis[2]
    m = 0
    for k in range(prof.shape[0] - 1):
        if K._piece_interval(prof, k, h0, az, wx2wy2, buf):
            lo = buf[0] + tip[2]
            hi = buf[1] + tip[2]
            q = m
            while q > 0 and out[q - 1, 0] > lo:
                out[q, 0] = out[q - 1, 0]
                out[q, 1] = out[q - 1, 1]
                q -= 1
            out[q, 0] = lo
            out[q, 1] = hi
            m += 1
    if m <= 1:
        return m
    w = 0
    for q in range(1, m):
        if out[q, 0] <= out[w, 1] + 1e-9:
            if out[q, 1] > out[w, 1]:
                out[w, 1] = out[q, 1]
        else:
            w += 1
            out[w, 0] = out[q, 0]
            out[w, 1] = out[q, 1]
    return w + 1


@nb.njit(cache=True)
def sweep_rays(which, prof, tips, axes, sp, rmax, sums):
    """Every ray within the body's reach of each pose through ``which`` (0: pose_intervals,
    1: every_piece); ``sums`` (2,) gets the count and the sum of the interval ends."""
    out = np.empty((prof.shape[0], 2))
    buf = np.empty(2)
    top = prof[prof.shape[0] - 1, 0]
    for k in range(tips.shape[0]):
        tip = tips[k]
        ax = axes[k]
        u0 = min(tip[0], tip[0] + top * ax[0]) - rmax
        u1 = max(tip[0], tip[0] + top * ax[0]) + rmax
        v0 = min(tip[1], tip[1] + top * ax[1]) - rmax
        v1 = max(tip[1], tip[1] + top * ax[1]) + rmax
        for j in range(int(math.ceil(v0 / sp)), int(math.floor(v1 / sp)) + 1):
            for i in range(int(math.ceil(u0 / sp)), int(math.floor(u1 / sp)) + 1):
                if which == 0:
                    m = K.pose_intervals(prof, tip, ax, i * sp, j * sp, out, buf)
                else:
                    m = every_piece(prof, tip, ax, i * sp, j * sp, out, buf)
                for q in range(m):
                    sums[0] += 1.0
                    sums[1] += out[q, 0] + out[q, 1]


def poses(case):
    """The program's instances (frame-local tips and axes) and the profile the cutter uses."""
    name, kin, tool, stock, moves = case
    c = Cutter(stock, tool, kinematics=kin, threads=1)
    work = c._plan(moves, np.arange(len(moves)), np.arange(1, len(moves) + 1, dtype=np.int32), tool,
                   np.zeros(len(moves), bool))
    tips, axes, _, _ = work.pose_arrays()
    f = stock.frame
    tips_l = np.ascontiguousarray(f.to_local(tips))
    axes_l = np.ascontiguousarray(np.stack([axes @ f.u, axes @ f.v, axes @ f.direction], axis=1))
    axes_l /= np.linalg.norm(axes_l, axis=1, keepdims=True)
    return name, np.ascontiguousarray(sweep.body_profile(tool)), tips_l, axes_l, f.spacing


def measure(case, repeat: int) -> dict:
    name, prof, tips, axes, sp = poses(case)
    rmax = float(prof[:, 1].max())
    sums = [np.zeros(2), np.zeros(2)]
    for w in (0, 1):  # compile
        sweep_rays(w, prof, tips[:2], axes[:2], sp, rmax, np.zeros(2))
    secs = ([], [])
    for _ in range(repeat):
        for w in (0, 1):
            sums[w][:] = 0.0
            t0 = time.perf_counter()
            sweep_rays(w, prof, tips, axes, sp, rmax, sums[w])
            secs[w].append(time.perf_counter() - t0)
    ratio = statistics.median(b / a for a, b in zip(*secs))
    return {"bench": "pose_intervals", "program": name, "instances": int(len(tips)), "pieces": int(len(prof) - 1),
            "intervals": int(sums[0][0]), "same": bool(np.array_equal(sums[0], sums[1])),
            "pose_intervals_s": round(statistics.median(secs[0]), 4),
            "every_piece_s": round(statistics.median(secs[1]), 4), "ratio": round(ratio, 2),
            "repeat": repeat, "loadavg": [round(v, 2) for v in os.getloadavg()]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    for case in (four_axis(), five_axis()):
        print(json.dumps(measure(case, args.repeat)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
