"""Bulk interpretation of runs of simple lines (bit-identical to the per-line path).

Most of a CAM program's lines are ``[N..] [G0|G1] [X..] [Y..] [Z..] [F..]`` in absolute
mode. Such lines are recognised and their numbers parsed with vectorised numpy over the
raw bytes, a chunk of lines at a time, and executed in bulk straight into the
interpreter's move table. The float operations are exactly the per-line interpreter's
(``work = value * units``, ``machine = work + offset``, missing axes carried as
``(machine - offset) + offset``), so the rows are identical bit for bit. Everything else
(expressions, comments, other words, G91, comp, inverse time...) goes through the full
interpreter.

Memory is what this module is about: a program is held once, as its UTF-8 bytes plus one
int32 offset per line (:class:`SourceLines`); no Python object is made per simple line
and every temporary array is bounded by :data:`CHUNK` lines. numba is deliberately not
used here: importing it costs ~170 MB of resident memory, more than the whole budget of
interpreting a million lines beside the 226 MB move table.
"""

from __future__ import annotations

import re

import numpy as np

from sim.gcode.limits import MAX_LINEAR_MM
from sim.gcode.moves import MoveKind

#: lines scanned and executed per chunk (bounds the temporaries: a few MB at most)
CHUNK = 1 << 13
#: longest number (sign excluded) the scanner parses; longer ones go to the per-line path
MAX_NUMBER_CHARS = 17

_POW10_F = np.array([10.0 ** k for k in range(23)])            # exact doubles 1e0 .. 1e22
_TWO53 = 1 << 53
_ODD_BREAKS = re.compile("[\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029]")
_ODD_BREAKS_ASCII = (b"\x0b", b"\x0c", b"\x1c", b"\x1d", b"\x1e")  # `in` on bytes is a memchr

# byte classes of the scanner, ordered so that each test is one comparison
_DIGIT, _DOT, _SIGN, _SPACE = 0, 1, 2, 3   # digit or dot: cls <= _DOT
_LETTER0 = 4                               # 4 + slot: G X Y Z F N (slots 0..5)
_EOL, _OTHER_LETTER, _OTHER = 10, 11, 12   # not simple: cls > _EOL
_SLOTS = "GXYZFN"
_N_SLOT = 5


def _byte_classes() -> np.ndarray:
    lut = np.full(256, _OTHER, dtype=np.uint8)
    lut[[ord(" "), ord("\t")]] = _SPACE
    lut[ord("0"):ord("9") + 1] = _DIGIT
    lut[ord(".")] = _DOT
    lut[[ord("+"), ord("-")]] = _SIGN
    for c in range(26):
        lut[ord("A") + c] = lut[ord("a") + c] = _OTHER_LETTER
    for slot, ch in enumerate(_SLOTS):
        lut[ord(ch)] = lut[ord(ch.lower())] = _LETTER0 + slot
    lut[[10, 13]] = _EOL  # a CR only ever precedes the LF here (see split_lines)
    return lut


_CLASS = _byte_classes()


class SourceLines:
    """The lines of a program held as UTF-8 bytes and line offsets; a line's str is made on demand.

    Behaves like ``text.splitlines()``: ``len``, indexing (str), slicing (list), iteration.
    ``starts`` (n + 1,) int32/int64: line ``i`` is ``data[starts[i]:starts[i + 1] - 1]``
    less a trailing CR.
    """

    def __init__(self, data: bytes, starts: np.ndarray):
        self.data = data
        self.starts = starts

    def __len__(self) -> int:
        return len(self.starts) - 1

    def span(self, i: int) -> tuple[int, int]:
        """Byte offsets ``(begin, end)`` of line ``i`` (end excludes CR LF)."""
        s, e = int(self.starts[i]), int(self.starts[i + 1]) - 1
        if e > s and self.data[e - 1] == 13:
            e -= 1
        return s, e

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        n = len(self)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError("line index out of range")
        s, e = self.span(i)
        return self.data[s:e].decode("utf-8", "surrogatepass")

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]

    def find_byte_lines(self, chars: bytes) -> np.ndarray:
        """Sorted indices (int64) of the lines holding any of the ASCII bytes ``chars``."""
        lines = []
        for a, chunk in _byte_chunks(self.data):
            hit = chunk == chars[0]
            for c in chars[1:]:
                hit |= chunk == c
            pos = np.flatnonzero(hit)
            if len(pos):
                lines.append(np.unique(self.line_of(pos + a)))
        return np.unique(np.concatenate(lines)) if lines else np.zeros(0, np.int64)

    def line_of(self, offsets) -> np.ndarray:
        """Line index (int64) of each byte offset in ``offsets``."""
        return np.searchsorted(self.starts, np.asarray(offsets), side="right") - 1


