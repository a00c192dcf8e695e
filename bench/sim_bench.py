"""Material-removal benchmark: one JSON line per case.

    python bench/sim_bench.py [--shared ../shared] [--case wavy_finish] [--no-check]
                              [--mode plain|record ...] [--pairs 5] [--shapes]

Cases (stock box 0,0,0,100,100,20 at 0.1 mm, 1001 x 1001 rays):

* ``wavy_finish`` - ~40k short G1 moves with a 6 mm ball end mill;
* ``pocket_rough`` - pocket roughing with arcs, 6 mm flat end mill.

Modes (one line each, field ``mode``): ``plain`` cuts with ``record_changes=False``;
``record`` keeps the changed rays and depths of cut.

Figures (best of ``--repeat`` runs, each on fresh stock): moves, seconds (wall),
cpu_seconds, moves_per_s (wall), moves_per_s_cpu,
peak_rss_mb, grid_mb, removed_mm3, and the height check against an independent
evaluation of the exact swept surface at every ray (numpy, vertical line against each
move's capsule / flat disk sweep; arcs sampled every 0.01 mm; rays within 1e-6 mm of
the swept boundary may fall either side): height_max_err_mm and rays_over_1um. The cut runs on one core (numba, no parallel loops); numba is warmed up
first so compilation is not timed.

``grid_bytes`` is everything the model keeps (:meth:`DexelGrid.nbytes`: the dense
per-ray arrays and the whole segment pool; nothing else is kept per ray) and
``bytes_per_ray`` that over the rays.

``--big`` instead times a wavy raster finish generated here (:func:`wavy_raster`: the
shape, step and stepover of ``wavy_finish.nc``, 6 mm ball) on 100 x 100 mm (1M rays)
and on 300 x 300 mm (10M rays) at 0.1 mm, in ``--pairs`` interleaved pairs, and prints
one line (``mode: big``) with the rays within reach per second of each and their ratio
(see :func:`run_big`), and the peak RSS of a fresh process that cuts the 10M case alone.

Then, per ``BASELINE_RUNS`` entry (ball and flat on ``wavy_finish``), a line with
``mode: baseline_pairs``: dexmon's plain cut and the straightforward z-map kernel of
``bench/zmap_baseline.py`` timed in ``--pairs`` interleaved pairs in this process;
``ratio_median`` (baseline seconds / dexmon seconds, median of the pairs) is the figure
to quote (see :func:`run_baseline_pairs`).

``--shapes`` prints only these lines: first ``mode: shape_pairs`` for the ball itself
(its height check), then one per ``SHAPE_RUNS`` entry (bull-nose ``bull:6:1``, vbit
``vbit:6:90``, drill ``drill:6``, all L=20) on ``wavy_finish``, each timed against the
ball in ``--pairs`` interleaved pairs of plain cuts in this process: ``ratio_median``
(shape seconds / ball seconds, median of the pairs; <= 2 means at least half the
ball's speed), ``shape_max_err_mm`` (4000 random rays against a golden-section
minimisation of the swept tool over every move within reach; rim rays within 1e-6 mm
accepted either side) and ``load_avg``. Then ``mode: reach_rate``: rays within the
cutting radius of each chord, summed, per second of plain cut, for the flat end mill
pocketing ``pocket_rough`` and the ball finishing ``wavy_finish`` (interleaved pairs,
medians; the same units, so the two are comparable).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from sim.cut import Cutter  # noqa: E402
from sim.frame import Frame  # noqa: E402
from sim.gcode import load_program  # noqa: E402
from sim.gcode.moves import MoveKind, empty_moves, tip_positions  # noqa: E402
from sim.grid import DexelGrid  # noqa: E402
from sim.sweep import PLANE_AXES, arc_points, chord_step_angle  # noqa: E402
from sim.tolerance import DEFAULT  # noqa: E402
from sim.tools import parse_tool_spec  # noqa: E402

from bench import zmap_baseline  # noqa: E402

CASES = {
    "wavy_finish": ("bench/wavy_finish.nc", "ball:6:L=20"),
    "pocket_rough": ("bench/pocket_rough.nc", "flat:6:L=25"),
}
#: (case, tool) pairs timed against the baseline z-map kernel (bench/zmap_baseline.py)
BASELINE_RUNS = (("wavy_finish", "ball:6:L=20"), ("wavy_finish", "flat:6:L=20"))
STOCK = (0.0, 0.0, 0.0, 100.0, 100.0, 20.0)
RESOLUTION = 0.1


def stock_grid() -> DexelGrid:
    x0, y0, z0, x1, y1, z1 = STOCK
    frame = Frame.top(x0, y0, x1, y1, RESOLUTION)
    return DexelGrid.from_intervals(frame, np.full(frame.shape, z0), np.full(frame.shape, z1))


def warm_up(tool, moves) -> None:
    """Compile (or load from cache) every kernel the timed run uses."""
    frame = Frame.top(0, 0, 20, 20, RESOLUTION)
    grid = DexelGrid.from_intervals(frame, np.zeros(frame.shape), np.full(frame.shape, 20.0))
    Cutter(grid, tool).cut_moves(moves[:50], record_changes=False)
    Cutter(grid, tool).cut_moves(moves[:50], record_changes=True)


# --- the independent reference ------------------------------------------------------

def _pieces(moves, chord: float | None = None):
    """Straight tip segments of every motion row; arcs sampled every 0.01 mm or, with
    ``chord``, into the chords the exact cut uses (sagitta within ``chord`` mm)."""
    kind = moves["kind"]
    s = tip_positions(moves, "start")
    e = tip_positions(moves, "end")
    p0, p1 = [], []
    for k in range(len(moves)):
        if kind[k] in (MoveKind.RAPID, MoveKind.FEED):
            p0.append(s[k])
            p1.append(e[k])
        elif kind[k] in (MoveKind.ARC_CW, MoveKind.ARC_CCW):
            c = np.array(moves["center"][k], float)
            c[2] -= moves["tool_length"][k]
            plane = int(moves["plane"][k])
            if chord is None:
                step = {"max_step_length": 0.01}
            else:
                pq = list(PLANE_AXES[plane][:2])
                radius = max(float(np.hypot(*(s[k][pq] - c[pq]))), 1e-9)
                step = {"max_step_angle": chord_step_angle(radius, chord)}
            pts = arc_points(s[k], e[k], c, plane, int(moves["turns"][k]) or 1,
                             kind[k] == MoveKind.ARC_CW, **step)
            p0.extend(pts[:-1])
            p1.extend(pts[1:])
    return np.array(p0), np.array(p1)


def reference_heights(frame: Frame, tool, moves, top: float, dr: float = 0.0) -> np.ndarray:
    """Exact top surface after all moves, float64 (nv, nu), by a different formulation.

    Ball: the lowest point of the vertical line inside the capsule (cylinder of radius R
    about the 3-D segment of ball centres plus end spheres), from the quadratic of the
    line against the infinite cylinder and the two spheres. Flat: the lowest tip height
    over the parameter range where the ray is inside the disk (a quadratic in t).
    ``dr`` grows the tool radius (to bracket rays lying on the swept boundary).
    """
    R = tool.radius + dr
    L = tool.flute_length
    H = np.full(frame.shape, top, dtype=np.float64)
    xs = frame.origin[0] + np.arange(frame.nu) * frame.spacing
    ys = frame.origin[1] + np.arange(frame.nv) * frame.spacing
    P0, P1 = _pieces(moves)
    for a, b in zip(P0, P1):
        i0 = max(0, int(math.floor((min(a[0], b[0]) - R - xs[0]) / frame.spacing)))
        i1 = min(frame.nu, int(math.ceil((max(a[0], b[0]) + R - xs[0]) / frame.spacing)) + 1)
        j0 = max(0, int(math.floor((min(a[1], b[1]) - R - ys[0]) / frame.spacing)))
        j1 = min(frame.nv, int(math.ceil((max(a[1], b[1]) + R - ys[0]) / frame.spacing)) + 1)
        if i1 <= i0 or j1 <= j0:
            continue
        X, Y = np.meshgrid(xs[i0:i1], ys[j0:j1])
        d = b - a
        if tool.kind == "ball":
            c0 = a + np.array([0, 0, R])
            z = np.full(X.shape, np.inf)
            for c in (c0, c0 + d):  # end spheres
                q = R * R - (X - c[0]) ** 2 - (Y - c[1]) ** 2
                z = np.where(q >= 0, np.minimum(z, c[2] - np.sqrt(np.maximum(q, 0))), z)
            nrm = np.linalg.norm(d)
            if nrm > 1e-12:
                D = d / nrm
                w0 = np.stack([X - c0[0], Y - c0[1], -c0[2] * np.ones_like(X)], axis=-1)
                pw = w0 - (w0 @ D)[..., None] * D      # perpendicular part at z = 0
                pe = np.array([0, 0, 1.0]) - D[2] * D  # perpendicular part of e_z
                A = pe @ pe
                if A > 1e-12:
                    B = pw @ pe
                    C = np.einsum("...k,...k", pw, pw) - R * R
                    disc = B * B - A * C
                    zr = (-B - np.sqrt(np.maximum(disc, 0))) / A
                    t = (w0 @ D) + zr * D[2]
                    ok = (disc >= 0) & (t >= 0) & (t <= nrm)
                    z = np.where(ok, np.minimum(z, zr), z)
            low = z
            touch = np.isfinite(z)
        else:  # flat
            fx, fy = X - a[0], Y - a[1]
            A = d[0] ** 2 + d[1] ** 2
            if A < 1e-18:
                touch = fx * fx + fy * fy <= R * R
                low = np.full(X.shape, min(a[2], b[2]))
            else:
                B = -(fx * d[0] + fy * d[1])
                C = fx * fx + fy * fy - R * R
                disc = B * B - A * C
                sq = np.sqrt(np.maximum(disc, 0))
                t0 = (-B - sq) / A
                t1 = (-B + sq) / A
                touch = (disc >= 0) & (t0 <= 1) & (t1 >= 0)
                t0 = np.clip(t0, 0, 1)
                t1 = np.clip(t1, 0, 1)
                low = np.minimum(a[2] + t0 * d[2], a[2] + t1 * d[2])
        # the flutes reach L above the tip; material above them stays (never here: L > 20)
        assert min(a[2], b[2]) + L >= top
        sub = H[j0:j1, i0:i1]
        H[j0:j1, i0:i1] = np.where(touch, np.minimum(sub, low), sub)
    return np.maximum(H, STOCK[2])


# --- any tool shape: a sampled reference and the reach of each chord --------------------

GOLD = (math.sqrt(5.0) - 1.0) / 2.0


def sweep_floor(tool, p0, p1, x, y, iters: int = 80) -> np.ndarray:
    """Lowest point (mm) of ``tool`` swept along straight tip moves ``p0 -> p1`` on the
    vertical rays at ``(x, y)``, float64; NaN where the move never reaches the ray.

    Shapes broadcast: ``p0``, ``p1`` (3,) or (n, 3), ``x``, ``y`` (n,). Independent of the
    kernels: the move is parametrised by ``t`` in [0, 1] along the 3-D tip segment, the
    part within reach of the ray comes from the quadratic ``|p(t) - ray| = Rc`` in XY, and
    the convex ``z(t) + tool.lowest_height(d(t))`` is minimised by golden section to the
    last bit (``iters`` steps shrink the bracket 0.618**iters; 80 reach 1e-16 of the move).
    """
    p0 = np.asarray(p0, np.float64)
    dv = np.asarray(p1, np.float64) - p0
    Rc = tool.cutting_radius
    fx, fy = x - p0[..., 0], y - p0[..., 1]
    A = dv[..., 0] ** 2 + dv[..., 1] ** 2
    level = A == 0.0  # a vertical move: every t is within reach or none
    B = -(fx * dv[..., 0] + fy * dv[..., 1])
    C = fx * fx + fy * fy - Rc * Rc
    disc = B * B - A * C
    sq = np.sqrt(np.maximum(disc, 0.0))
    A1 = np.where(level, 1.0, A)
    t0 = np.where(level, 0.0, (-B - sq) / A1)
    t1 = np.where(level, 1.0, (-B + sq) / A1)
    reach = np.where(level, C <= 0.0, (disc >= 0) & (t0 <= 1) & (t1 >= 0))
    t0, t1 = np.clip(t0, 0, 1), np.clip(t1, 0, 1)

    def f(t):
        d = np.hypot(p0[..., 0] + t * dv[..., 0] - x, p0[..., 1] + t * dv[..., 1] - y)
        return p0[..., 2] + t * dv[..., 2] + tool.lowest_height(np.minimum(d, Rc))

    lo, hi = t0, t1
    c, e = hi - GOLD * (hi - lo), lo + GOLD * (hi - lo)
    fc, fe = f(c), f(e)
    for _ in range(iters):
        left = fc < fe  # the minimum of a convex function lies in [lo, e]
        hi = np.where(left, e, hi)
        lo = np.where(left, lo, c)
        t = np.where(left, hi - GOLD * (hi - lo), lo + GOLD * (hi - lo))  # the new probe
        ft = f(t)
        c, e = np.where(left, t, e), np.where(left, c, t)
        fc, fe = np.where(left, ft, fe), np.where(left, fc, ft)
    best = np.minimum(np.minimum(f(t0), f(t1)), np.minimum(fc, fe))
    return np.where(reach, best, np.nan)


def _path_distance(P0, P1, x, y) -> np.ndarray:
    """XY distance of each ray ``(x, y)`` from the tip path ``P0 -> P1`` (broadcast)."""
    d = P1[..., :2] - P0[..., :2]
    L2 = d[..., 0] ** 2 + d[..., 1] ** 2
    fx, fy = x - P0[..., 0], y - P0[..., 1]
    t = np.clip((fx * d[..., 0] + fy * d[..., 1]) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
    return np.hypot(fx - t * d[..., 0], fy - t * d[..., 1])


def sampled_check(grid: DexelGrid, tool, moves, n_rays: int = 4000, seed: int = 15) -> dict:
    """Heights of ``n_rays`` random rays of ``grid`` (cut from fresh stock by ``moves``)
    against :func:`sweep_floor` over every move within reach (arcs sampled every 0.01 mm).

    A ray within 1e-6 mm of a move's rim may fall either side: the reference is taken
    without and with those moves. ``shape_max_err_mm``: how far the cut heights lie
    outside that bracket; ``shape_rays``: the rays checked; ``shape_rim_rays``: those
    with a rim move.
    """
    frame = grid.frame
    rng = np.random.default_rng(seed)
    rays = np.sort(rng.choice(frame.n_rays, size=min(n_rays, frame.n_rays), replace=False))
    x = frame.origin[0] + (rays % frame.nu) * frame.spacing
    y = frame.origin[1] + (rays // frame.nu) * frame.spacing
    P0, P1 = _pieces(moves)
    Rc = tool.cutting_radius
    ray_of, move_of, rim = [], [], []
    for k0 in range(0, len(P0), 2000):  # pairs (ray, move) within reach, a block at a time
        dist = _path_distance(P0[k0:k0 + 2000, None], P1[k0:k0 + 2000, None], x[None], y[None])
        km, ir = np.nonzero(dist <= Rc + 1e-6)
        ray_of.append(ir)
        move_of.append(km + k0)
        rim.append(np.abs(dist[km, ir] - Rc) < 1e-6)
    ray_of, move_of, rim = (np.concatenate(v) for v in (ray_of, move_of, rim))
    floor = sweep_floor(tool, P0[move_of], P1[move_of], x[ray_of], y[ray_of])
    floor = np.where(np.isnan(floor), STOCK[5], floor)  # a rim pair just outside the reach
    ref_in = np.full(rays.size, STOCK[5])
    ref_out = np.full(rays.size, STOCK[5])
    np.minimum.at(ref_in, ray_of[~rim], floor[~rim])
    np.minimum.at(ref_out, ray_of, floor)
    ref_in, ref_out = np.maximum(ref_in, STOCK[2]), np.maximum(ref_out, STOCK[2])
    top = np.nan_to_num(grid.top().reshape(-1)[rays].astype(np.float64), nan=STOCK[2])
    err = np.maximum(0.0, np.maximum(top - ref_in, ref_out - top))
    return {"shape_rays": int(rays.size), "shape_rim_rays": int(np.unique(ray_of[rim]).size),
            "shape_max_err_mm": float(f"{err.max():.3g}")}


def rays_in_reach(frame: Frame, tool, moves) -> int:
    """Rays within the cutting radius of each chord the exact cut sweeps, summed."""
    P0, P1 = _pieces(moves, chord=DEFAULT.chord)
    Rc = tool.cutting_radius
    sp = frame.spacing
    total = 0
    for a, b in zip(P0, P1):
        i0 = max(0, int(math.ceil((min(a[0], b[0]) - Rc - frame.origin[0]) / sp)))
        i1 = min(frame.nu - 1, int(math.floor((max(a[0], b[0]) + Rc - frame.origin[0]) / sp)))
        j0 = max(0, int(math.ceil((min(a[1], b[1]) - Rc - frame.origin[1]) / sp)))
        j1 = min(frame.nv - 1, int(math.floor((max(a[1], b[1]) + Rc - frame.origin[1]) / sp)))
        if i1 < i0 or j1 < j0:
            continue
        x = frame.origin[0] + np.arange(i0, i1 + 1) * sp
        y = frame.origin[1] + np.arange(j0, j1 + 1) * sp
        total += int((_path_distance(a, b, x[None, :], y[:, None]) <= Rc).sum())
    return total


#: the shapes timed against the ball on ``wavy_finish`` by ``--shapes``
SHAPE_BASE = "ball:6:L=20"
SHAPE_RUNS = ("bull:6:1:L=20", "vbit:6:90:L=20", "drill:6:L=20")


def _median_pairs(first, second, pairs: int) -> tuple[list, list]:
    """Seconds of ``first()`` and ``second()`` in ``pairs`` interleaved pairs (the order
    alternates so a drifting machine load favours neither)."""
    ta, tb = [], []
    for k in range(max(1, pairs)):
        if k % 2 == 0:
            ta.append(first())
            tb.append(second())
        else:
            tb.append(second())
            ta.append(first())
    return ta, tb


def run_shape_pairs(shared: Path, pairs: int = 5, check: bool = True) -> list[dict]:
    """Each of ``SHAPE_RUNS`` against the ball on ``wavy_finish``, timed in interleaved
    pairs of plain cuts on fresh stock in this process: ``ratio_median`` is the median
    over the pairs of shape seconds / ball seconds (< 1: faster than the ball); with the
    sampled height check of the shape's cut (:func:`sampled_check`). The first line is
    the ball's own check."""
    moves = load_program(shared / CASES["wavy_finish"][0]).moves
    ball = parse_tool_spec(SHAPE_BASE)
    warm_up(ball, moves)
    out = []
    if check:
        _, grid = _time_dexmon(ball, moves)
        out.append({"case": "wavy_finish", "mode": "shape_pairs", "tool": SHAPE_BASE,
                    **sampled_check(grid, ball, moves)})
    for spec in SHAPE_RUNS:
        tool = parse_tool_spec(spec)
        warm_up(tool, moves)
        grids = []

        def shape():
            t, g = _time_dexmon(tool, moves)
            grids[:] = [g]
            return t

        tb, ts = _median_pairs(lambda: _time_dexmon(ball, moves)[0], shape, pairs)
        line = {"case": "wavy_finish", "mode": "shape_pairs", "tool": spec, "base": SHAPE_BASE,
                "base_s": round(statistics.median(tb), 4), "shape_s": round(statistics.median(ts), 4),
                "ratio_median": round(statistics.median([s / b for s, b in zip(ts, tb)]), 3),
                "ratios": [round(s / b, 3) for s, b in zip(ts, tb)], "pairs": len(ts)}
        if check:
            line.update(sampled_check(grids[0], tool, moves))
        line["load_avg"] = [round(v, 2) for v in os.getloadavg()]
        out.append(line)
    return out


