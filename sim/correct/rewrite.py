"""Write a corrected path back into the program's own text.

Every line the correction does not touch is kept byte for byte. A line whose move changed
gets its X Y Z words replaced by the first point of its corrected move and keeps
everything else it says (G and M words, F, S, comments); the further points follow it as
new lines in the same motion mode. Changed lines end with ``(dexmon: corrected line N)``,
new ones with ``(dexmon: inserted for line N)``, N the original line. A straight line that
omits an axis the correction moved before it gets that axis written out (G90), and a G91
line after a moved point gets its increments from where the tool now stands. With
``--linearize`` an arc line that must change is written as G1 chords, and the next line
that leaned on its modal G2/G3 says it again.

Coordinates are written in the line's units (G20: inches) and work system, from the
row's own work offset (``machine - wco``, the interpreter's), with :data:`DECIMALS`
decimals; Z is rounded up, never down, so rounding cannot deepen a cut.

What cannot be rewritten safely is refused with an :class:`~sim.errors.InputError`
naming ``file:line``: a change inside a subroutine file or an o-word loop, a line whose
coordinates are expressions, a line with G53 / G28 / G30 / G92 / G10 / a canned cycle /
a probe, G93 inverse time, cutter compensation, block delete, a program end or a rotary
move on a line that must become several.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from sim.correct.path import SAME_POINT, Correction
from sim.errors import InputError
from sim.gcode.moves import MoveKind
from sim.gcode.parser import parse_line

#: decimals written per unit (mm: 0.1 um; inch: 0.25 um)
DECIMALS = {"mm": 4, "inch": 5}
#: G codes a rewritten line may carry (they take effect before its motion, or are modal
#: settings the new lines after it inherit)
SAFE_G = {0.0, 1.0, 4.0, 17.0, 18.0, 19.0, 20.0, 21.0, 40.0, 43.0, 49.0, 54.0, 55.0, 56.0, 57.0, 58.0, 59.0,
          59.1, 59.2, 59.3, 61.0, 61.1, 64.0, 90.0, 91.0, 90.1, 91.1, 94.0}
#: M codes that end or pause the program: a line carrying one cannot become several
STOP_M = {0.0, 1.0, 2.0, 30.0, 60.0}

_AXIS_WORD = re.compile(r"[XYZxyz][ \t]*([+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+))")


@dataclass
class Rewrite:
    """The new program text and what changed: ``changed`` original lines (1-based),
    ``inserted`` new lines."""

    text: bytes
    changed: list = field(default_factory=list)
    inserted: int = 0


def rewrite_program(data: bytes, filename: str, program, correction: Correction, to_prog: np.ndarray,
                    moves: np.ndarray | None = None) -> Rewrite:
    """The corrected program.

    ``data``: the main file's bytes; ``program``: its :class:`sim.gcode.Program`;
    ``moves``: the table the correction ran on, in the program's row order (default
    ``program.moves``; with ``--linearize`` the table with arcs as chords, whose rows keep
    their arc's line); ``to_prog`` (n, 3) mm: what turns a corrected tip of row k into
    the program's work coordinates of that row.
    """
    text = data.decode("utf-8", "surrogateescape")
    if text.startswith("\ufeff"):
        bom, text = "\ufeff", text[1:]
    else:
        bom = ""
    lines = text.splitlines(keepends=True)
    moves = program.moves if moves is None else moves
    from_arc = _arc_lines(program.moves, moves)
    plan = _plan(moves, from_arc, correction, lines, program, filename)
    out = Rewrite(b"")
    new_lines = list(lines)
    restate = None  # (G2 or G3, line): the modal arc the chords of a line replaced
    for idx, raw in enumerate(lines):
        line = idx + 1
        rows = plan.get(line)
        if rows is None:
            if restate is not None:
                new_lines[idx], restate = _restate_arc(raw, restate, program.dialect)
                if new_lines[idx] is not raw:
                    out.changed.append(line)
            continue
        if from_arc[rows[0]]:
            new_lines[idx], code = _rewrite_arc_line(raw, line, rows, moves, correction, to_prog, program, filename)
            restate = (code, line)
        else:
            new_lines[idx] = _rewrite_line(raw, line, rows, moves, correction, to_prog, program, filename)
            restate = None if _has_motion_word(raw, program.dialect) else restate
        out.changed.append(line)
        out.inserted += new_lines[idx].count("(dexmon: inserted for line")
    missing = [ln for ln in plan if not 0 < ln <= len(lines)]
    if missing:
        raise InputError("the correction changes a line the file does not have", where=f"{filename}:{missing[0]}")
    out.text = (bom + "".join(new_lines)).encode("utf-8", "surrogateescape")
    return out


def _arc_lines(prog_moves: np.ndarray, moves: np.ndarray) -> np.ndarray:
    """bool (n,): rows of ``moves`` that come from an arc of the program (its chords)."""
    arc = np.isin(prog_moves["kind"], (MoveKind.ARC_CW, MoveKind.ARC_CCW))
    keys = set(zip(prog_moves["file"][arc].tolist(), prog_moves["line"][arc].tolist()))
    if not keys:
        return np.zeros(len(moves), bool)
    return np.array([(f, ln) in keys for f, ln in zip(moves["file"].tolist(), moves["line"].tolist())], bool)


#: G codes of the motion group (a line naming one does not lean on the modal motion)
_MOTION_G = {0.0, 1.0, 2.0, 3.0, 5.0, 5.1, 5.2, 33.0, 33.1, 38.2, 38.3, 38.4, 38.5, 73.0, 76.0, 80.0, 81.0, 82.0,
             83.0, 84.0, 85.0, 86.0, 87.0, 88.0, 89.0}


def _has_motion_word(raw: str, dialect: str) -> bool:
    try:
        return any(g in _MOTION_G for g, _ in parse_line(raw.rstrip("\r\n"), dialect).g)
    except Exception:  # noqa: BLE001
        return True


def _restate_arc(raw: str, restate, dialect: str):
    """A line after arc chords: one leaning on the modal arc gets its G2/G3 back."""
    code, line = restate
    try:
        block = parse_line(raw.rstrip("\r\n"), dialect)
    except Exception:  # noqa: BLE001
        return raw, None
    if any(g in _MOTION_G for g, _ in block.g):
        return raw, None
    if not any(a in block.words for a in "XYZABCIJKR"):
        return raw, restate
    body, ending = _split_ending(raw)
    code_part, tail = _split_semicolon(body)
    return _join(f"{code} {code_part.lstrip()}", f"(dexmon: {code} restated after the chords of line {line})",
                 tail, ending), None


def _plan(moves, from_arc, correction: Correction, lines, program, filename) -> dict:
    """{line: [rows]} of the main-file lines that must be rewritten (refusing what
    cannot be)."""
    need = correction.changed.copy()
    moved = np.abs(correction.start - correction.orig_start) > SAME_POINT
    for k in np.flatnonzero(moved.any(axis=1) & ~need):
        k = int(k)
        if int(moves["kind"][k]) in (MoveKind.RAPID, MoveKind.FEED) and not from_arc[k]:
            # the row starts elsewhere than programmed: its line keeps its end only if it
            # names, absolutely, every axis that moved
            need[k] = not _keeps_end(moves, k, moved[k], lines, program)
        else:
            need[k] = True
    plan: dict = {}
    for k in np.flatnonzero(need):
        k = int(k)
        f, line = int(moves["file"][k]), int(moves["line"][k])
        if f != 0:
            files = getattr(program, "files", [])
            raise InputError("the correction has to change a move made in a subroutine file; correct it by hand",
                             where=f"{files[f] if f < len(files) else filename}:{line}")
        plan.setdefault(line, []).append(k)
    # a line run more than once (an o-word loop or subroutine) cannot be rewritten for one pass
    for line, rows in plan.items():
        same = np.flatnonzero((moves["file"] == 0) & (moves["line"] == line))
        if same.size and (same[-1] - same[0] + 1 != same.size):
            raise InputError("the correction has to change a line that runs more than once (an o-word loop or "
                             "subroutine); correct it by hand", where=f"{filename}:{line}")
        plan[line] = [int(r) for r in same]
    return dict(sorted(plan.items()))


def _keeps_end(moves, k: int, moved, lines, program) -> bool:
    """Row k, started from a moved point, still ends where programmed: a main-file G90
    line naming every moved axis."""
    line = int(moves["line"][k])
    if int(moves["file"][k]) != 0 or not 0 < line <= len(lines):
        return False
    try:
        block = parse_line(lines[line - 1].rstrip("\r\n"), program.dialect)
    except Exception:  # noqa: BLE001
        return False
    if program.state_at(line).distance == 910 or any(g == 53.0 for g, _ in block.g):
        return False
    return all(a in block.words for a, m in zip("XYZ", moved) if m)


def _rewrite_line(raw: str, line: int, rows, moves, correction: Correction, to_prog, program, filename) -> str:
    """A straight line: its X Y Z words go to the first corrected point, the others follow."""
    where = f"{filename}:{line}"
    body, ending = _split_ending(raw)
    code_part, comment_tail = _split_semicolon(body)
    block = _read(body, program, where)
    # a dwell, tool change or program end on the line happens before or after its motion
    rows = [k for k in rows if int(moves["kind"][k]) in _MOTION_KINDS]
    kinds = {int(moves["kind"][k]) for k in rows}
    if not kinds <= {int(MoveKind.RAPID), int(MoveKind.FEED)}:
        raise InputError("the correction has to change an arc, a canned cycle or a probe on this line; "
                         "give --linearize MM for arcs, or correct it by hand", where=where)
    if len(rows) != 1:
        raise InputError(f"the line makes {len(rows)} moves (G28/G30 or a cycle) and one of them needs a "
                         "correction; correct it by hand", where=where)
    st = _writable_state(block, program, line, where, SAFE_G)
    words = _coordinate_words(rows, correction, to_prog, st)
    if len(words) > 1 and any(m in STOP_M for m, _ in block.m):
        raise InputError("the line's move must become several but the line also stops or ends the program; "
                         "correct it by hand", where=where)
    if len(words) > 1 and any(a in block.words for a in "ABC"):
        raise InputError("the line's move must become several but it also turns a rotary axis; "
                         "correct it by hand", where=where)
    first = _replace_axes(code_part, words[0], where)
    out = [_join(first, f"(dexmon: corrected line {line})", comment_tail, ending)]
    motion = "G0" if int(moves["kind"][rows[0]]) == MoveKind.RAPID else "G1"
    out += [f"{motion} {w} (dexmon: inserted for line {line})" + (ending or "\n") for w in words[1:]]
    if not ending:
        out[-1] = out[-1].rstrip("\n")
    return "".join(out)


#: rows that move the tool
_MOTION_KINDS = {int(MoveKind.RAPID), int(MoveKind.FEED), int(MoveKind.ARC_CW), int(MoveKind.ARC_CCW),
                 int(MoveKind.PROBE)}

#: words an arc line may carry to be written as chords (its geometry, feed, line number)
_ARC_WORDS = set("XYZIJKRPFN")


def _rewrite_arc_line(raw: str, line: int, rows, moves, correction: Correction, to_prog, program, filename):
    """An arc line as G1 chords (``--linearize``): its corrected points, the first line
    keeping its modal G words and F. Returns the text and the arc's G code (G2/G3)."""
    where = f"{filename}:{line}"
    body, ending = _split_ending(raw)
    block = _read(body, program, where)
    other = sorted(set(block.words) - _ARC_WORDS)
    if other or block.m:
        what = other[0] if other else "M"
        raise InputError(f"the arc needs a correction but its line also carries {what} words; correct it by hand",
                         where=where)
    st = _writable_state(block, program, line, where, SAFE_G | {2.0, 3.0})
    if block.has_expr:
        raise InputError("the arc needs a correction but its words are expressions; correct it by hand",
                         where=where)
    code = "G2" if st.motion == 20 else "G3"
    words = _coordinate_words(rows, correction, to_prog, st)
    modal = " ".join(f"G{g:g}" for g, _ in block.g if g not in (2.0, 3.0))
    feed = f" F{block.words['F']:g}" if "F" in block.words else ""
    first = f"{modal + ' ' if modal else ''}G1 {words[0]}{feed} (dexmon: corrected line {line}, the arc as chords)"
    eol = ending or "\n"
    out = [first + eol] + [f"G1 {w} (dexmon: inserted for line {line})" + eol for w in words[1:]]
    if not ending:
        out[-1] = out[-1].rstrip("\n")
    return "".join(out), code