def split_lines(text) -> SourceLines:
    """A program's lines, like ``str.splitlines()`` of its text, without a str per line.

    ``text`` is a str, or bytes (decoded as UTF-8, invalid bytes replaced). Texts whose
    only line breaks are LF or CR LF keep their bytes as they are; any other break
    (lone CR, VT, FF, U+2028 ...) is normalised to LF first, so line numbers are those
    of ``splitlines()`` either way.
    """
    if isinstance(text, (bytes, bytearray, memoryview)):
        data = bytes(text)
        if not data.isascii() or any(c in data for c in _ODD_BREAKS_ASCII) or data.count(b"\r") != data.count(b"\r\n"):
            return split_lines(data.decode("utf-8", errors="replace"))
    elif _ODD_BREAKS.search(text) or text.count("\r") != text.count("\r\n"):
        data = "\n".join(text.splitlines()).encode("utf-8", "surrogatepass")
    else:
        data = text.encode("utf-8", "surrogatepass")
    n_nl = data.count(b"\n")
    tail = bool(data) and data[-1:] != b"\n"  # a last line without a newline
    starts = np.empty(1 + n_nl + tail, dtype=np.int32 if len(data) < 2**31 - 2 else np.int64)
    starts[0] = 0
    k = 1
    for a, chunk in _byte_chunks(data):  # small temporaries (see _byte_chunks)
        nl = np.flatnonzero(chunk == 10)
        starts[k:k + len(nl)] = nl + (a + 1)
        k += len(nl)
    if tail:
        starts[k] = len(data) + 1
    return SourceLines(data, starts)


def _byte_chunks(data: bytes, step: int = 1 << 20):
    """``(offset, uint8 view)`` pieces of ``data``.

    Whole-text temporaries (a bool per byte, an int64 per hit) would also raise glibc's
    dynamic mmap threshold, after which tens of MB of freed chunk temporaries stay resident.
    """
    for a in range(0, len(data), step):
        yield a, np.frombuffer(data, dtype=np.uint8, count=min(step, len(data) - a), offset=a)


def _is_word_letter(c: np.ndarray) -> np.ndarray:
    return (c - np.uint8(_LETTER0)) < 6  # uint8 wraps below _LETTER0


