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
CHUNK = 1 << 16  # rows per output chunk (bounds the extra memory of assembling the table)


_POW10 = np.array([10.0 ** k for k in range(23)])  # exact doubles 1e0 .. 1e22
_ODD_BREAKS = re.compile("[\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029]")


class SourceLines:
    """The lines of an ASCII text without a list of strings: offsets into the text.

    Behaves like ``text.splitlines()`` (for texts whose only breaks are \\n and \\r\\n).
    """

    def __init__(self, text: str, starts: np.ndarray, ends: np.ndarray):
        self.text = text
        self.starts = starts
        self.ends = ends

    def __len__(self) -> int:
        return len(self.starts)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        if i < 0:
            i += len(self.starts)
        return self.text[self.starts[i]:self.ends[i]]

    def __iter__(self):
        for i in range(len(self.starts)):
            yield self[i]


def split_lines(text: str):
    """``(lines, data)``: lines like ``text.splitlines()`` and the uint8 bytes when fast scanning applies.

    Fast scanning applies to ASCII texts whose line breaks are only \\n or \\r\\n.
    """
    if not text.isascii() or _ODD_BREAKS.search(text) or text.count("\r") != text.count("\r\n"):
        return text.splitlines(), None
    data = np.frombuffer(text.encode("ascii"), dtype=np.uint8)
    nl = np.flatnonzero(data == 10)
    starts = np.concatenate(([0], nl + 1))
    ends = np.concatenate((nl, [len(data)]))
    if len(starts) and starts[-1] == len(data):  # text ends with a newline: no empty last line
        starts, ends = starts[:-1], ends[:-1]
    cr = (ends > starts) & (data[np.maximum(ends - 1, 0)] == 13)
    ends = ends - cr
    return SourceLines(text, starts, ends), data


@njit(cache=True)
def _number(b, k, end, pow10):
    """Parse [+-]digits[.digits] at b[k:end]; returns (value, next index, ok). Exact like float()."""
    neg = False
    if k < end and (b[k] == 43 or b[k] == 45):
        neg = b[k] == 45
        k += 1
    m = 0
    nd = 0
    frac = 0
    while k < end and 48 <= b[k] <= 57:
        m = m * 10 + (b[k] - 48)
        nd += 1
        k += 1
        if m > 9007199254740992:
            return 0.0, k, False
    if k < end and b[k] == 46:
        k += 1
        while k < end and 48 <= b[k] <= 57:
            m = m * 10 + (b[k] - 48)
            nd += 1
            frac += 1
            k += 1
            if m > 9007199254740992 or frac > 22:
                return 0.0, k, False
    if nd == 0:
        return 0.0, k, False
    v = m / pow10[frac]
    return (-v if neg else v), k, True


@njit(cache=True)
def _scan(b, starts, ends, pow10, vals, simple):
    """Mark simple lines ([N] [G0|G1] [X] [Y] [Z] [F], any order, once each) and store their values."""
    for li in range(starts.shape[0]):
        k = starts[li]
        end = ends[li]
        ok = True
        seen = 0
        useful = False
        while k < end:
            c = b[k]
            if c == 32 or c == 9:
                k += 1
                continue
            if 97 <= c <= 122:
                c -= 32
            if c == 78:
                slot = 5
            elif c == 71:
                slot = 0
            elif c == 88:
                slot = 1
            elif c == 89:
                slot = 2
            elif c == 90:
                slot = 3
            elif c == 70:
                slot = 4
            else:
                ok = False
                break
            bit = 1 << slot
            if seen & bit:
                ok = False
                break
            seen |= bit
            v, k, good = _number(b, k + 1, end, pow10)
            if not good:
                ok = False
                break
            if k < end and b[k] != 32 and b[k] != 9 and not (65 <= (b[k] & 223) <= 90):
                ok = False
                break
            if slot == 0:
                if v != 0.0 and v != 1.0:
                    ok = False
                    break
            if slot == 5 and (v != np.floor(v) or v < 0.0 or v > 9999999.0):
                ok = False
                break
            if slot != 5:
                vals[li, slot] = v
                useful = True
        simple[li] = ok and useful


