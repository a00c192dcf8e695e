"""One line of G-code text -> a :class:`Block` of words (values or expression trees).

LinuxCNC's rules: case and whitespace do not matter outside comments, ``( )`` comments
do not nest, ``;`` comments run to the end of the line, ``/`` first means block delete,
values may be numbers, ``#`` parameters or ``[ ]`` expressions. Parameter settings are
collected and applied after the line is read. The grbl dialect accepts only numbers and
refuses the rest with GRBL 1.1's error numbers.

Expression trees are tuples evaluated by :mod:`sim.gcode.expr`:
``("p", index_tree)`` numbered parameter, ``("n", name)`` named parameter,
``("b", op, a, b)`` binary operator, ``("f", name, a)`` unary function,
``("atan", a, b)``, ``("neg", a)``, ``("exists", name)``; plain floats are constants.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from sim.gcode.errors import LineError

_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)")  # ASCII digits only: "１２" is no number
_UNARY = ("ABS", "ACOS", "ASIN", "ATAN", "COS", "EXP", "FIX", "FUP", "LN", "ROUND", "SIN", "SQRT", "TAN", "EXISTS")
# binary operators by precedence (lowest first), as RS274NGC groups them
_BINARY_LEVELS = (
    ("AND", "OR", "XOR"),
    ("EQ", "NE", "GT", "GE", "LT", "LE"),
    ("+", "-"),
    ("*", "/", "MOD"),
    ("**",),
)
_OP_NAMES = sorted({op for level in _BINARY_LEVELS for op in level}, key=len, reverse=True)
_OWORD_KEYWORDS = (
    "ENDSUB", "SUB", "CALL", "RETURN", "ENDWHILE", "WHILE", "DO", "ENDIF", "ELSEIF", "ELSE", "IF",
    "ENDREPEAT", "REPEAT", "BREAK", "CONTINUE",
)
AXES = "XYZABC"
#: bracket nesting of one expression (:class:`sim.gcode.limits.Limits` ``max_nesting``)
MAX_NESTING = 64


@dataclass(slots=True)
class Block:
    """The words of one line. Values are floats or expression trees (tuples)."""

    words: dict = field(default_factory=dict)   # letter -> value (not G, M, N, O)
    cols: dict = field(default_factory=dict)    # letter -> 1-based column in the source
    g: list = field(default_factory=list)       # [(value, column)]
    m: list = field(default_factory=list)       # [(value, column)]
    assigns: list = field(default_factory=list)  # [(target tree, value, column)]
    oword: tuple | None = None   # (label, KEYWORD, [arg values], column)
    message: str | None = None   # (MSG, ...) text
    deleted: bool = False        # block delete '/'
    percent: bool = False        # a '%' delimiter line
    has_expr: bool = False       # some value needs evaluation
    empty: bool = True


def is_deleted(text: str) -> bool:
    """True when ``text`` starts with the block delete character '/' (after blanks): the
    line a controller with its block delete switch on drops before reading it."""
    return text.lstrip(" \t")[:1] == "/"


def strip_line(text: str, dialect: str = "linuxcnc") -> tuple[str, list[int], str | None, bool]:
    """Remove comments and whitespace; upper-case the rest.

    Returns ``(compressed, columns, message, deleted)`` where ``columns[i]`` is the
    1-based source column of ``compressed[i]`` and ``message`` the text of a
    ``(MSG, ...)`` comment (None when there is none).
    """
    out: list[str] = []
    cols: list[int] = []
    message = None
    i, n = 0, len(text)
    deleted = False
    commented = False  # a comment came first: a '/' after it is no block delete
    while i < n:
        c = text[i]
        if c == "(":
            j = text.find(")", i + 1)
            if j < 0:
                raise LineError("unclosed comment: '(' has no ')'", i + 1, grbl_code=1)
            body = text[i + 1 : j]
            if "(" in body and not dialect.startswith("grbl"):
                raise LineError("nested comment: '(' inside a comment", i + 2 + body.index("("), grbl_code=1)
            squeezed = body.lstrip()
            if squeezed[:4].upper() == "MSG," or re.match(r"(?i)msg\s*,", squeezed):
                message = squeezed.split(",", 1)[1].strip()
            i = j + 1
            commented = True
            continue
        if c == ";":
            break
        if c in " \t\r\n\f\v":
            i += 1
            continue
        if c == "/" and not out and not commented and not deleted:
            deleted = True
            i += 1
            continue
        out.append(c.upper())
        cols.append(i + 1)
        i += 1
    return "".join(out), cols, message, deleted


class _Reader:
    """Recursive-descent reader over one compressed line."""

    __slots__ = ("s", "cols", "i", "grbl", "has_expr", "depth", "max_depth")

    def __init__(self, s: str, cols: list[int], grbl: bool, max_depth: int = MAX_NESTING):
        self.s = s
        self.cols = cols
        self.i = 0
        self.grbl = grbl
        self.has_expr = False
        self.depth = 0             # brackets open around the reader
        self.max_depth = max_depth

    def col(self, i: int | None = None) -> int:
        i = self.i if i is None else i
        if not self.cols:
            return 1
        return self.cols[min(i, len(self.cols) - 1)] + (1 if i >= len(self.cols) else 0)

    def fail(self, message: str, grbl_code: int | None = None, at: int | None = None):
        raise LineError(message, self.col(at), grbl_code)

    def peek(self) -> str:
        return self.s[self.i] if self.i < len(self.s) else ""

    def number(self) -> float:
        m = _NUMBER.match(self.s, self.i)
        if not m:
            self.fail(f"expected a number, found {self._found()}", 2)
        self.i = m.end()
        return float(m.group())

    def _found(self) -> str:
        return repr(self.s[self.i]) if self.i < len(self.s) else "end of line"

    def value(self):
        """A real value: number, parameter, [expression], unary function, signed value."""
        c = self.peek()
        if not c:
            self.fail("expected a value, found end of line", 2)
        if self.grbl:
            return self.number()
        if c in "+-":
            nxt = self.s[self.i + 1 : self.i + 2]
            if "0" <= nxt <= "9" or nxt == ".":
                return self.number()
            self.i += 1
            v = self.value()
            if c == "-":
                return -v if isinstance(v, float) else ("neg", v)
            return v
        if c == "[":
            self.has_expr = True
            return self.expression()
        if c == "#":
            self.has_expr = True
            return self.parameter()
        if c.isalpha():
            for name in _UNARY:
                if self.s.startswith(name, self.i):
                    self.has_expr = True
                    return self.unary(name)
            self.fail(f"expected a value, found {self._found()}", 2)
        return self.number()

    def unary(self, name: str):
        self.i += len(name)
        if name == "EXISTS":
            if not self.s.startswith("[#<", self.i):
                self.fail("EXISTS needs [#<name>]")
            self.i += 1
            p = self.parameter()
            if self.peek() != "]" or p[0] != "n":
                self.fail("EXISTS needs [#<name>]")
            self.i += 1
            return ("exists", p[1])
        if self.peek() != "[":
            self.fail(f"{name} must be followed by '['")
        a = self.expression()
        if name == "ATAN":
            if self.peek() != "/":
                self.fail("ATAN needs the form ATAN[y]/[x]")
            self.i += 1
            if self.peek() != "[":
                self.fail("ATAN needs the form ATAN[y]/[x]")
            b = self.expression()
            return ("atan", a, b)
        return ("f", name, a)

    def _angle_name(self, start: int, what: str) -> str:
        """The lower-cased text of ``<name>`` (the reader stands on '<' and ends past
        '>'); a missing '>' fails at ``start``, naming ``what``."""
        j = self.s.find(">", self.i)
        if j < 0:
            self.fail(f"{what} has no closing '>'", at=start)
        name = self.s[self.i + 1 : j].lower()
        self.i = j + 1
        return name

    def parameter(self):
        start = self.i
        self.i += 1  # '#'
        c = self.peek()
        if c == "<":
            name = self._angle_name(start, "named parameter")
            if not name:
                self.fail("empty parameter name", at=start)
            return ("n", name)
        if c == "":
            self.fail("'#' must be followed by a parameter number or <name>", at=start)
        return ("p", self.value())

    def expression(self):
        """``[ ... ]`` with RS274NGC precedence; the reader stands on '['."""
        if self.depth >= self.max_depth:
            self.fail(f"expression nested more than {self.max_depth} brackets deep")
        self.depth += 1
        self.i += 1
        tree = self._level(0)
        if self.peek() != "]":
            self.fail(f"expected ']' or an operator, found {self._found()}")
        self.i += 1
        self.depth -= 1
        return tree

    def _level(self, level: int):
        if level == len(_BINARY_LEVELS):
            return self.value()
        left = self._level(level + 1)
        ops = _BINARY_LEVELS[level]
        while True:
            op = None
            for cand in _OP_NAMES:
                if cand in ops and self.s.startswith(cand, self.i):
                    if cand == "*" and self.s.startswith("**", self.i):
                        continue
                    op = cand
                    break
            if op is None:
                return left
            self.i += len(op)
            right = self._level(level + 1)
            left = ("b", op, left, right)

    def oword(self):
        """``O<label> KEYWORD [args]`` (the reader stands on 'O')."""
        start = self.i
        self.i += 1
        c = self.peek()
        if c == "<":
            label = self._angle_name(start, "o-word name")
        elif c == "#" or c == "[":
            v = self.value()
            label = v
        else:
            m = re.match(r"[0-9]+", self.s[self.i :])
            if not m:
                self.fail("o-word needs a number or <name>", at=start)
            label = str(int(m.group()))
            self.i += m.end()
        kw = None
        for name in _OWORD_KEYWORDS:
            if self.s.startswith(name, self.i):
                kw = name
                break
        word = re.match(r"[A-Z]*", self.s[self.i:]).group()
        if kw is None or word != kw:
            # rs274 reads the keyword and refuses what follows it ("callsub": call, then 'S')
            found = f"'{word.lower()}'" if word else self._found()
            self.fail(f"unknown o-word command {found} (expected sub, call, if, while, ...)")
        self.i += len(kw)
        args = []
        while self.i < len(self.s):
            if self.peek() != "[":
                self.fail(f"o-word arguments must be [expressions], found {self._found()}")
            args.append(self.expression())
            self.has_expr = True
        return (label, kw, args, self.col(start))


def dialect_parts(dialect: str) -> tuple[str, str]:
    """``(base dialect, rotary letters it accepts)``: ``"grbl+A"`` is the grbl dialect of a
    grblHAL with an A axis (it takes A words; plain ``"grbl"``, Grbl 1.1, takes none);
    ``"linuxcnc"`` accepts A B C. Raises ValueError for anything else."""
    base, plus, letters = str(dialect).partition("+")
    if base == "linuxcnc" and not plus:
        return base, "ABC"
    if base == "grbl" and (not plus or (letters and set(letters) <= set("ABC") and len(set(letters)) == len(letters))):
        return base, letters
    raise ValueError(f"unknown dialect {dialect!r}: expected 'linuxcnc', 'grbl' or 'grbl+' rotary letters "
                     f"(e.g. 'grbl+A', a grblHAL with an A axis)")


def parse_line(text: str, dialect: str = "linuxcnc") -> Block:
    """Parse one source line into a :class:`Block`; raises ``LineError`` on bad syntax."""
    try:
        return _parse_line(text, dialect)
    except RecursionError:
        raise LineError("expression nested too deeply", 1, grbl_code=1) from None


def _parse_line(text: str, dialect: str) -> Block:
    grbl = dialect.startswith("grbl")
    rotary = dialect[5:] if grbl else ""  # "grbl+A": the A word too (grblHAL)
    block = Block()
    stripped = text.strip()
    if stripped.startswith("%"):
        block.percent = True
        return block
    s, cols, message, deleted = strip_line(text, dialect)
    block.message = message
    block.deleted = deleted
    if not s:
        return block
    block.empty = False
    r = _Reader(s, cols, grbl)
    n = len(s)
    while r.i < n:
        c = s[r.i]
        at = r.i
        if c == "#" and not grbl:
            target = r.parameter()
            if r.peek() != "=":
                r.fail("expected '=' after the parameter to set")
            r.i += 1
            block.assigns.append((target, r.value(), r.col(at)))
            r.has_expr = True
            continue
        if c == "O" and not grbl:
            if block.words or block.g or block.m or r.i != 0 and s[0] != "N":
                r.fail("an o-word must be the only command on its line")
            block.oword = r.oword()
            continue
        if not ("A" <= c <= "Z") and not (c in "@^$" and not grbl):
            if grbl:
                r.fail(f"expected a command letter, found {c!r}", 1)
            r.fail(f"expected a word letter, found {c!r}")
        if grbl and c not in "FGIJKLMNPRSTXYZ" and c not in rotary:
            if c in "ABC":
                r.fail(f"GRBL does not support the {c} word (a grblHAL with a rotary {c} axis does: "
                       f"give [machine] kinematics with {c})", 20)
            r.fail(f"GRBL does not support the {c} word", 20)
        if c in "UVW" and not grbl:
            r.fail(f"{c} axis words are not supported by this machine (XYZABC)")
        if c not in "ABCDEFGHIJKLMNPQRSTXYZ@^$":
            r.fail(f"unknown word letter {c!r}")
        r.i += 1
        if r.i >= n:
            r.fail(f"{c} word has no value", 2)
        v = r.value()
        col = r.col(at)
        if c == "G":
            block.g.append((v, col))
        elif c == "M":
            block.m.append((v, col))
        elif c == "N":
            if grbl and isinstance(v, float) and (v != int(v) or v > 9999999 or v < 0):
                r.fail("line number must be an integer between 0 and 9999999", 27, at)
            block.words.setdefault("N", v)
            block.cols.setdefault("N", col)
        else:
            if c in block.words:
                r.fail(f"{c} word given twice on one line", 25, at)
            block.words[c] = v
            block.cols[c] = col
    block.has_expr = r.has_expr
    return block