def scan(lines: SourceLines, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
    """Find the simple lines among lines ``a:b`` and parse their numbers.

    Returns ``simple`` (b - a,) bool and ``values`` (b - a, 5) float64: the G, X, Y, Z, F
    values as written (NaN when absent or the line is not simple). A simple line has
    only N G X Y Z F words (any order, each at most once, at least one besides N), G0 or
    G1, N a non-negative integer, numbers ``[+-]digits[.digits]`` of at most
    :data:`MAX_NUMBER_CHARS` characters whose digits fit 2**53: such a number divided
    by an exact power of ten is the correctly rounded double, the same as ``float()``.
    Anything else is left to the per-line parser, so this only has to be sound.
    """
    nl = b - a
    simple = np.zeros(nl, dtype=np.bool_)
    vals = np.full((nl, 5), np.nan)
    if nl <= 0:
        return simple, vals
    s0 = int(lines.starts[a])
    L = min(int(lines.starts[b]), len(lines.data)) - s0
    # classes of the chunk's bytes, padded with EOL so reads past the end (and at -1, -2) are EOL
    cls = np.full(L + MAX_NUMBER_CHARS + 3, _EOL, dtype=np.uint8)
    cls[:L] = _CLASS[np.frombuffer(lines.data, dtype=np.uint8, count=L, offset=s0)]
    body = cls[:L]
    rel = lines.starts[a:b + 1] - s0

    def line_at(pos):
        return np.searchsorted(rel, pos, side="right") - 1

    bad = np.zeros(nl, dtype=np.bool_)
    bad[line_at(np.flatnonzero(body > _EOL))] = True
    # every sign must follow a word letter; every run of digits and dots must follow one
    # (or a sign that does): then each number belongs to a word
    signs = np.flatnonzero(body == _SIGN)
    bad[line_at(signs[~_is_word_letter(cls[signs - 1])])] = True
    isnum = body <= _DOT
    runs = np.flatnonzero(isnum[1:] & ~isnum[:-1]) + 1
    if L and isnum[0]:
        runs = np.concatenate(([0], runs))
    before = cls[runs - 1]
    owned = _is_word_letter(before) | ((before == _SIGN) & _is_word_letter(cls[runs - 2]))
    bad[line_at(runs[~owned])] = True

    # the words: a letter, an optional sign, then digits and dots parsed one column at a
    # time (Horner: exact in int64 for 17 digits; no (words, 17) matrices)
    pos = np.flatnonzero(_is_word_letter(body))
    slot = cls[pos] - np.uint8(_LETTER0)
    line = line_at(pos)
    signed = cls[pos + 1] == _SIGN
    q = pos + 1 + signed
    T = len(q)
    m = np.zeros(T, dtype=np.int64)
    nd = np.zeros(T, dtype=np.int64)
    frac = np.zeros(T, dtype=np.int64)
    ndot = np.zeros(T, dtype=np.int64)
    length = np.zeros(T, dtype=np.int64)
    alive = np.ones(T, dtype=np.bool_)
    raw = np.frombuffer(lines.data, dtype=np.uint8, count=L, offset=s0)
    for j in range(MAX_NUMBER_CHARS + 1):
        c = cls[q + j]
        alive &= c <= _DOT
        if not alive.any():
            break
        if j == MAX_NUMBER_CHARS:  # longer numbers are left to the per-line parser
            bad[line[alive]] = True
            break
        d = alive & (c == _DIGIT)
        m = np.where(d, m * 10 + (raw[np.minimum(q + j, L - 1)] - 48), m)
        nd += d
        frac += d & (ndot > 0)
        ndot += alive & (c == _DOT)
        length += alive
    word_bad = (nd == 0) | (ndot > 1) | (m > _TWO53) | (cls[q + length] == _SIGN)
    bad |= (np.bincount(line * 6 + slot, minlength=6 * nl).reshape(nl, 6) > 1).any(axis=1)
    v = m.astype(np.float64) / _POW10_F[frac]
    v = np.where(signed & (raw[np.minimum(pos + 1, L - 1)] == 45), -v, v)
    is_g = slot == 0
    word_bad |= is_g & (v != 0.0) & (v != 1.0)
    is_n = slot == _N_SLOT
    word_bad |= is_n & ((v != np.floor(v)) | (v < 0.0) | (v > 9999999.0))
    bad[line[word_bad]] = True
    useful = np.bincount(line[~is_n], minlength=nl) > 0
    simple = ~bad & useful
    keep = ~is_n & simple[line]
    vals[line[keep], slot[keep]] = v[keep]
    return simple, vals


class ChunkScanner:
    """Scan results for the chunk of :data:`CHUNK` lines holding a given line.

    The last two chunks are kept: a loop whose body straddles a chunk boundary goes back
    and forth between two chunks on every pass, and must not rescan them each time.
    """

    def __init__(self, lines: SourceLines):
        self.lines = lines
        self.kept: list[tuple] = []  # (a, simple, values, run_end), newest last

    def at(self, i: int):
        """``(a, simple, values, run_end)`` of the chunk starting at line ``a`` that holds line ``i``.

        ``run_end[k]``: chunk index of the first non-simple line at or after ``k`` (or the
        chunk length).
        """
        a = i - i % CHUNK
        for got in self.kept:
            if got[0] == a:
                return got
        b = min(a + CHUNK, len(self.lines))
        simple, values = scan(self.lines, a, b)
        not_simple = np.flatnonzero(~simple)
        ends = np.append(not_simple, b - a)
        run_end = ends[np.searchsorted(not_simple, np.arange(b - a), side="left")]
        self.kept = self.kept[-1:] + [(a, simple, values, run_end)]
        return self.kept[-1]


def _carry(off: float, p: np.ndarray) -> np.ndarray:
    """One line's update of an axis with no word on it: ``(machine - offset) + offset``."""
    return (p - off) + off


def run_simple(it, vals: np.ndarray, first: int, snapshot) -> bool:
    """Execute simple main-file lines in bulk on interpreter ``it``.

    ``vals`` (k, 5) G X Y Z F values of lines ``first .. first + k - 1`` (0-based) from
    :func:`scan`. Returns False (having done nothing) when the state or the lines need
    the full interpreter: not absolute mode, comp on or the tool left off the program position
    by G40, inverse time or feed per rev, a feed move with no feed rate, a negative F.
    """
    if it.distance != 900 or it.comp != 400 or it.feed_mode != 940 or it.ended or it.tool_pos is not None:
        return False
    k = len(vals)
    gcol, fcol = vals[:, 0], vals[:, 4]
    has_g = ~np.isnan(gcol)
    if it.motion not in (0, 10) and not has_g[0]:
        return False
    has_f = ~np.isnan(fcol)
    if (fcol[has_f] < 0).any():
        return False
    idx = np.arange(k)
    # modal motion (0 or 10) and feed word of every line, carried from the interpreter
    last_g = np.maximum.accumulate(np.where(has_g, idx, -1))
    mo0 = it.motion if it.motion in (0, 10) else -1
    motion = np.where(last_g >= 0, np.where(gcol[np.maximum(last_g, 0)] == 0.0, 0, 10), mo0)
    last_f = np.maximum.accumulate(np.where(has_f, idx, -1))
    feed_word = np.where(last_f >= 0, fcol[np.maximum(last_f, 0)], it.feed_word)
    feed_set = (last_f >= 0) | it.feed_set
    feed = feed_word * it.factor
    moved = ~np.isnan(vals[:, 1:4]).all(axis=1)
    is_feed = moved & (motion == 10)
    if (is_feed & ((feed <= 0) | (~feed_set if it.grbl else False))).any():
        return False  # the per-line path reports the error at its line
    ri = np.flatnonzero(moved)
    n = len(ri)
    off = np.array(it.offsets(), dtype=np.float64)
    pos0 = np.array(it.pos, dtype=np.float64)
    end = np.empty((n, 6))
    if n:
        for i in range(6):
            if i < 3:
                w = vals[ri, 1 + i]
                given = ~np.isnan(w)
                base = w * it.factor + off[i]
                last = np.maximum.accumulate(np.where(given, np.arange(n), -1))
                carried = _carry(off[i], np.where(last >= 0, base[np.maximum(last, 0)], pos0[i]))
                col = np.where(given, base, carried)
                missing = ~given
            else:
                col = np.full(n, _carry(off[i], pos0[i]))
                missing = np.ones(n, dtype=np.bool_)
            # one carry is a fixed point of the next (so k carries = one); checked, not assumed
            if not np.array_equal(_carry(off[i], col[missing]), col[missing]):
                return False
            end[:, i] = col
        if not (np.abs(end[:, :3]) <= MAX_LINEAR_MM).all():
            return False  # the per-line path refuses the coordinate at its line
    meta = it.meta()
    it._seal()
    if n:
        j = it.reserve(n)
        rows = it._table[j:j + n]
        rows["end"] = end
        rows["start"][0] = pos0
        rows["start"][1:] = end[:-1]
        line_no = (first + 1 + ri).astype(np.int32)
        rows["file"] = meta[0]
        rows["line"] = line_no
        rows["kind"] = np.where(motion[ri] == 0, MoveKind.RAPID, MoveKind.FEED)
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
        it._table_lines[j:j + n] = line_no
        it._n += n
        del rows
    # a modal state snapshot wherever motion or feed word changes, as the per-line path does
    prev_motion = np.concatenate(([it.motion], motion[:-1]))
    prev_feed = np.concatenate(([it.feed_word], feed_word[:-1]))
    for c in np.flatnonzero((motion != prev_motion) | (feed_word != prev_feed)):
        it.motion = int(motion[c])
        it.feed_word = float(feed_word[c])
        it.main_line = it.line = first + int(c) + 1
        snapshot()
    if n:
        it.pos = [float(v) for v in end[-1]]
        it.canon_tlo = it.tlo   # a motion carries the offsets in force (tool_length)
    if n or has_g.any():
        it.cycle.il = None      # a G0/G1 motion ends a sequence of canned cycles
    it.motion = int(motion[-1])
    it.feed_word = float(feed_word[-1])
    it.feed_set = bool(feed_set[-1])
    it.line = it.main_line = first + k
    snapshot()
    return True