def _read(body: str, program, where: str):
    try:
        return parse_line(body, program.dialect)
    except Exception:  # noqa: BLE001 - the interpreter read it; a second reading cannot fail
        raise InputError("cannot read the line again to rewrite it", where=where) from None


def _writable_state(block, program, line: int, where: str, allowed_g: set):
    """The modal state the line's words are read in, refusing what cannot be rewritten."""
    if block.deleted:
        raise InputError("the line's move needs a correction but the line is under block delete ('/'); "
                         "correct it by hand", where=where)
    bad_g = sorted(g for g, _ in block.g if g not in allowed_g)
    if bad_g:
        raise InputError(f"the line's move needs a correction but it carries G{bad_g[0]:g}; correct it by hand",
                         where=where)
    if block.has_expr and any(a in block.words for a in "XYZ"):
        raise InputError("the line's move needs a correction but its coordinates are expressions; "
                         "correct it by hand", where=where)
    st = program.state_at(line)
    if st.feed_mode == 930:
        raise InputError("the line's move needs a correction but it is in G93 inverse time; correct it by hand",
                         where=where)
    if st.cutter_comp != 400:
        raise InputError("the line's move needs a correction but cutter compensation (G41/G42) is on; "
                         "correct it by hand", where=where)
    return st


def _coordinate_words(rows, correction: Correction, to_prog, st) -> list[str]:
    """The X Y Z words of every point the rows now visit, in the line's units and
    distance mode (G91: from where the tool stands)."""
    inch = not st.metric
    scale = 25.4 if inch else 1.0
    dec = DECIMALS["inch" if inch else "mm"]
    incremental = st.distance == 910
    prev = (correction.start[rows[0]] + to_prog[rows[0]]) / scale
    words = []
    for k in rows:
        pts = correction.points[k] if correction.points[k] is not None else correction.end[k][None, :]
        for p in pts:
            target = (p + to_prog[k]) / scale
            words.append(_xyz(target, prev, incremental, dec))
            prev = _as_written(target, prev, incremental, dec)
    return words