def run_reach_rate(shared: Path, pairs: int = 5) -> dict:
    """Rays within reach of each chord, summed, per second of plain cut: the flat end
    mill pocketing ``pocket_rough`` beside the ball finishing ``wavy_finish`` (same
    units; interleaved pairs, medians)."""
    runs = {}
    for name in ("wavy_finish", "pocket_rough"):
        tool = parse_tool_spec(CASES[name][1])
        moves = load_program(shared / CASES[name][0]).moves
        warm_up(tool, moves)
        runs[name] = (tool, moves, rays_in_reach(stock_grid().frame, tool, moves))
    (tw, mw, nw), (tp, mp, npk) = runs["wavy_finish"], runs["pocket_rough"]
    sw, sp_ = _median_pairs(lambda: _time_dexmon(tw, mw)[0], lambda: _time_dexmon(tp, mp)[0], pairs)
    return {"mode": "reach_rate",
            "ball_finish": {"case": "wavy_finish", "tool": CASES["wavy_finish"][1], "rays_in_reach": nw,
                            "seconds": round(statistics.median(sw), 4),
                            "rays_per_s": round(nw / statistics.median(sw))},
            "flat_pocket": {"case": "pocket_rough", "tool": CASES["pocket_rough"][1], "rays_in_reach": npk,
                            "seconds": round(statistics.median(sp_), 4),
                            "rays_per_s": round(npk / statistics.median(sp_))},
            "pairs": len(sw), "load_avg": [round(v, 2) for v in os.getloadavg()]}