class FastLines:
    """Per main-file line: is it simple, and its G, X, Y, Z, F values (NaN when absent)."""

    def __init__(self, lines, data: np.ndarray | None = None):
        n = len(lines)
        vals = np.full((n, 5), np.nan)
        if data is not None and isinstance(lines, SourceLines):
            simple = np.zeros(n, dtype=np.bool_)
            _scan(data, lines.starts, lines.ends, _POW10, vals, simple)
            vals[~simple] = np.nan
        else:
            found = []
            fm = SIMPLE.fullmatch
            for s in lines:
                m = fm(s)
                found.append(m.groups(default="") if m else None)
            simple = np.array([g is not None and any(g) for g in found], dtype=np.bool_)
            for i in np.flatnonzero(simple):
                vals[i] = [float(v) if v else np.nan for v in found[i]]
        self.simple = simple
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
    off = np.array(it.offsets(), dtype=np.float64)
    meta = it.meta()
    it._seal()
    pos = np.array(it.pos, dtype=np.float64)
    mo = it.motion if it.motion in (0, 10) else -1
    fw = it.feed_word
    fset = it.feed_set
    fcol_all = fl.values[start:stop, 4]
    if (fcol_all[~np.isnan(fcol_all)] < 0).any():
        return False
    n0 = it._n
    # rows of this run, exactly: the table grows once instead of by steps
    it.reserve(int(np.count_nonzero(~np.isnan(fl.values[start:stop, 1:4]).all(axis=1))))
    changes = []  # (line index, motion, feed word) where the modal state changes
    prev_m, prev_f = it.motion, it.feed_word
    for a in range(start, stop, CHUNK):
        b = min(stop, a + CHUNK)
        vals = fl.values[a:b]
        end, motion, moved = _positions(vals, pos, off, it.factor, mo)
        fcol = vals[:, 4]
        has_f = ~np.isnan(fcol)
        last = np.where(has_f, np.arange(len(vals)), -1)
        np.maximum.accumulate(last, out=last)
        feed_word = np.where(last >= 0, fcol[np.maximum(last, 0)], fw)
        feed_set = (last >= 0) | fset
        feed = feed_word * it.factor
        is_feed = moved & (motion == 10)
        if (is_feed & ((feed <= 0) | (~feed_set if it.grbl else False))).any():
            it._n = n0  # refuse the whole run: the per-line path reports the error
            return False
        ri = np.flatnonzero(moved)
        n = len(ri)
        if n:
            ends = end[ri]
            i = it.reserve(n)
            rows = it._table[i:i + n]
            starts = np.empty((n, 6))
            starts[0] = pos
            starts[1:] = ends[:-1]
            line_no = (a + 1 + ri).astype(np.int32)
            rows["file"] = meta[0]
            rows["line"] = line_no
            rows["kind"] = np.where(motion[ri] == 0, MoveKind.RAPID, MoveKind.FEED)
            rows["start"] = starts
            rows["end"] = ends
            rows["wco"] = off
            rows["center"] = np.nan
            rows["plane"] = meta[7]
            rows["turns"] = 0
            rows["feed"] = np.where(motion[ri] == 0, 0.0, feed[ri])
            rows["inverse_time"] = 0.0
            rows["spindle"] = meta[2]
            rows["spindle_dir"] = meta[3]
            rows["tool"] = meta[4]
            rows["tool_length"] = meta[5]
            rows["coolant"] = meta[6]
            rows["dwell"] = 0.0
            it._table_lines[i:i + n] = line_no
            it._n += n
            del rows
        prev_motion = np.concatenate(([prev_m], motion[:-1]))
        prev_feed = np.concatenate(([prev_f], feed_word[:-1]))
        for k in np.flatnonzero((motion != prev_motion) | (feed_word != prev_feed)):
            changes.append((a + int(k) + 1, int(motion[k]), float(feed_word[k])))
        pos = end[-1].copy()
        mo = int(motion[-1])
        fw = float(feed_word[-1])
        fset = bool(feed_set[-1])
        prev_m, prev_f = mo, fw
    for line, m, f in changes:
        it.motion = m
        it.feed_word = f
        it.main_line = it.line = line
        snapshot()
    it.pos = [float(v) for v in pos]
    it.motion = mo
    it.feed_word = fw
    it.feed_set = fset
    it.line = it.main_line = stop
    snapshot()
    return True
