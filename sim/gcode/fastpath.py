"""Bulk interpretation of runs of simple lines (bit-identical to the per-line path).

Most of a CAM program's lines are ``[N..] [G0|G1] [X..] [Y..] [Z..] [F..]`` in absolute
mode. Such lines are recognised with one compiled regular expression and executed in
bulk: a numba loop does exactly the float operations the per-line interpreter does
(``work = value * units``, ``machine = work + offset``, missing axes carried as
``(machine - offset) + offset``), so the rows are identical bit for bit. Everything
else (expressions, comments, other words, G91, comp, inverse time...) goes through the
full interpreter.
"""

from __future__ import annotations

import re

import numpy as np
from numba import njit

from sim.gcode.moves import MOVE_DTYPE, MoveKind

_NUM = r"([-+]?(?:\d+\.?\d*|\.\d+))"
SIMPLE = re.compile(
    rf"[ \t]*(?:[Nn]\d+[ \t]*)?(?:[Gg]0*([01])[ \t]*)?(?:[Xx]{_NUM}[ \t]*)?(?:[Yy]{_NUM}[ \t]*)?"
    rf"(?:[Zz]{_NUM}[ \t]*)?(?:[Ff]{_NUM}[ \t]*)?\r?"
)
_WHOLE = re.compile(rf"^(?:{SIMPLE.pattern}|(.+))$", re.MULTILINE)
CHUNK = 1 << 16  # rows per output chunk (bounds the extra memory of assembling the table)


class FastLines:
    """Per main-file line: is it simple, and its G, X, Y, Z, F values (NaN when absent)."""

    def __init__(self, lines: list[str], text: str | None = None):
        n = len(lines)
        self.simple = np.zeros(n, dtype=np.bool_)
        vals = np.full((n, 5), np.nan)
        found = None
        if text is not None:
            # one C-level pass over the whole text: a tuple per line, the last group set
            # (the whole line) only when the line is not simple
            found = _WHOLE.findall(text)
            if len(found) == n + 1 and not found[-1][-1] and not any(found[-1][:5]):
                found.pop()
            if len(found) != n:
                found = None
        if found is None:
            found = []
            fm = SIMPLE.fullmatch
            for s in lines:
                m = fm(s)
                found.append(m.groups(default="") + ("",) if m else ("",) * 5 + (s or " ",))
        cols = list(zip(*found)) if found else [()] * 6
        simple = np.fromiter((not rest and bool(g or x or y or z or f) for g, x, y, z, f, rest in found),
                             dtype=np.bool_, count=n)
        self.simple = simple
        ia = np.flatnonzero(simple)
        for k in range(5):
            col = cols[k]
            arr = np.array([col[i] or "nan" for i in ia], dtype=np.float64) if len(ia) else np.zeros(0)
            vals[ia, k] = arr
        self.values = vals
        # index of the first non-simple line at or after each line
        nxt = np.arange(n + 1)
        not_simple = np.flatnonzero(~self.simple)
        pos = np.searchsorted(not_simple, np.arange(n), side="left")
        ends = np.append(not_simple, n)
        self.run_end = ends[pos]
        del nxt


@njit(cache=True)
def _positions(vals, pos0, off, factor, motion0):
    """Machine end positions (n, 6), motion (n,), moved (n,) bool for a run of simple lines."""
    n = vals.shape[0]
    end = np.empty((n, 6))
    motion = np.empty(n, dtype=np.int64)
    moved = np.zeros(n, dtype=np.bool_)
    pos = pos0.copy()
    mo = motion0
    for k in range(n):
        g = vals[k, 0]
        if g == g:
            mo = 0 if g == 0.0 else 10
        motion[k] = mo
        has = False
        for i in range(3):
            v = vals[k, 1 + i]
            if v == v:
                has = True
        if has:
            for i in range(6):
                if i < 3 and vals[k, 1 + i] == vals[k, 1 + i]:
                    target = vals[k, 1 + i] * factor
                else:
                    target = pos[i] - off[i]
                pos[i] = target + off[i]
            moved[k] = True
        for i in range(6):
            end[k, i] = pos[i]
    return end, motion, moved


