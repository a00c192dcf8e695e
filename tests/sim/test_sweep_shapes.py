"""Exact sweeps of the bull-nose and the cone (vbit, drill) against an independent oracle.

The oracle (:func:`bench.sim_bench.sweep_floor`, also the benchmark's height check)
parametrises the move by ``t`` in [0, 1] along the 3-D tip segment, finds the part of
the move within reach of each ray from the quadratic ``|p(t) - ray| = Rc`` and minimises
the convex ``z(t) + lowest_height(d(t))`` (:meth:`Tool.lowest_height`) by golden section
to the last bit - no slope, no root, no closed form shared with the kernels.
Both kernels are checked: :func:`sim.sweep_kernels.linear_interval` (float64, 1e-9 mm)
and the batch cut's row kernels through :class:`Cutter` (heights stored as float32;
exact to 1e-6 mm). Rays within 1e-6 mm of the swept rim may fall either side and are
left out (the tests assert that they are few).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.sim_bench import sweep_floor
from sim import sweep
from sim.cut import Cutter
from sim.frame import Frame
from sim.gcode.moves import MoveKind, empty_moves
from sim.grid import DexelGrid
from sim.tools import parse_tool_spec

SHAPES = ["bull:6:1", "bull:8:3", "bull:6:3", "bull:6:0.25", "vbit:6:90", "vbit:10:30",
          "drill:6", "drill:3:150"]
STOCK_TOP = 15.0


def path_distance(p0, p1, x, y):
    """XY distance of the rays ``(x, y)`` from the tip's path."""
    a, d = np.asarray(p0, float)[:2], np.asarray(p1, float)[:2] - np.asarray(p0, float)[:2]
    L2 = d @ d
    t = np.zeros_like(x) if L2 == 0 else np.clip(((x - a[0]) * d[0] + (y - a[1]) * d[1]) / L2, 0, 1)
    return np.hypot(x - a[0] - t * d[0], y - a[1] - t * d[1])


def frame_around(p0, p1, Rc, sp=0.1, shift=(0.0, 0.0)):
    """A top frame covering the move's reach, its rays shifted by ``shift`` (mm)."""
    x0 = min(p0[0], p1[0]) - Rc - 0.3 + shift[0]
    y0 = min(p0[1], p1[1]) - Rc - 0.3 + shift[1]
    x1 = max(p0[0], p1[0]) + Rc + 0.3
    y1 = max(p0[1], p1[1]) + Rc + 0.3
    return Frame.top(x0, y0, x0 + sp * math.ceil((x1 - x0) / sp), y0 + sp * math.ceil((y1 - y0) / sp), sp)


