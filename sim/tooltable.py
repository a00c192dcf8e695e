"""LinuxCNC tool-table files: ``T<n> P<pocket> D<diameter> Z<offset> ... ;comment``.

One tool per line; words in any order, separated by blanks; ``;`` starts the comment
(the tool's description). Blank lines and lines holding only a comment are skipped.
Words: ``T`` tool number (required), ``P`` pocket, ``X Y Z A B C U V W`` offsets,
``D`` diameter, ``I`` front angle, ``J`` back angle, ``Q`` orientation (lathe).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from sim.errors import InputError

_WORD = re.compile(r"([A-Za-z])\s*([+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)$")
_LINEAR = "XYZUVW"
_ANGULAR = "ABC"
UNITS = {"mm": 1.0, "inch": 25.4, "in": 25.4}


@dataclass(frozen=True)
class ToolEntry:
    """One row of a tool table, lengths in mm (converted from the table's units).

    ``offsets`` holds the X Y Z U V W offsets (mm) and A B C (degrees) that were given;
    ``z_offset`` is the tool length offset (``offsets['Z']``, 0 when absent).
    """

    number: int
    pocket: int
    diameter: float = 0.0
    z_offset: float = 0.0
    offsets: dict = field(default_factory=dict)
    front_angle: float | None = None
    back_angle: float | None = None
    orientation: int | None = None
    comment: str = ""
    line: int = 0

    @property
    def radius(self) -> float:
        return self.diameter / 2.0

    def guess_kind(self) -> str:
        """A tool kind guessed from the comment: ball, vbit, drill or flat."""
        c = self.comment.lower()
        if "ball" in c:
            return "ball"
        if "bull" in c or "corner radius" in c:
            return "bull"
        if any(w in c for w in ("v-bit", "vbit", "v bit", "chamfer", "engrav")):
            return "vbit"
        if "drill" in c:
            return "drill"
        return "flat"


def read_tool_table(path, units: str = "mm") -> dict[int, ToolEntry]:
    """Read a LinuxCNC tool table; return ``{tool number: ToolEntry}`` with lengths in mm.

    ``units`` is what the numbers in the file are in: ``"mm"`` or ``"inch"`` (LinuxCNC's
    standalone interpreter reads tables as inches). Raises :class:`InputError` naming
    ``file:line`` and the field for a bad word, a missing ``T``, a duplicate tool number
    or a negative diameter.
    """
    if units not in UNITS:
        raise InputError(f"tool table units must be 'mm' or 'inch', got {units!r}")
    scale = UNITS[units]
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise InputError(f"cannot read tool table: {exc.strerror or exc}", where=str(path)) from None
    table: dict[int, ToolEntry] = {}
    for lineno, raw in enumerate(text.splitlines(), start=1):
        body, _, comment = raw.partition(";")
        body = body.strip()
        if not body:
            continue
        where = f"{path}:{lineno}"
        words: dict[str, float] = {}
        if re.search(r"[^A-Za-z0-9.+\-eE\s]", body):
            bad = re.search(r"[^A-Za-z0-9.+\-eE\s]", body).group(0)
            raise InputError(f"unexpected character {bad!r}: expected words like T1 P1 D6 Z0", where=where)
        # words may be glued ("T1P1") or spaced ("T1 P1", "Z +0.5")
        for tok in re.findall(r"[A-Za-z]\s*[^A-Za-z\s]*", body):
            m = _WORD.match(tok.strip())
            if not m:
                raise InputError(f"bad word {tok.strip()!r}: expected a letter and a number "
                                 "(T P D X Y Z A B C U V W I J Q)", where=where)
            letter, value = m.group(1).upper(), float(m.group(2))
            if letter not in "TPDXYZABCUVWIJQ":
                raise InputError(f"unknown word {letter}: expected one of T P D X Y Z A B C U V W I J Q",
                                 where=where)
            if letter in words:
                raise InputError(f"word {letter} given twice", where=where)
            if not math.isfinite(value):
                raise InputError(f"{letter} must be a finite number", where=where)
            words[letter] = value
        if "T" not in words:
            raise InputError("missing T word (tool number)", where=where)
        t = words["T"]
        if t != int(t) or t < 0:
            raise InputError(f"T must be a non-negative integer, got {t:g}", where=where)
        t = int(t)
        if t in table:
            raise InputError(f"tool T{t} already defined on line {table[t].line}", where=where)
        p = words.get("P", float(t))
        if p != int(p) or p < 0:
            raise InputError(f"P (pocket) must be a non-negative integer, got {p:g}", where=where)
        d = words.get("D", 0.0) * scale
        if d < 0:
            raise InputError(f"D (diameter) must be >= 0, got {words['D']:g}", where=where)
        offsets = {k: (v * scale if k in _LINEAR else v) for k, v in words.items()
                   if k in _LINEAR + _ANGULAR}
        q = words.get("Q")
        table[t] = ToolEntry(
            number=t, pocket=int(p), diameter=d, z_offset=offsets.get("Z", 0.0), offsets=offsets,
            front_angle=words.get("I"), back_angle=words.get("J"),
            orientation=None if q is None else int(q), comment=comment.strip(), line=lineno)
    return table


def tool_from_entry(entry: ToolEntry, kind: str | None = None, flute_length: float | None = None):
    """A :class:`sim.tools.Tool` for a table row (kind guessed from the comment unless given).

    Raises :class:`InputError` when the row has no usable diameter.
    """
    from sim.tools import DEFAULT_DRILL_ANGLE, Tool

    kind = kind or entry.guess_kind()
    if not entry.diameter > 0:
        raise InputError(f"tool T{entry.number} has no diameter (D) in the tool table", where=f"line {entry.line}")
    D = entry.diameter
    angle = {"vbit": 90.0, "drill": DEFAULT_DRILL_ANGLE}.get(kind, 0.0)
    rc = D / 4.0 if kind == "bull" else 0.0
    L = flute_length or max(4.0 * D, D)
    return Tool(kind, D, L, corner_radius=rc, angle=angle, number=entry.number,
                name=entry.comment or f"T{entry.number}")
