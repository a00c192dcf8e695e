"""Program sync on synthetic traces: noise, jitter, feed hold, overrides, mid-program start, jumps."""

from __future__ import annotations

import numpy as np
import pytest

from monitor.sync import ProgramPath, ProgramSync, row_lengths, row_seconds
from sim.gcode.moves import MoveKind, empty_moves


def table(points, kinds, feed=600.0, first_line=10):
    """A move table through ``points`` (k+1, 3); row r goes points[r] -> points[r+1]."""
    pts = np.asarray(points, float)
    n = len(pts) - 1
    m = empty_moves(n)
    m["line"] = np.arange(first_line, first_line + n)
    m["kind"] = kinds
    for col, src in (("start", pts[:-1]), ("end", pts[1:])):
        m[col][:, :3] = src
    m["feed"] = np.where(np.asarray(kinds) == MoveKind.RAPID, 0.0, feed)
    return m


def raster(passes=6, width=40.0, step=2.0, depth=-1.0):
    """Plunge, zigzag passes, retract up the last plunge line, rapid home."""
    pts = [(0, 0, 5), (0, 0, 1), (0, 0, depth)]
    kinds = [MoveKind.RAPID, MoveKind.FEED]  # rapid down to 1 mm above, feed plunge
    x = 0.0
    for p in range(passes):
        x = width if p % 2 == 0 else 0.0
        pts.append((x, p * step, depth))
        kinds.append(MoveKind.FEED)
        if p < passes - 1:
            pts.append((x, (p + 1) * step, depth))
            kinds.append(MoveKind.FEED)
    pts.append((x, (passes - 1) * step, 5))
    kinds.append(MoveKind.RAPID)
    pts.append((0, 0, 5))
    kinds.append(MoveKind.RAPID)
    return table(pts, kinds[:len(pts) - 1])


def trace(path, rate=1.0, dt=0.02, t_from=0.0, t_to=None):
    """True progress and tip positions sampled every dt wall seconds at speed ``rate``."""
    t_to = path.duration if t_to is None else t_to
    prog = np.arange(t_from, t_to, dt * rate)
    return prog, np.array([path.point_at(p) for p in prog])


def test_row_seconds_and_lengths():
    m = raster()
    sec = row_seconds(m, rapid_rate=6000)
    lengths = row_lengths(m)
    assert lengths[0] == pytest.approx(4.0) and lengths[1] == pytest.approx(2.0)
    assert sec[0] == pytest.approx(4.0 / 6000 * 60)
    assert sec[2] == pytest.approx(40.0 / 600 * 60)


def test_arc_is_flattened_with_its_true_length():
    m = empty_moves(1)
    m["kind"] = MoveKind.ARC_CCW
    m["start"][0, :3] = (10, 0, 0)
    m["end"][0, :3] = (-10, 0, 0)
    m["center"][0] = (0, 0, 0)
    m["feed"] = 600
    m["turns"] = 1
    assert row_lengths(m)[0] == pytest.approx(np.pi * 10, rel=1e-3)
    path = ProgramPath.from_moves(m, chord=0.01)
    assert len(path) > 10 and path.p1[-1].tolist() == [-10, 0, 0]
    assert path.point_at(path.duration / 2) == pytest.approx([0, 10, 0], abs=0.05)


def follow(sync, prog, pts, dt=0.02, noise=0.0, seed=0, lines=None):
    rng = np.random.default_rng(seed)
    got = []
    for q, (p, x) in enumerate(zip(prog, pts)):
        r = sync.update(x + rng.normal(0, noise, 3), t=q * dt, line=None if lines is None else lines[q])
        got.append(r.progress)
    return np.array(got)


def test_tracks_noisy_jittery_trace_monotonically():
    path = ProgramPath.from_moves(raster())
    sync = ProgramSync(path, noise=0.05)
    prog, pts = trace(path)
    rng = np.random.default_rng(1)
    jitter = np.clip(rng.normal(1.0, 0.3, prog.size), 0.2, 2.5)  # irregular poll times
    t = np.cumsum(0.02 * jitter)
    got = []
    for k in range(prog.size):
        got.append(sync.update(pts[k] + rng.normal(0, 0.02, 3), t=t[k]).progress)
    got = np.array(got)
    assert np.all(np.diff(got) >= 0)
    # position error <= a few noise sigmas: compare through the path points
    err = np.linalg.norm(np.array([path.point_at(g) for g in got]) - pts, axis=1)
    assert np.percentile(err, 99) < 0.15
    assert abs(got[-1] - prog[-1]) < 0.2