def _split_ending(raw: str) -> tuple[str, str]:
    body = raw.rstrip("\r\n")
    return body, raw[len(body):]


def _split_semicolon(body: str) -> tuple[str, str]:
    """The line before a ``;`` comment (outside parentheses) and the comment."""
    depth = 0
    for i, c in enumerate(body):
        if c == "(":
            depth = 1
        elif c == ")":
            depth = 0
        elif c == ";" and depth == 0:
            return body[:i], body[i:]
    return body, ""


def _axis_spans(code: str, where: str) -> list[tuple[int, int]]:
    """(start, end) of every X / Y / Z word outside comments."""
    spans = []
    i, n = 0, len(code)
    while i < n:
        c = code[i]
        if c == "(":
            j = code.find(")", i + 1)
            i = n if j < 0 else j + 1
            continue
        if c in "XYZxyz":
            m = _AXIS_WORD.match(code, i)
            if not m:
                raise InputError(f"cannot read the value of its {c.upper()} word", where=where)
            spans.append((i, m.end()))
            i = m.end()
            continue
        i += 1
    return spans


def _replace_axes(code: str, xyz: str, where: str) -> str:
    """``code`` with its X Y Z words taken out and ``xyz`` put where the first was (at the
    end when it had none); the blanks after a removed word go with it."""
    spans = _axis_spans(code, where)
    if not spans:
        return code.rstrip() + " " + xyz
    out = []
    last = 0
    for k, (a, b) in enumerate(spans):
        out.append(code[last:a])
        if k == 0:
            out.append(xyz + " ")
        while b < len(code) and code[b] in " \t":
            b += 1
        last = b
    out.append(code[last:])
    return "".join(out)