def run_case(name: str, shared: Path, check: bool, repeat: int = 3, mode: str = "plain") -> dict:
    rel, spec = CASES[name]
    path = shared / rel
    tool = parse_tool_spec(spec)
    t0 = time.perf_counter()
    moves = load_program(path).moves
    load_s = time.perf_counter() - t0
    warm_up(tool, moves)
    wall = cpu = math.inf
    res = None
    for _ in range(max(1, repeat)):  # best of N on fresh stock: the machine may be shared
        res = None  # the last run's result must not count in this run's peak
        grid = stock_grid()
        cutter = Cutter(grid, tool)
        c0 = time.process_time()
        w0 = time.perf_counter()
        res = cutter.cut_moves(moves, record_changes=mode != "plain")
        wall = min(wall, time.perf_counter() - w0)
        cpu = min(cpu, time.process_time() - c0)
    out = {
        "case": name,
        "mode": mode,
        "tool": spec,
        "threads": cutter.threads,
        "moves": int(len(moves)),
        "rays": grid.frame.n_rays,
        "repeat": repeat,
        "seconds": round(wall, 4),
        "cpu_seconds": round(cpu, 4),
        "moves_per_s": round(len(moves) / wall, 1),
        "moves_per_s_cpu": round(len(moves) / cpu, 1) if cpu > 0 else None,
        "removed_mm3": round(float(res.removed.sum()), 3),
        "grid_mb": round(grid.nbytes() / 2**20, 2),
        "grid_bytes": grid.nbytes(),
        "bytes_per_ray": round(grid.nbytes() / grid.frame.n_rays, 2),
        "load_seconds": round(load_s, 3),
    }
    if mode != "plain":
        out["changed_entries"] = int(res.changed_rays.size)
    out["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    if check:
        # a ray within 1e-6 mm of the swept boundary may fall either side: accept both
        ref_in = reference_heights(grid.frame, tool, moves, STOCK[5], -1e-6)
        ref_out = reference_heights(grid.frame, tool, moves, STOCK[5], +1e-6)
        top = grid.top().astype(np.float64)
        top = np.where(np.isnan(top), STOCK[2], top)
        err = np.maximum(0.0, np.maximum(top - np.maximum(ref_in, ref_out),
                                         np.minimum(ref_in, ref_out) - top))
        out["height_max_err_mm"] = float(f"{err.max():.3g}")
        out["rays_over_1um"] = int((err > 0.001).sum())
    return out


# --- 1M against 10M rays -------------------------------------------------------------

BIG_TOOL = "ball:6:L=20"


def wavy_surface(x, y):
    """Height (mm) of the wavy test surface: 10 +- 3 mm, periods 60 mm in X, 75 mm in Y."""
    return 10.0 + 3.0 * np.sin(2 * np.pi * x / 60.0) * np.cos(2 * np.pi * y / 75.0)


def wavy_raster(size: float, step: float = 0.5, stepover: float = 0.5) -> np.ndarray:
    """A zigzag raster finish over :func:`wavy_surface` on ``[0, size]^2`` (tip on the surface).

    As ``wavy_finish.nc``: from Z25 over the origin a plunge onto the surface, then
    passes along X in ``step`` mm moves, ``stepover`` mm apart in Y, alternating direction
    (4 x 10^4 moves for 100 mm, 3.6 x 10^5 for 300 mm).
    """
    xs = np.linspace(0.0, size, int(round(size / step)) + 1)
    ys = np.linspace(0.0, size, int(round(size / stepover)) + 1)
    pts = []
    for k, y in enumerate(ys):
        x = xs if k % 2 == 0 else xs[::-1]
        pts.append(np.column_stack([x, np.full_like(x, y), wavy_surface(x, y)]))
    path = np.concatenate([[[0.0, 0.0, 25.0]]] + pts)  # the plunge from Z25, then the passes
    moves = empty_moves(len(path) - 1)
    moves["kind"] = MoveKind.FEED
    moves["start"][:, :3] = path[:-1]
    moves["end"][:, :3] = path[1:]
    return moves


def rays_within_reach(frame: Frame, moves, radius: float) -> int:
    """Sum over the moves of the rays within ``radius`` (XY) of the tip's path, mm.

    The moves must be parallel to X or Y (as :func:`wavy_raster`'s): then each row's
    reach is the segment's X range grown by ``sqrt(radius^2 - dy^2)``.
    """
    p0 = tip_positions(moves, "start")
    p1 = tip_positions(moves, "end")
    d = p1 - p0
    if np.any((d[:, 0] != 0) & (d[:, 1] != 0)):
        raise ValueError("rays_within_reach takes moves parallel to X or Y")
    sp = frame.spacing
    x_lo = np.minimum(p0[:, 0], p1[:, 0]) - frame.origin[0]
    x_hi = np.maximum(p0[:, 0], p1[:, 0]) - frame.origin[0]
    y_lo = np.minimum(p0[:, 1], p1[:, 1]) - frame.origin[1]
    y_hi = np.maximum(p0[:, 1], p1[:, 1]) - frame.origin[1]
    j0 = np.ceil((y_lo - radius) / sp).astype(np.int64)
    rows = int(np.ceil((y_hi - y_lo).max() / sp + 2 * radius / sp)) + 2
    total = 0
    for k in range(rows):
        j = j0 + k
        y = j * sp
        dy = np.maximum(np.maximum(y_lo - y, y - y_hi), 0.0)
        ok = (dy <= radius) & (j >= 0) & (j < frame.nv)
        w = np.sqrt(np.maximum(radius * radius - dy * dy, 0.0))
        i0 = np.maximum(np.ceil((x_lo - w) / sp), 0)
        i1 = np.minimum(np.floor((x_hi + w) / sp), frame.nu - 1)
        total += int(np.sum(np.where(ok, np.maximum(i1 - i0 + 1, 0), 0)))
    return total


def _big_grid(size: float) -> DexelGrid:
    """Stock ``size`` x ``size`` x 20 mm, written straight into the store (no temporaries:
    the peak RSS is the cut's)."""
    grid = DexelGrid(Frame.top(0.0, 0.0, size, size, RESOLUTION))
    grid.store["count"][:] = 1
    grid.store["near"][:] = STOCK[2]
    grid.store["far"][:] = STOCK[5]
    return grid


def _time_big(size: float, tool, moves) -> tuple[float, float, DexelGrid]:
    """Wall and CPU seconds of the plain cut of ``moves`` into a fresh ``size`` mm square,
    and the grid."""
    grid = _big_grid(size)
    cutter = Cutter(grid, tool)
    c0 = time.process_time()
    w0 = time.perf_counter()
    cutter.cut_moves(moves, record_changes=False)
    return time.perf_counter() - w0, time.process_time() - c0, grid


def run_big(pairs: int = 3) -> dict:
    """Rays within reach per second on 1M rays (100 mm) and on 10M rays (300 mm).

    The same raster (:func:`wavy_raster`) on both, cut on fresh stock in ``pairs``
    interleaved pairs (the 10M grid is dropped before the next pair's). ``ratio_median``:
    median over the pairs of (10M rays/s) / (1M rays/s), wall time; 1.0 means the
    bigger model costs nothing per ray (``ratio_cpu_median``: the same by CPU time, less
    disturbed by other processes). ``window_max_diff_mm``: the largest height difference of the
    two results on ``[0, 96]^2`` mm, where both are cut by the same segments (0: exact
    alike). ``peak_rss_10m_mb``: ``ru_maxrss`` of a fresh process that cuts only the
    10M case (``rss_before_grid_mb``: the same before it builds the grid - the moves,
    numba and the kernels; ``vm_hwm_mb``: its VmHWM, the same peak from /proc).
    """
    # first, while this process is small: a child's ru_maxrss starts from its parent's
    # peak at the fork (Linux keeps the high-water mark across exec)
    child = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--big-rss"],
                           capture_output=True, text=True, check=True)
    rss = json.loads(child.stdout.strip().splitlines()[-1])
    tool = parse_tool_spec(BIG_TOOL)
    small, big = wavy_raster(100.0), wavy_raster(300.0)
    reach_small = rays_within_reach(Frame.top(0.0, 0.0, 100.0, 100.0, RESOLUTION), small, tool.cutting_radius)
    reach_big = rays_within_reach(Frame.top(0.0, 0.0, 300.0, 300.0, RESOLUTION), big, tool.cutting_radius)
    warm_up(tool, small)
    s_small, s_big, c_small, c_big, ratios, ratios_cpu = [], [], [], [], [], []
    top_small = top_big = None
    for k in range(max(1, pairs)):
        order = (100.0, 300.0) if k % 2 == 0 else (300.0, 100.0)
        for size in order:
            secs, cpu, grid = _time_big(size, tool, small if size == 100.0 else big)
            n = int(round(96.0 / RESOLUTION))
            top = grid.top()[:n, :n].copy()
            if size == 100.0:
                s_small.append(secs)
                c_small.append(cpu)
                top_small = top
            else:
                s_big.append(secs)
                c_big.append(cpu)
                top_big = top
                big_rays = grid.frame.n_rays
                big_bytes = grid.nbytes()
            del grid
        ratios.append((reach_big / s_big[-1]) / (reach_small / s_small[-1]))
        ratios_cpu.append((reach_big / c_big[-1]) / (reach_small / c_small[-1]))
    return {
        "case": "wavy_raster",
        "mode": "big",
        "tool": BIG_TOOL,
        "moves_1m": int(len(small)),
        "moves_10m": int(len(big)),
        "rays_10m": big_rays,
        "reach_rays_1m": reach_small,
        "reach_rays_10m": reach_big,
        "seconds_1m": round(statistics.median(s_small), 3),
        "seconds_10m": round(statistics.median(s_big), 3),
        "rays_per_s_1m": round(reach_small / statistics.median(s_small)),
        "rays_per_s_10m": round(reach_big / statistics.median(s_big)),
        "ratio_median": round(statistics.median(ratios), 3),
        "ratios": [round(r, 3) for r in ratios],
        "ratio_cpu_median": round(statistics.median(ratios_cpu), 3),
        "pairs": len(ratios),
        "window_max_diff_mm": float(np.nanmax(np.abs(top_small.astype(np.float64) - top_big))),
        "grid_mb_10m": round(big_bytes / 2**20, 1),
        **rss,
        "load_avg": [round(x, 2) for x in os.getloadavg()],
    }


