"""Culling rays a move cannot reach changes nothing.

The batch kernels visit, per row, only the rays of a move's stadium (the segment's XY
footprint grown by the tool's radius) and skip rows and moves lying wholly above the
material. The oracles here are copies of the kernels' earlier behaviour: every ray of
each row's bounding-box range (``_cut_box_rows``) or of each pose's bounding box
(``_cut_box_poses``), cut one interval at a time. Heights and face ids must come out
bit for bit the same.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
import pytest

from sim import dexel_store as ds
from sim import sweep
from sim import sweep_kernels as K
from sim.cut import Cutter
from sim.frame import Frame
from sim.gcode.moves import MoveKind, empty_moves
from sim.grid import DexelGrid
from sim.tools import parse_tool_spec

SP = 0.1
TOP = 10.0


def box(x1=42.0, sp=SP) -> DexelGrid:
    f = Frame.top(-2.0, -3.0, x1, x1 + 1.0, sp)
    return DexelGrid.from_intervals(f, np.zeros(f.shape), np.full(f.shape, TOP))


def random_program(seed: int, n: int = 240) -> np.ndarray:
    """Diagonal moves, chained and not, many reaching above the top; arcs every 10th move."""
    rng = np.random.default_rng(seed)
    rows = []
    p = np.array([20.0, 20.0, 8.0])
    for k in range(n):
        if k % 3 == 1:  # a fresh start somewhere
            p = np.array([rng.uniform(0, 40), rng.uniform(0, 40), rng.uniform(4, 14)])
        q = p + np.array([rng.uniform(-8, 8), rng.uniform(-8, 8), rng.uniform(-2, 2)])
        rows.append((MoveKind.FEED, p, q, None))
        if k % 10 == 5:
            r = rng.uniform(1, 8)
            ang = rng.uniform(0, 2 * np.pi)
            c = q + np.array([r * np.cos(ang), r * np.sin(ang), 0.0])
            a2 = ang + np.pi + rng.uniform(-2, 2)
            e = c + np.array([r * np.cos(a2), r * np.sin(a2), rng.uniform(-1, 1)])
            rows.append((MoveKind.ARC_CW if k % 20 == 5 else MoveKind.ARC_CCW, q, e, c))
            q = e
        p = q
    m = empty_moves(len(rows))
    for i, (kind, a, b, c) in enumerate(rows):
        m["kind"][i] = kind
        m["start"][i, :3] = a
        m["end"][i, :3] = b
        if c is not None:
            m["center"][i] = c
            m["turns"][i] = 1
    return m


@nb.njit(cache=True)
def _cut_box_rows(S, gx0, gy0, sp, nu, nv, P0, P1, seg_id, tp, eps, top_bound):
    """The exact linear cut as it was before culling: each row's rays within Rc of the
    move's bounding box (less the rays behind a chained move), every interval through
    ``subtract_interval``. Returns False if the pool ran out (grow it first)."""
    code = int(tp[0])
    R = tp[1]
    h_top = tp[5]
    Rc = tp[6]
    row_ilo = np.empty(nv + 1, np.int64)
    row_off = np.empty(nv + 2, np.int64)
    for k in range(P0.shape[0]):
        x0, y0, z0 = P0[k, 0], P0[k, 1], P0[k, 2]
        dx, dy, dz = P1[k, 0] - x0, P1[k, 1] - y0, P1[k, 2] - z0
        ell = math.sqrt(dx * dx + dy * dy)
        ux, uy, m, sin_t = 1.0, 0.0, 0.0, 0.0
        if ell > 1e-9:
            ux, uy, m = dx / ell, dy / ell, dz / ell
            sin_t = dz / math.sqrt(ell * ell + dz * dz)
        else:
            ell = 0.0
        xmin, xmax = min(x0, x0 + dx), max(x0, x0 + dx)
        ymin, ymax = min(y0, y0 + dy), max(y0, y0 + dy)
        jlo = max(0, int(math.ceil((ymin - Rc - gy0) / sp)))
        jhi = min(nv - 1, int(math.floor((ymax + Rc - gy0) / sp)))
        if jhi < jlo:
            continue
        skip_behind = False
        a_cut = 0.0
        if (k > 0 and ell > 0.0 and P1[k - 1, 0] == x0 and P1[k - 1, 1] == y0
                and P1[k - 1, 2] == z0 and min(P0[k - 1, 2], z0) + h_top >= top_bound):
            skip_behind, a_cut = K._behind_cut(code, R, tp[2], tp[3], m, sin_t)
        nrows = jhi - jlo + 1
        row_off[0] = 0
        for jj in range(nrows):
            y = gy0 + (jlo + jj) * sp
            dym = max(ymin - y, y - ymax, 0.0)
            ilo = 0
            ihi = -1
            if dym <= Rc:
                w = math.sqrt(Rc * Rc - dym * dym)
                ilo = max(0, int(math.ceil((xmin - w - gx0) / sp)))
                ihi = min(nu - 1, int(math.floor((xmax + w - gx0) / sp)))
                if skip_behind:
                    if ux > 1e-12:
                        ilo = max(ilo, int(math.floor((x0 + (a_cut - uy * (y - y0)) / ux - gx0) / sp)))
                    elif ux < -1e-12:
                        ihi = min(ihi, int(math.ceil((x0 + (a_cut - uy * (y - y0)) / ux - gx0) / sp)))
                    elif uy * (y - y0) < a_cut - 1e-9:
                        ihi = ilo - 1
            row_ilo[jj] = ilo
            row_off[jj + 1] = row_off[jj] + max(ihi - ilo + 1, 0)
        total = row_off[nrows]
        lo = np.empty(total, np.float32)
        hi = np.empty(total, np.float32)
        flag = np.empty(total, np.bool_)
        rx0, ry0 = gx0 - x0, gy0 - y0
        if ell > 0.0 and code == K.CODE_BALL:
            K._rows_ball(R, Rc, tp[4], h_top, z0, m, sin_t, ell, ux, uy, rx0, ry0, sp, nu, jlo, nrows,
                         row_ilo, row_ilo, row_off, S[0], S[1], S[2], lo, hi, flag)
        elif ell > 0.0 and code == K.CODE_FLAT:
            K._rows_flat(Rc, tp[4], h_top, z0, m, ell, ux, uy, rx0, ry0, sp, nu, jlo, nrows,
                         row_ilo, row_ilo, row_off, S[0], S[1], S[2], lo, hi, flag)
        elif ell > 0.0 and code == K.CODE_BULL:
            K._rows_bull(R, tp[2], Rc, tp[4], h_top, z0, m, ell, ux, uy, rx0, ry0, sp, nu, jlo, nrows,
                         row_ilo, row_ilo, row_off, S[0], S[1], S[2], lo, hi, flag, skip_behind)
        elif ell > 0.0 and code == K.CODE_CONE:
            K._rows_cone(tp[3], Rc, tp[4], h_top, z0, m, ell, ux, uy, rx0, ry0, sp, nu, jlo, nrows,
                         row_ilo, row_ilo, row_off, S[0], S[1], S[2], lo, hi, flag, skip_behind)
        else:
            K._rows_any(tp, x0, y0, z0, dz, ell, ux, uy, rx0, ry0, sp, nu, jlo, nrows,
                        row_ilo, row_off, S[0], S[1], S[2], lo, hi, flag)
        for jj in range(nrows):
            o = row_off[jj]
            for q in range(row_off[jj + 1] - o):
                if flag[o + q]:
                    r = (jlo + jj) * nu + row_ilo[jj] + q
                    got = ds.subtract_interval(S, r, np.float64(lo[o + q]), np.float64(hi[o + q]),
                                               seg_id[k], eps)
                    if got == ds.POOL_FULL:
                        return False
    return True


@nb.njit(cache=True)
def _cut_box_poses(S, sp, nu, nv, tips, axes, pose_id, prof, rmax, eps):
    """Instances of motion as cut before culling: every ray of each pose's bounding box."""
    top_h = prof[prof.shape[0] - 1, 0]
    bot_h = prof[0, 0]
    ivs = np.empty((prof.shape[0], 2))
    buf = np.empty(2)
    for k in range(tips.shape[0]):
        tip = tips[k]
        ax = axes[k]
        ua, ub = tip[0] + bot_h * ax[0], tip[0] + top_h * ax[0]
        va, vb = tip[1] + bot_h * ax[1], tip[1] + top_h * ax[1]
        ilo = max(0, int(math.ceil((min(ua, ub) - rmax) / sp)))
        ihi = min(nu - 1, int(math.floor((max(ua, ub) + rmax) / sp)))
        jlo = max(0, int(math.ceil((min(va, vb) - rmax) / sp)))
        jhi = min(nv - 1, int(math.floor((max(va, vb) + rmax) / sp)))
        for j in range(jlo, jhi + 1):
            for i in range(ilo, ihi + 1):
                r = j * nu + i
                if S[0][r] == 0:
                    continue
                for q in range(K.pose_intervals(prof, tip, ax, i * sp, j * sp, ivs, buf)):
                    got = ds.subtract_interval(S, r, np.float64(np.float32(ivs[q, 0])),
                                               np.float64(np.float32(ivs[q, 1])), pose_id[k], eps)
                    if got == ds.POOL_FULL:
                        return False
    return True