def random_moves(rng, n):
    """Moves of every kind that matters: any direction or along an axis, level, gentle,
    steep and vertical, climbing and descending, short and long."""
    out = []
    for k in range(n):
        ell = [0.0, 0.02, 0.5, 3.0, 6.0][k % 5]
        ang = [rng.uniform(0, 2 * math.pi), 0.0, math.pi / 2, math.pi, 0.75 * math.pi][(k // 5) % 5]
        slope = [0.0, 1e-3, 0.2, 0.6, 1.0, 1.7, 5.0, 40.0][rng.integers(8)]
        slope *= 1 if rng.random() < 0.5 else -1
        p0 = np.array([10 + rng.uniform(-0.5, 0.5), 10 + rng.uniform(-0.5, 0.5), 6.0 + rng.uniform(0, 1)])
        dz = slope * ell if ell > 0 else rng.uniform(-4, 4)
        dz = float(np.clip(dz, -5.0, 5.0))
        out.append((p0, p0 + np.array([ell * math.cos(ang), ell * math.sin(ang), dz])))
    return out


def rim_moves(tool):
    """Moves whose rows of rays lie at the rim, at the edge of a bull-nose's flat bottom,
    on the path and just inside or outside those (``e``: the rays' offset from the path)."""
    R, Rc, a0 = tool.radius, tool.cutting_radius, tool.radius - tool.corner_radius
    out = []
    for e in (Rc - 1e-7, Rc - 1e-4, a0, a0 + 1e-9, a0 - 1e-9, 1e-9, 0.0, 0.5 * (a0 + R)):
        for slope in (0.4, -3.0, 1e-6):
            dz = min(max(4 * slope, -4.0), 4.0)  # stays inside the stock
            out.append((np.array([10.0, 10.0 - e, 7.0]), np.array([14.0, 10.0 - e, 7.0 + dz])))
    return out


def check_linear_interval(tool, p0, p1, shift=(0.0, 0.0), tol=1e-9):
    frame = frame_around(p0, p1, tool.cutting_radius, shift=shift)
    lo, _ = sweep.linear_sweep_on_rays(tool, p0, p1, frame)
    pts = frame.ray_points().reshape(-1, 3)
    want = sweep_floor(tool, p0, p1, pts[:, 0], pts[:, 1])
    rim = np.abs(path_distance(p0, p1, pts[:, 0], pts[:, 1]) - tool.cutting_radius) < 1e-6
    got = lo.reshape(-1)
    assert np.array_equal(np.isnan(got[~rim]), np.isnan(want[~rim])), (p0, p1)
    ok = ~rim & ~np.isnan(want)
    err = np.abs(got[ok] - want[ok])
    assert err.max(initial=0.0) <= tol, (p0, p1, err.max())
    return int(rim.sum()), int(ok.sum())


def cut_and_compare(tool, segments, frame, tol=1e-6):
    """Cut the chained ``segments`` into fresh stock by :meth:`Cutter.cut_moves` and
    compare every ray's top with the oracle's; returns (rays compared, rim rays)."""
    g = DexelGrid.from_intervals(frame, np.zeros(frame.shape), np.full(frame.shape, STOCK_TOP))
    mv = empty_moves(len(segments))
    for k, (p0, p1) in enumerate(segments):
        mv["kind"][k] = MoveKind.FEED
        mv["start"][k, :3] = p0
        mv["end"][k, :3] = p1
        mv["line"][k] = k + 1
    Cutter(g, tool).cut_moves(mv, record_changes=False)
    pts = frame.ray_points().reshape(-1, 3)
    want = np.full(frame.n_rays, STOCK_TOP)
    rim = np.zeros(frame.n_rays, bool)
    for p0, p1 in segments:
        dist = path_distance(p0, p1, pts[:, 0], pts[:, 1])
        near = np.nonzero(dist <= tool.cutting_radius + 1e-6)[0]
        rim[near[np.abs(dist[near] - tool.cutting_radius) < 1e-6]] = True
        floor = sweep_floor(tool, p0, p1, pts[near, 0], pts[near, 1])
        want[near] = np.fmin(want[near], floor)
    got = g.top().reshape(-1).astype(np.float64)
    ok = ~rim
    err = np.abs(got[ok] - want[ok])
    worst = int(np.argmax(err)) if err.size else 0
    assert err.max(initial=0.0) <= tol, (err.max(), np.nonzero(ok)[0][worst])
    return int(ok.sum()), int(rim.sum())


@pytest.mark.parametrize("spec", SHAPES)
def test_linear_interval_matches_the_oracle_on_random_moves(spec):
    tool = parse_tool_spec(spec + ":L=20")  # the flutes reach above the stock
    rng = np.random.default_rng(sum(map(ord, spec)))
    rim = total = 0
    for p0, p1 in random_moves(rng, 25):
        r, n = check_linear_interval(tool, p0, p1, shift=tuple(rng.uniform(0, 0.1, 2)))
        rim += r
        total += n
    assert rim < 0.001 * total


@pytest.mark.parametrize("spec", ["bull:6:1", "bull:6:3", "bull:8:3", "vbit:6:90", "drill:6"])
def test_linear_interval_at_the_rim_and_the_flat_edge(spec):
    tool = parse_tool_spec(spec + ":L=20")  # the flutes reach above the stock
    for p0, p1 in rim_moves(tool):
        check_linear_interval(tool, p0, p1)


@pytest.mark.parametrize("spec", SHAPES)
def test_batch_cut_of_single_moves_matches_the_oracle(spec):
    tool = parse_tool_spec(spec + ":L=20")  # the flutes reach above the stock
    rng = np.random.default_rng(1 + sum(map(ord, spec)))
    for p0, p1 in random_moves(rng, 20) + rim_moves(tool)[::3]:
        frame = frame_around(p0, p1, tool.cutting_radius, shift=tuple(rng.uniform(0, 0.1, 2)))
        n, rim = cut_and_compare(tool, [(p0, p1)], frame)
        assert rim < 0.01 * n + 2


@pytest.mark.parametrize("spec", ["bull:6:1", "bull:8:3", "vbit:6:90", "drill:6", "ball:6", "flat:6"])
def test_batch_cut_of_a_chained_path_matches_the_oracle(spec):
    # >= 64 chained moves: the batch skips the rays behind each move's start (cut as deep by
    # the previous move's end pose); level, climbing and descending, turning at random
    tool = parse_tool_spec(spec + ":L=20")  # the flutes reach above the stock
    rng = np.random.default_rng(2 + sum(map(ord, spec)))
    p = np.array([12.0, 12.0, 8.0])
    segments = []
    for k in range(72):
        ang = rng.uniform(0, 2 * math.pi) if k % 4 else 0.0
        ell = [0.5, 0.3, 1.2, 0.05][k % 4]
        slope = [0.0, 0.3, -0.3, 1.5, -1.5, 0.05, -4.0][rng.integers(7)]
        q = p + np.array([ell * math.cos(ang), ell * math.sin(ang), slope * ell])
        q[:2] = np.clip(q[:2], 9.0, 15.0)
        q[2] = float(np.clip(q[2], 3.0, 12.0))
        segments.append((p, q))
        p = q
    frame = Frame.top(4.03, 4.07, 20.03, 20.07, 0.1)
    n, rim = cut_and_compare(tool, segments, frame)
    assert rim < 0.01 * n


@pytest.mark.parametrize("spec", ["vbit:6:90", "drill:6", "bull:6:1"])
def test_batch_cut_of_steep_chained_moves_along_x_matches_the_oracle(spec):
    # rows along the move leave out the rays whose lowest point is the start pose; on a
    # cone climbing nearly as steep as its flank that is only the part within reach of it
    tool = parse_tool_spec(spec + ":L=20")
    slopes = [0.9, 0.5, 0.0, 0.8, -0.3, 0.95, 0.6, 1.2]
    p = np.array([8.0, 12.03, 3.0])
    segments = []
    for k in range(70):
        q = p + np.array([0.13, 0.0, 0.13 * slopes[k % len(slopes)]])
        segments.append((p, q))
        p = q
    frame = Frame.top(4.01, 8.02, 21.01, 16.02, 0.1)
    n, rim = cut_and_compare(tool, segments, frame)
    assert rim < 0.01 * n