def big_rss() -> dict:
    """The 10M case alone in this (fresh) process: its peak RSS."""
    tool = parse_tool_spec(BIG_TOOL)
    moves = wavy_raster(300.0)
    warm_up(tool, moves)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    secs, _, grid = _time_big(300.0, tool, moves)
    return {"peak_rss_10m_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
            "rss_before_grid_mb": round(before, 1), "vm_hwm_mb": _vm_hwm_mb(),
            "seconds_10m_alone": round(secs, 3)}


def _vm_hwm_mb() -> float | None:
    """This process's own peak resident set (VmHWM, Linux), MB; None where unknown."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return round(int(line.split()[1]) / 1024, 1)
    except OSError:
        pass
    return None


def _time_dexmon(tool, moves, threads: int | None = None) -> tuple[float, DexelGrid]:
    """Wall seconds of dexmon's plain cut of ``moves`` into fresh stock, and the grid."""
    grid = stock_grid()
    cutter = Cutter(grid, tool, threads=threads)
    w0 = time.perf_counter()
    cutter.cut_moves(moves, record_changes=False)
    return time.perf_counter() - w0, grid


def _time_baseline(tool, moves, frame: Frame) -> tuple[float, np.ndarray]:
    """Wall seconds of the baseline z-map cut of ``moves`` into fresh stock, and its heights."""
    H = np.full(frame.shape, STOCK[5])
    w0 = time.perf_counter()
    zmap_baseline.cut_into(H, frame, tool, moves, STOCK[2])
    return time.perf_counter() - w0, H