def _same_bits(a: DexelGrid, b: DexelGrid) -> None:
    rays = np.arange(a.frame.n_rays)
    for x, y in zip(a.segments_of(rays), b.segments_of(rays)):
        assert x.dtype == y.dtype
        np.testing.assert_array_equal(x.view(np.uint8), y.view(np.uint8))


SPECS = ["flat:6:L=3", "ball:6:L=3", "bull:6:1:L=3", "vbit:6:90:L=3", "drill:5:L=3",
         "flat:6:L=30", "ball:6:L=30", "bull:8:2:L=30", "vbit:6:60:L=30", "drill:3:L=30"]


@pytest.mark.parametrize("spec", SPECS)
def test_batch_cut_is_bitwise_the_cut_of_every_ray_in_the_box(spec):
    """Random diagonal moves and arcs; short flutes (L=3) split rays into several segments,
    long ones (L=30) let chained moves skip the rays behind them."""
    tool = parse_tool_spec(spec)
    moves = random_program(SPECS.index(spec))
    got = box()
    Cutter(got, tool).cut_moves(moves, record_changes=False)
    want = box()
    cutter = Cutter(want, tool)
    work = cutter._plan(moves, np.arange(len(moves)), np.arange(1, len(moves) + 1, dtype=np.int32),
                        tool, np.zeros(len(moves), bool))
    p0, p1, _, sid = work.seg_arrays()
    assert len(p0) >= 64  # so that the batch knows the top (skips behind and above it)
    top_bound = float(np.nanmax(want.top()))
    ds.grow_pool(want.store, 1 << 22)
    f = want.frame
    assert _cut_box_rows(want.S, f.origin[0], f.origin[1], f.spacing, f.nu, f.nv, p0, p1, sid,
                         sweep.body_params(tool), cutter.tol.length, top_bound)
    assert (got.counts > 1).any() == spec.endswith("L=3")
    assert np.nanmin(got.top()) < TOP - 3
    _same_bits(got, want)