def test_retract_up_the_plunge_line_is_not_mistaken_for_the_plunge():
    # plunge down then straight back up the same line, then across
    m = table([(0, 0, 5), (0, 0, -2), (0, 0, 5), (20, 0, 5)], [MoveKind.FEED, MoveKind.FEED, MoveKind.FEED])
    path = ProgramPath.from_moves(m)
    sync = ProgramSync(path)
    prog, pts = trace(path, dt=0.01)
    got = follow(sync, prog, pts, dt=0.01)
    assert np.max(np.abs(got - prog)) < 0.05
    assert sync.update(pts[-1]).row == 2


def test_feed_hold_and_override():
    path = ProgramPath.from_moves(raster())
    sync = ProgramSync(path)
    prog, pts = trace(path, t_to=3.0)
    follow(sync, prog, pts)
    held = sync.progress
    for q in range(100):  # 2 s standing still in hold, with noise
        r = sync.update(pts[-1] + np.random.default_rng(q).normal(0, 0.02, 3), t=3.0 + q * 0.02)
    assert abs(r.progress - held) < 0.05
    # resume at 200 % feed override: twice the program time per wall second
    prog2, pts2 = trace(path, rate=2.0, t_from=held, t_to=held + 8.0)
    got = []
    for q, x in enumerate(pts2):
        got.append(sync.update(x, t=5.0 + q * 0.02).progress)
    assert np.max(np.abs(np.array(got) - prog2)) < 0.05


def test_mid_program_start_and_jump_ahead():
    path = ProgramPath.from_moves(raster())
    sync = ProgramSync(path)
    start = path.duration * 0.55
    prog, pts = trace(path, t_from=start, t_to=start + 2.0)
    got = follow(sync, prog, pts, noise=0.02)
    assert sync.update(pts[0]).how in ("track", "search")
    assert np.max(np.abs(got - prog)) < 0.1
    # operator skips ahead: positions now come from much later in the program
    later = path.duration * 0.85
    prog2, pts2 = trace(path, t_from=later, t_to=later + 1.0)
    got2 = [sync.update(x, t=10 + q * 0.02).progress for q, x in enumerate(pts2)]
    assert abs(got2[-1] - prog2[-1]) < 0.1


def test_reported_line_wins_and_off_path_is_lost():
    m = raster()
    path = ProgramPath.from_moves(m)
    sync = ProgramSync(path)
    p = path.point_at(path.row_t0[4] + 0.1)
    r = sync.update(p, t=0.0, line=int(m["line"][4]))
    assert r.how == "line" and r.row == 4 and r.line == m["line"][4]
    r = sync.update((500, 500, 500), t=0.02)
    assert r.how == "lost" and r.progress == pytest.approx(path.row_t0[4] + 0.1, abs=1e-6)


def test_a_reported_line_no_row_can_have_is_not_matched_but_tracked():
    # lines are int32 in the move table; a controller may report any number (a corrupt
    # N word): beyond that range the state is followed by position, as for an unknown line
    m = raster()
    path = ProgramPath.from_moves(m)
    sync = ProgramSync(path)
    p = path.point_at(path.row_t0[4] + 0.1)
    assert sync.update(p, t=0.0, line=int(m["line"][4])).how == "line"
    for q, line in enumerate((2**31, 2**40, 99_999)):
        r = sync.update(p, t=0.02 * (q + 1), line=line)
        assert r.how == "track" and r.row == 4


def test_path_measures():
    path = ProgramPath.from_moves(raster())
    assert path.length_at(path.duration) == pytest.approx(path.s1[-1])
    t = path.progress_at_length(20.0)
    assert path.length_at(t) == pytest.approx(20.0)
    assert path.segment_at(-5) == 0 and path.segment_at(1e9) == len(path) - 1