def run_baseline_pairs(name: str, spec: str, shared: Path, pairs: int = 5) -> dict:
    """dexmon's plain cut against the baseline z-map kernel, timed in interleaved pairs.

    Each pair cuts fresh stock once with each (the order alternates from pair to pair so
    a drifting machine load favours neither). ``ratio_median``: median over the pairs of
    baseline seconds / dexmon seconds (> 1: dexmon is faster) - the figure to quote, as
    absolute speeds drift with the machine's load; ``dexmon_s`` / ``baseline_s``: the
    medians. ``height_max_diff_mm``: largest |baseline - dexmon| over all rays (for the
    flat tool rays on a vertical wall may differ by the wall's height: ``rays_over_1um``
    counts those); ``bracket_max_err_mm``: how far dexmon's heights lie outside the
    baseline's with the radius 1e-6 mm smaller and larger (boundary rays accepted either
    way); ``load_avg``: the 1, 5 and 15 min load averages after the run. dexmon cuts on
    every core it may use (``threads``, see :mod:`sim.bands`); each pair also times it on
    one core: ``dexmon_1core_s`` and ``ratio_median_1core``.
    """
    tool = parse_tool_spec(spec)
    moves = load_program(shared / CASES[name][0]).moves
    warm_up(tool, moves)
    frame = stock_grid().frame
    zmap_baseline.cut_program(Frame.top(0, 0, 20, 20, RESOLUTION), tool, moves[:50], STOCK[5], STOCK[2])
    dexmon_s, one_core_s, baseline_s, ratios, ratios_1 = [], [], [], [], []
    for k in range(max(1, pairs)):
        if k % 2 == 0:
            td, grid = _time_dexmon(tool, moves)
            t1, _ = _time_dexmon(tool, moves, threads=1)
            tb, H = _time_baseline(tool, moves, frame)
        else:
            tb, H = _time_baseline(tool, moves, frame)
            t1, _ = _time_dexmon(tool, moves, threads=1)
            td, grid = _time_dexmon(tool, moves)
        dexmon_s.append(td)
        one_core_s.append(t1)
        baseline_s.append(tb)
        ratios.append(tb / td)
        ratios_1.append(tb / t1)
    top = np.nan_to_num(grid.top().astype(np.float64), nan=STOCK[2])
    diff = np.abs(H - top)
    bracket = []  # a ray within 1e-6 mm of the swept boundary may fall either side
    for dr in (-1e-6, 1e-6):
        bracket.append(np.full(frame.shape, STOCK[5]))
        zmap_baseline.cut_into(bracket[-1], frame, tool, moves, STOCK[2], dr)
    outside = np.maximum(0.0, np.maximum(top - np.maximum(*bracket), np.minimum(*bracket) - top))
    return {
        "case": name,
        "mode": "baseline_pairs",
        "tool": spec,
        "moves": int(len(moves)),
        "rays": frame.n_rays,
        "threads": Cutter(grid, tool).threads,
        "dexmon_s": round(statistics.median(dexmon_s), 4),
        "dexmon_1core_s": round(statistics.median(one_core_s), 4),
        "baseline_s": round(statistics.median(baseline_s), 4),
        "ratio_median": round(statistics.median(ratios), 3),
        "ratios": [round(r, 3) for r in ratios],
        "ratio_median_1core": round(statistics.median(ratios_1), 3),
        "pairs": len(ratios),
        "height_max_diff_mm": float(f"{diff.max():.3g}"),
        "rays_over_1um": int((diff > 0.001).sum()),
        "bracket_max_err_mm": float(f"{outside.max():.3g}"),
        "load_avg": [round(x, 2) for x in os.getloadavg()],
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", default=str(ROOT.parent / "shared"))
    ap.add_argument("--case", choices=sorted(CASES), action="append")
    ap.add_argument("--no-check", action="store_true", help="skip the reference height check")
    ap.add_argument("--repeat", type=int, default=3, help="runs per case; the best is reported (default 3)")
    ap.add_argument("--mode", choices=["plain", "record"], action="append",
                    help="what the cut records (default: plain and record)")
    ap.add_argument("--pairs", type=int, default=5,
                    help="interleaved pairs per baseline run and per shape (default 5; 0: no baseline)")
    ap.add_argument("--shapes", action="store_true",
                    help="only the tool shapes against the ball, and the rays-in-reach rates")
    ap.add_argument("--big", action="store_true",
                    help="only the 1M against 10M rays comparison (see run_big)")
    ap.add_argument("--big-rss", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.big_rss:
        print(json.dumps(big_rss()), flush=True)
        return 0
    if args.big:
        print(json.dumps(run_big(max(1, args.pairs))), flush=True)
        return 0
    shared = Path(args.shared)
    if not shared.is_dir():
        print(f"sim_bench: {shared} not found (pass --shared)", file=sys.stderr)
        return 2
    if args.shapes:
        for line in run_shape_pairs(shared, max(1, args.pairs), not args.no_check):
            print(json.dumps(line), flush=True)
        print(json.dumps(run_reach_rate(shared, max(1, args.pairs))), flush=True)
        return 0
    for name in args.case or list(CASES):
        for mode in args.mode or ["plain", "record"]:
            print(json.dumps(run_case(name, shared, not args.no_check and mode == "plain",
                                      args.repeat, mode)), flush=True)
    for name, spec in BASELINE_RUNS:
        if args.pairs > 0 and name in (args.case or list(CASES)):
            print(json.dumps(run_baseline_pairs(name, spec, shared, args.pairs)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