@pytest.mark.parametrize("spec", ["flat:6:L=12", "ball:6:L=12", "bull:6:1:L=12", "vbit:6:90:L=12"])
def test_poses_cut_is_bitwise_the_cut_of_every_ray_in_the_box(spec):
    """Tilted single poses and tilted 5-axis segments (instances of motion)."""
    tool = parse_tool_spec(spec)
    rng = np.random.default_rng(5)
    tips = np.column_stack([rng.uniform(0, 20, 40), rng.uniform(0, 20, 40), rng.uniform(5, 9, 40)])
    axes = np.column_stack([rng.uniform(-0.7, 0.7, 40), rng.uniform(-0.7, 0.7, 40), np.ones(40)])
    got = box(22.0)
    cutter = Cutter(got, tool)
    for k in range(len(tips)):
        cutter.cut_poses(tips[k:k + 1], axes[k], k + 1)
    want = box(22.0)
    f = want.frame
    tips_l = np.ascontiguousarray(f.to_local(tips))
    axes_l = np.ascontiguousarray(np.stack([axes @ f.u, axes @ f.v, axes @ f.direction], axis=1))
    axes_l /= np.linalg.norm(axes_l, axis=1, keepdims=True)
    prof = sweep.body_profile(tool)
    ds.grow_pool(want.store, 1 << 20)
    assert _cut_box_poses(want.S, f.spacing, f.nu, f.nv, tips_l, axes_l,
                          np.arange(1, len(tips) + 1, dtype=np.int32), prof, float(prof[:, 1].max()),
                          cutter.tol.length)
    assert np.nanmin(got.top()) < 7.0
    _same_bits(got, want)


def test_stadium_span_is_the_chord_of_the_segment_grown_by_the_radius():
    """Dense samples of each row: a point within the radius of the segment lies in the
    span, and the span's ends are at the radius (not the bounding box's)."""
    rng = np.random.default_rng(3)
    for _ in range(300):
        a = rng.uniform(-5, 5, 2)
        d = rng.uniform(-6, 6, 2) * rng.choice([0.0, 1e-13, 1.0], 2, p=[0.15, 0.1, 0.75])
        rad = rng.uniform(0.5, 4)
        y = a[1] + rng.uniform(-11, 11)
        lo, hi = K._stadium_span(a[0], a[1], d[0], d[1], rad, y)
        xs = np.linspace(a[0] - 20, a[0] + 20, 40001)
        pts = np.column_stack([xs, np.full_like(xs, y)]) - a
        t = np.clip((pts @ d) / max(d @ d, 1e-300), 0.0, 1.0)
        dist = np.hypot(*(pts - t[:, None] * d).T)
        inside = xs[dist <= rad]
        if inside.size == 0:
            assert lo > hi or hi - lo < 2e-3
            continue
        assert lo <= inside.min() + 1e-9 and hi >= inside.max() - 1e-9
        assert inside.min() - lo < 2e-3 and hi - inside.max() < 2e-3