def _join(code: str, tag: str, semicolon: str, ending: str) -> str:
    return f"{code.rstrip()} {tag}{(' ' + semicolon) if semicolon else ''}{ending}"


def _fmt(v: float, dec: int) -> str:
    s = f"{v:.{dec}f}"
    return "0." + "0" * dec if s.startswith("-") and float(s) == 0.0 else s


def _round_up(v: float, dec: int) -> float:
    q = 10.0**dec
    return math.ceil(v * q - 1e-6) / q


def _xyz(target, prev, incremental: bool, dec: int) -> str:
    """The X Y Z words reaching ``target`` (program units) from ``prev``."""
    z = _round_up(float(target[2]), dec)
    if not incremental:
        return f"X{_fmt(target[0], dec)} Y{_fmt(target[1], dec)} Z{_fmt(z, dec)}"
    d = dec + 2  # increments carry more digits: their rounding errors add up
    return (f"X{_fmt(target[0] - prev[0], d)} Y{_fmt(target[1] - prev[1], d)} "
            f"Z{_fmt(_round_up(float(target[2] - prev[2]), d), d)}")


def _as_written(target, prev, incremental: bool, dec: int) -> np.ndarray:
    """Where the written words put the tool (program units)."""
    if not incremental:
        return np.array([round(float(target[0]), dec), round(float(target[1]), dec), _round_up(float(target[2]), dec)])
    d = dec + 2
    return prev + np.array([round(float(target[0] - prev[0]), d), round(float(target[1] - prev[1]), d),
                            _round_up(float(target[2] - prev[2]), d)])