def run_simple(it, fl: FastLines, start: int, stop: int, snapshot) -> bool:
    """Execute main-file lines ``start:stop`` (all simple) in bulk on interpreter ``it``.

    Returns False (having done nothing) when the state or the lines need the full
    interpreter: not absolute mode, comp on, inverse time or feed per rev, or a feed
    move with no feed rate.
    """
    if it.distance != 900 or it.comp != 400 or it.feed_mode != 940 or it.ended or it.comp_engine is not None:
        return False
    if it.motion not in (0, 10) and np.isnan(fl.values[start, 0]):
        return False
    vals = fl.values[start:stop]
    off = np.array(it.offsets(), dtype=np.float64)
    end, motion, moved = _positions(vals, np.array(it.pos, dtype=np.float64), off, it.factor,
                                    it.motion if it.motion in (0, 10) else -1)
    fcol = vals[:, 4]
    has_f = ~np.isnan(fcol)
    if (fcol[has_f] < 0).any():
        return False
    # feed word in force on each line (forward fill)
    last = np.where(has_f, np.arange(len(vals)), -1)
    np.maximum.accumulate(last, out=last)
    feed_word = np.where(last >= 0, fcol[np.maximum(last, 0)], it.feed_word)
    feed_set = (last >= 0) | it.feed_set
    feed = feed_word * it.factor
    is_feed = moved & (motion == 10)
    if (is_feed & ((feed <= 0) | (~feed_set if it.grbl else False))).any():
        return False
    rows_idx = np.flatnonzero(moved)
    n = len(rows_idx)
    it._seal()
    prev_end = np.empty((n, 6))
    if n:
        prev_end[0] = it.pos
        prev_end[1:] = end[rows_idx[:-1]]
    line_no = np.arange(start + 1, stop + 1, dtype=np.int32)
    meta = it.meta()
    for c0 in range(0, n, CHUNK):
        sl = slice(c0, min(n, c0 + CHUNK))
        ri = rows_idx[sl]
        rows = np.zeros(len(ri), dtype=MOVE_DTYPE)
        rows["file"] = meta[0]
        rows["line"] = line_no[ri]
        rows["kind"] = np.where(motion[ri] == 0, MoveKind.RAPID, MoveKind.FEED)
        rows["start"] = prev_end[sl]
        rows["end"] = end[ri]
        rows["start_work"] = prev_end[sl] - off
        rows["end_work"] = end[ri] - off
        rows["center"] = np.nan
        rows["plane"] = meta[7]
        rows["feed"] = np.where(motion[ri] == 0, 0.0, feed[ri])
        rows["spindle"] = meta[2]
        rows["spindle_dir"] = meta[3]
        rows["tool"] = meta[4]
        rows["tool_length"] = meta[5]
        rows["coolant"] = meta[6]
        it._chunks.append(rows)
        it._chunk_lines.append(line_no[ri].astype(np.int64))
    # modal snapshots where motion mode or feed changes inside the run
    prev_motion = np.concatenate(([it.motion], motion[:-1]))
    prev_feed = np.concatenate(([it.feed_word], feed_word[:-1]))
    change = np.flatnonzero((motion != prev_motion) | (feed_word != prev_feed))
    for k in change:
        it.motion = int(motion[k])
        it.feed_word = float(feed_word[k])
        it.main_line = it.line = int(start + k + 1)
        snapshot()
    it.pos = [float(v) for v in end[-1]]
    it.motion = int(motion[-1])
    it.feed_word = float(feed_word[-1])
    it.feed_set = bool(feed_set[-1])
    it.line = it.main_line = stop
    snapshot()
    return True
