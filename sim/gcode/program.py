"""Whole programs: o-word control flow, subroutine files, the Program result.

``load_program(path)`` / ``interpret(text)`` run a program through an
:class:`~sim.gcode.interpreter.Interpreter` and return a :class:`Program` holding the
move table, the files it came from, the ``(MSG, ...)`` texts, the modal state history
and, with ``keep_going=True``, every error instead of only the first.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from sim.gcode.errors import GCodeError, LineError, ProgramFileError
from sim.gcode.expr import evaluate
from sim.gcode.interpreter import Interpreter
from sim.gcode.limits import Limits
from sim.gcode.parser import Block, is_deleted, parse_line
from sim.gcode.source_file import check_text, read_program
from sim.gcode.state import ModalState

SEAL_ROWS = 2048  # pending row tuples moved into the table this often
#: move kinds that move the machine (rapid, feed, both arcs, probe)
MOTION_KINDS = (0, 1, 2, 3, 6)

_STRUCT_OPEN = {"SUB", "IF", "WHILE", "DO", "REPEAT"}
_LOOPS = {"WHILE", "DO", "REPEAT"}


@dataclass
class _Source:
    """One file's lines, parsed once, with its o-word structure."""

    name: str
    index: int
    lines: object                                # SourceLines: str per line on demand
    blocks: dict = field(default_factory=dict)   # line -> Block or LineError (o-words, cached lines)
    end_of: dict = field(default_factory=dict)   # opening line -> closing line (indices)
    owner: dict = field(default_factory=dict)    # elseif/else/end/break/continue -> opening line
    branches: dict = field(default_factory=dict)  # if line -> [elseif/else lines]
    kind: dict = field(default_factory=dict)     # line -> structural keyword (DOWHILE for do's end)
    subs: dict = field(default_factory=dict)     # label -> sub line
    struct_errors: list = field(default_factory=list)  # (line index, LineError)
    warnings: list = field(default_factory=list)       # what LinuxCNC takes but a user should hear
    percent_end: int | None = None
    has_long_lines: bool = False  # lines over the limit: refused one by one, so no bulk fast path
    cached: object = None  # (n,) bool: lines whose parsed block is kept (loop/sub bodies); None = all
    block_delete: bool = False  # the switch is on: '/' lines are dropped unread

    def block(self, i: int, dialect: str):
        """Line ``i`` parsed (a Block, or the LineError it raised); kept only where it will be read again."""
        b = self.blocks.get(i)
        if b is None:
            text = self.lines[i]
            if self.block_delete and is_deleted(text):
                return _DROPPED
            try:
                b = parse_line(text, dialect)
            except LineError as exc:
                b = exc
            if self.cached is None or self.cached[i]:
                self.blocks[i] = b
        return b


#: what a line dropped by the block delete switch reads as (rs274 -b reads nothing of it)
_DROPPED = Block(deleted=True)

_OWORD_LINE = re.compile(r"[ \t]*(?:/[ \t]*)?(?:[Nn][ \t]*\d+[ \t]*)?[Oo]")


def oname(label: str) -> str:
    """An o-word label as a program spells it: ``o100``, ``o<probe_rect_pocket>``."""
    return f"o{label}" if label.isdigit() else f"o<{label}>"


def _percent_end(lines) -> int | None:
    """With a '%' as the first non-blank character, the line of the next '%' line (else None)."""
    data = lines.data
    pct = [m.start() for m in re.finditer(rb"%", data)]
    if not pct or data[:pct[0]].decode("utf-8", "surrogatepass").strip():
        return None
    first = int(lines.line_of(pct[0]))
    for i in sorted({int(i) for i in lines.line_of(pct[1:])}):
        if i > first and lines[i].lstrip().startswith("%"):
            return i
    return None


def _prepare(name: str, index: int, text, dialect: str, max_line_chars: int = Limits.max_line_chars,
             block_delete: bool = False) -> _Source:
    """Split ``text`` (str or UTF-8 bytes) into lines and find its o-word structure
    (with ``block_delete``, '/' lines are none of it)."""
    from sim.gcode.fastpath import split_lines

    lines = split_lines(text)
    del text  # the lines hold the only copy from here on
    src = _Source(name, index, lines, block_delete=block_delete)
    # lines are parsed when first executed; only o-word lines are needed up front
    blocks = src.blocks
    # an overlong line is refused where it runs (its bytes are never parsed)
    for i in np.flatnonzero(np.diff(lines.starts) - 1 > max_line_chars):
        n = int(lines.starts[i + 1] - lines.starts[i] - 1)
        blocks[int(i)] = LineError(f"line is {n} characters long; at most {max_line_chars} "
                                   "(LinuxCNC reads 255, GRBL 80)", 1)
    src.has_long_lines = bool(blocks)
    for i in lines.find_byte_lines(b"oO"):
        i = int(i)
        if i in blocks:
            continue
        raw = lines[i]
        if _OWORD_LINE.match(raw) and not (block_delete and is_deleted(raw)):
            try:
                blocks[i] = parse_line(raw, dialect)
            except LineError as exc:
                blocks[i] = exc
    # '%' delimiters: a first '%' line means the program ends at the next one
    src.percent_end = _percent_end(lines)
    stack: list[tuple[str, str, int]] = []  # (keyword, label, line index)
    for i in sorted(blocks):
        b = blocks[i]
        if isinstance(b, LineError) or b.oword is None:
            continue
        label, kw, _args, col = b.oword
        if not isinstance(label, str):
            if kw in _STRUCT_OPEN or kw.startswith("END") or kw in ("ELSE", "ELSEIF", "BREAK", "CONTINUE"):
                src.struct_errors.append((i, LineError("a computed o-word label can only be used with call", col)))
            continue
        src.kind[i] = kw
        if kw == "WHILE" and stack and stack[-1][0] == "DO" and stack[-1][1] == label:
            _, _, opener = stack.pop()
            src.end_of[opener] = i
            src.owner[i] = opener
            src.kind[i] = "DOWHILE"
            continue
        if kw in _STRUCT_OPEN:
            if kw == "SUB":
                # LinuxCNC reads sub lines as definitions only in the main file; in a sub
                # file it skips to the one called, and runs on through any other
                if stack and index == 0:
                    src.struct_errors.append((i, LineError(f"{oname(label)} sub inside {oname(stack[-1][1])} "
                                                           f"{stack[-1][0].lower()} (subroutines cannot nest)", col)))
                if label in src.subs:
                    src.struct_errors.append((i, LineError(f"{oname(label)} sub is defined twice (first on line "
                                                           f"{src.subs[label] + 1})", col)))
                src.subs.setdefault(label, i)
            stack.append((kw, label, i))
            if kw == "IF":
                src.branches[i] = []
            continue
        if kw in ("ENDSUB", "RETURN"):
            sub = next((s for s in reversed(stack) if s[0] == "SUB"), None)
            if sub is None:
                src.struct_errors.append((i, LineError(f"{oname(label)} {kw.lower()} outside any o-word sub", col)))
                continue
            if kw == "RETURN" or label != sub[1]:
                # LinuxCNC skips a definition up to the endsub of its own label; a sub being
                # run returns at the first return or endsub it meets, whatever its label
                src.kind[i] = "RETURN"
                continue
        closers = {"ENDSUB": "SUB", "ENDIF": "IF", "ENDWHILE": "WHILE", "ENDREPEAT": "REPEAT"}
        if kw in closers or kw in ("ELSE", "ELSEIF"):
            want = closers.get(kw, "IF")
            if not stack or stack[-1][0] != want or stack[-1][1] != label:
                opened = (f" ({oname(stack[-1][1])} {stack[-1][0].lower()} on line {stack[-1][2] + 1} is still open)"
                          if stack else "")
                src.struct_errors.append((i, LineError(f"{oname(label)} {kw.lower()} without a matching "
                                                       f"{oname(label)} {want.lower()}{opened}", col)))
                continue
            opener = stack[-1][2]
            src.owner[i] = opener
            if kw in ("ELSE", "ELSEIF"):
                br = src.branches[opener]
                if br and src.kind[br[-1]] == "ELSE":
                    src.struct_errors.append((i, LineError(f"{oname(label)} {kw.lower()} after {oname(label)} else",
                                                           col)))
                br.append(i)
            else:
                stack.pop()
                src.end_of[opener] = i
            continue
        if kw in ("BREAK", "CONTINUE"):
            loop = next((s for s in reversed(stack) if s[1] == label and s[0] in _LOOPS), None)
            if loop is None:
                src.struct_errors.append((i, LineError(f"{oname(label)} {kw.lower()} outside an {oname(label)} loop",
                                                       col)))
                continue
            src.owner[i] = loop[2]
    for kw, label, i in stack:
        close = {"SUB": "endsub", "IF": "endif", "WHILE": "endwhile", "DO": "while", "REPEAT": "endrepeat"}[kw]
        said = f"{oname(label)} {kw.lower()} is never closed (no {oname(label)} {close})"
        if kw == "SUB":
            # LinuxCNC skips the definition to the end of the file (and refuses nothing)
            src.end_of[i] = len(lines) - 1
            src.warnings.append(f"{name}:{i + 1}: {said}: the rest of the file is its body")
            continue
        src.struct_errors.append((i, LineError(said, blocks[i].oword[3])))
    src.struct_errors.sort(key=lambda e: e[0])
    if index == 0:
        # the main program runs top to bottom: only lines inside loops and subs run twice
        src.cached = np.zeros(len(lines), dtype=np.bool_)
        for opener, closer in src.end_of.items():
            if src.kind.get(opener) in ("SUB", "WHILE", "DO", "REPEAT"):
                src.cached[opener:closer + 1] = True
    return src


class Program:
    """The result of interpreting a program.

    Attributes
    ----------
    moves : MOVE_DTYPE array, one row per motion/dwell/tool change/stop.
    files : list[str], index = ``moves["file"]`` (0 = main program).
    errors : list[GCodeError], all errors when ``keep_going`` (else at most one, raised).
        Each error's ``rows_before`` is the number of rows made before it was met (None:
        found before the run, e.g. an o-word never closed).
    messages : list[(line, text)] from ``(MSG, ...)`` comments.
    warnings : list[str], e.g. a program that ends with no M2/M30/%.
    """

    def __init__(self, moves, files, errors, messages, warnings, snapshots, snapshot_lines, row_main_line,
                 dialect, machine_units):
        self.moves = moves
        self.files = files
        self.errors = errors
        self.messages = messages
        self.warnings = warnings
        self.dialect = dialect
        self.machine_units = machine_units
        self._snapshots = snapshots
        self._snap_lines = np.maximum.accumulate(np.asarray(snapshot_lines, dtype=np.int64)) if snapshot_lines else np.zeros(0, np.int64)
        row_main = np.array(row_main_line, dtype=np.int32, copy=None)
        self._row_main = np.maximum.accumulate(row_main, out=row_main)  # in place: no second table-sized array

    def __len__(self) -> int:
        return len(self.moves)

    @property
    def inch(self) -> bool:
        """True when the program works in inches (G20) anywhere (its table is in mm)."""
        return any(not s.metric for s in self._snapshots)

    def __repr__(self) -> str:
        return f"Program({self.files[0]!r}, {len(self.moves)} moves, {len(self.errors)} errors)"

    def state_at(self, line: int) -> ModalState:
        """Modal state just after main-file line ``line`` first executed (line 0 = start).

        Position and work position are those at the end of the last move of lines up
        to ``line``; in o-word loops this is the first pass through the line.
        """
        k = int(np.searchsorted(self._snap_lines, line, side="right")) - 1
        st = self._snapshots[max(k, 0)]
        st = replace(st, position=st.position.copy(), work_position=st.work_position.copy())
        r = int(np.searchsorted(self._row_main, line, side="right")) - 1
        if r >= 0:
            row = self.moves[r]
            st.position = np.array(row["end"], dtype=np.float64)
            st.work_position = st.position - st.work_offset - st.g92_offset - st.tool_offset
        st.line = int(line)
        return st

    def linearize(self, tolerance=None) -> np.ndarray:
        """Arcs -> chords within a chordal tolerance (mm, or a Tolerance); see :mod:`sim.gcode.linearize`."""
        from sim.gcode.linearize import linearize

        return linearize(self.moves, tolerance)

    def cycle_time(self, machine=None):
        """(total seconds, per-row seconds) as GRBL would plan it; see :mod:`sim.gcode.timing`."""
        from sim.gcode.timing import cycle_time

        return cycle_time(self.moves, machine)


class _Runner:
    def __init__(self, it: Interpreter, keep_going: bool, subroutine_path, fast: bool = True):
        self.it = it
        self.fast = fast
        self.keep_going = keep_going
        self.errors: list[GCodeError] = []
        self.defined: dict[str, tuple[int, int]] = {}  # sub label -> (source index, line index)
        self.scopes: list[str] = [""]   # the sub each call level runs ("" the program): o-word label scopes
        self.labels: dict[tuple[str, str], tuple[int, int]] = {}  # (scope, label) -> first (source, line) run
        self.sources: list[_Source] = []
        self.sub_path = [Path(p) for p in (subroutine_path or [])]
        self.limits = it.limits
        self.passes: dict = {}  # (call depth, file, loop's opening line) -> passes since it was entered
        self.snapshots: list[ModalState] = []
        self.snap_lines: list[int] = []
        self.last_key = None
        self.warnings: list[str] = []
        self.running = False

    def fail(self, src: _Source, i: int, exc: LineError, ahead: bool = False):
        i = getattr(exc, "line_index", i)  # a loop limit names the loop's opening line
        err = GCodeError(exc.message, src.name, i + 1, exc.column, src.lines[i] if i < len(src.lines) else "",
                         exc.grbl_code if self.it.grbl else None)
        if self.it.grbl and err.grbl_code is None:
            err.grbl_code = 20
        # the rows made before the error (what a controller made before it stopped); None for an
        # error found before the program runs
        err.rows_before = self.it._n + len(self.it._rows) if self.running and not ahead else None
        if not self.keep_going:
            raise err
        self.errors.append(err)

    def snapshot(self):
        key = self.it.modal_key()
        if key != self.last_key:
            self.last_key = key
            self.snapshots.append(self.it.state)
            self.snap_lines.append(self.it.main_line)

    def add_source(self, name: str, text: str) -> _Source:
        src = _prepare(name, len(self.sources), text, self.it.dialect, self.limits.max_line_chars,
                       self.it.block_delete)
        self.sources.append(src)
        if src.index >= len(self.it.files):
            self.it.files.append(name)
        for i, exc in src.struct_errors:
            self.fail(src, i, exc, ahead=src.index == 0)
        self.warnings.extend(src.warnings)
        return src

    def find_sub(self, label: str, src: _Source, col: int, pc: int):
        """(source, line index) of the sub a call on line index ``pc`` of ``src`` runs, found
        as LinuxCNC finds it: a sub already defined (its definition read, or an earlier call
        found it), else the file ``<label>.ngc`` of the subroutine path or the program's
        folder, else a definition further on in this file."""
        hit = self.defined.get(label)
        if hit is not None:
            return self.sources[hit[0]], hit[1]
        found = self.sub_file(label, col)
        if found is None and src.subs.get(label, -1) > pc:
            found = src, src.subs[label]
        if found is None:
            raise LineError(f"{oname(label)} call: no {oname(label)} sub in this program or the subroutine path",
                            col)
        self.defined[label] = (found[0].index, found[1])
        return found

    def sub_file(self, label: str, col: int):
        """(source, line index) of sub ``label`` in its file ``<label>.ngc``; None without one."""
        dirs = list(self.sub_path) + [Path(self.sources[0].name).parent]
        for d in dirs:
            for cand in (d / f"{label}.ngc", d / f"{label}.NGC"):
                if cand.is_file():
                    loaded = next((s for s in self.sources if s.name == str(cand)), None)
                    if loaded is None:
                        try:
                            text = read_program(cand)
                        except ProgramFileError as exc:
                            raise LineError(f"{oname(label)} call: {exc}", col) from None
                        loaded = self.add_source(str(cand), text)
                    if label not in loaded.subs:
                        raise LineError(f"{oname(label)} call: {cand} has no {oname(label)} sub", col)
                    return loaded, loaded.subs[label]
        return None

    def run(self, main: _Source):
        it = self.it
        p = it.params
        src = main
        pc = 0
        depth = 0
        calls: list[tuple] = []  # (src, return pc, saved #1..#30)
        repeats: dict = {}
        steps = 0
        # straight-line code is bounded by the file; loops and calls by the limit
        max_steps = self.limits.max_steps + len(main.lines)
        max_rows = self.limits.max_steps + 2 * len(main.lines)
        self.running = True
        self.snapshot()
        end_index = main.percent_end
        fl = None
        # room for a row per main line up front: untouched zeroed pages cost no memory, and
        # the table then rarely has to grow (which would touch what it adds)
        it.expect(len(main.lines) + 64)
        if self.fast and not main.has_long_lines:
            from sim.gcode.fastpath import ChunkScanner, run_simple

            fl = ChunkScanner(main.lines)
        while True:
            limit = len(src.lines) if not (depth == 0 and src is main and end_index is not None) else end_index
            if pc >= limit:
                if depth == 0:
                    if end_index is None and not it.ended:
                        self.warnings.append(f"{main.name}: program ends with no M2, M30 or '%'")
                    break
                # a subroutine file that runs off its end returns
                self.leave(src, pc - 1)
                self.scopes.pop()
                src, pc, saved = calls.pop()
                depth -= 1
                p.numbered.update(saved)
                p.frames.pop()
                continue
            steps += 1
            if steps > max_steps:
                self.fail(src, pc, LineError(f"program ran more than {self.limits.max_steps} blocks beyond its "
                                             f"{len(main.lines)} lines: an endless o-word loop? (--max-loop "
                                             "raises the limit)"))
                break
            if depth == 0:
                it.main_line = pc + 1
                if fl is not None and not it.ended:
                    a, simple, values, run_end = fl.at(pc)
                    if simple[pc - a]:
                        stop = a + int(run_end[pc - a])
                        if end_index is not None:
                            stop = min(stop, end_index)
                        if stop - pc >= 8 and run_simple(it, values[pc - a:stop - a], pc, self.snapshot):
                            steps += stop - pc - 1
                            pc = stop
                            continue
            b = src.block(pc, it.dialect)
            it.line = pc + 1
            it.file_index = src.index
            if isinstance(b, LineError):
                self.fail(src, pc, b)
                pc += 1
                continue
            if b.oword is None:
                if b.deleted and it.block_delete or b.empty:
                    if b.message is not None:
                        it.messages.append((pc + 1, b.message))
                    pc += 1
                    continue
                n_rows = len(it._rows)
                try:
                    it.execute_block(b, pc + 1, src.index)
                except LineError as exc:
                    del it._rows[n_rows:], it._row_line[n_rows:]
                    self.fail(src, pc, exc)
                except (ArithmeticError, ValueError, OverflowError) as exc:
                    del it._rows[n_rows:], it._row_line[n_rows:]
                    self.fail(src, pc, LineError(f"cannot compute this line: {exc}"))
                self.snapshot()
                if it._n + len(it._rows) > max_rows:
                    self.fail(src, pc, LineError(f"program made more than {max_rows} moves from its "
                                                 f"{len(main.lines)} lines: memory is bounded"))
                    break
                if len(it._rows) >= SEAL_ROWS:
                    it._seal()  # rows as compact table rows, not Python tuples
                if it.ended:
                    break
                pc += 1
                continue
            try:
                nxt = self.control(src, pc, b, calls, repeats, depth)
            except LineError as exc:
                self.fail(src, pc, exc)
                nxt = None
            if nxt is None:
                pc += 1
            else:
                kind, value = nxt
                if kind == "jump":
                    pc = value
                elif kind == "call":
                    new_src, new_pc, args, label = value
                    self.scopes.append(label)
                    saved = {k: p.numbered.get(k, 0.0) for k in range(1, 31)}
                    calls.append((src, pc + 1, saved))
                    for k in range(1, 31):
                        p.numbered[k] = args[k - 1] if k - 1 < len(args) else 0.0
                    p.frames.append({})
                    it.contexts.enter()
                    depth += 1
                    src, pc = new_src, new_pc + 1
                elif kind == "return":
                    if not calls:
                        pc += 1
                        continue
                    self.leave(src, pc)
                    self.scopes.pop()
                    src, pc, saved = calls.pop()
                    depth -= 1
                    p.numbered.update(saved)
                    p.frames.pop()
                    set_value(p, value)
        return self

    def first_use(self, src: _Source, i: int, label: str, kw: str, col: int) -> None:
        """LinuxCNC keeps the label of each if/while/repeat/do it runs, per program or called
        sub; one label run from two lines is refused at the second."""
        key = (self.scopes[-1], label)
        first = self.labels.setdefault(key, (src.index, i))
        if first != (src.index, i) and kw != "DO":
            raise LineError(f"{oname(label)} {kw.lower()}: label {oname(label)} was already used on line "
                            f"{first[1] + 1}; LinuxCNC refuses a label used twice in one program or sub", col)

    def leave(self, src: _Source, i: int) -> None:
        """The subroutine return on line index ``i``: an M73 in the sub restores the
        caller's modal state now."""
        try:
            self.it.contexts.leave(self.it)
        except LineError as exc:
            self.fail(src, i, exc)

    def define(self, src: _Source, end: int) -> None:
        """A sub definition skipped up to its endsub on line index ``end``: LinuxCNC reads
        that endsub, so its [value] becomes #<_value> (named parameters not yet defined
        read as 0 in a definition)."""
        if src.kind.get(end) != "ENDSUB":
            return  # a sub never closed: the file ended first
        args = src.block(end, self.it.dialect).oword[2]
        set_value(self.it.params, evaluate(args[0], _Lenient(self.it.params)) if args else None)

    def count_pass(self, src: _Source, opener: int, depth: int) -> None:
        """One more pass of the loop opened on line index ``opener``; LineError (naming
        that line) past the loop limit."""
        key = (depth, src.index, opener)
        n = self.passes.get(key, 0) + 1
        if n > self.limits.max_loop:
            self.passes.pop(key, None)
            label, kw, _args, col = src.block(opener, self.it.dialect).oword
            exc = LineError(f"{oname(label)} {kw.lower()} ran more than {self.limits.max_loop} times: an endless loop? "
                            "(--max-loop raises the limit)", col)
            exc.line_index = opener
            raise exc
        self.passes[key] = n

    def control(self, src: _Source, i: int, b, calls, repeats, depth):
        it = self.it
        p = it.params
        label, kw, args, col = b.oword
        kw = src.kind.get(i, kw)
        if b.message is not None:
            it.messages.append((i + 1, b.message))

        def cond():
            if not args:
                raise LineError(f"{oname(label)} {kw.lower()} needs a [condition]", col)
            return evaluate(args[0], p) != 0.0

        if i in {e[0] for e in src.struct_errors}:
            return None
        if kw in ("IF", "WHILE", "REPEAT", "DO"):
            self.first_use(src, i, label, kw, col)
        if kw == "SUB":
            if depth > 0:
                return None  # LinuxCNC runs on into it: only at the top level is a sub line a definition
            hit = self.defined.get(label)
            if hit == (src.index, i):
                raise LineError(f"{oname(label)} sub is read here after a call already ran it: LinuxCNC "
                                "refuses a definition after its first call", col)
            if hit is not None:
                raise LineError(f"{oname(label)} sub is already defined in {self.sources[hit[0]].name}", col)
            self.defined[label] = (src.index, i)
            if i not in src.end_of:
                return None
            self.define(src, src.end_of[i])
            return ("jump", src.end_of[i] + 1)
        if kw in ("ENDSUB", "RETURN"):
            if not calls:
                if kw == "RETURN":
                    raise LineError(f"{oname(label)} return outside a subroutine call", col)
                return None
            value = evaluate(args[0], p) if args else None
            return ("return", value)
        if kw == "CALL":
            if not isinstance(label, str):
                v = evaluate(label, p)
                label = str(int(v)) if v == int(v) else f"{v:g}"
            if depth >= 100:
                raise LineError("subroutine calls nested more than 100 deep", col)
            s, line = self.find_sub(label, src, col, i)
            values = [evaluate(a, p) for a in args]
            if len(values) > 30:
                raise LineError("more than 30 subroutine arguments", col)
            return ("call", (s, line, values, label))
        if kw == "IF":
            if cond():
                return None
            for br in src.branches.get(i, []):
                bb = src.block(br, it.dialect)
                if src.kind[br] == "ELSE":
                    return ("jump", br + 1)
                _l, _k, bargs, bcol = bb.oword
                if not bargs:
                    raise LineError(f"{oname(label)} elseif needs a [condition]", bcol)
                if evaluate(bargs[0], p) != 0.0:
                    return ("jump", br + 1)
            return ("jump", src.end_of[i] + 1)
        if kw in ("ELSEIF", "ELSE"):
            end = src.end_of.get(src.owner[i])
            return None if end is None else ("jump", end + 1)  # an if never closed was reported
        if kw == "ENDIF":
            return None
        if kw == "WHILE":
            if cond():
                return None
            self.passes.pop((len(calls), src.index, i), None)
            return ("jump", src.end_of[i] + 1)
        if kw == "ENDWHILE":
            self.count_pass(src, src.owner[i], len(calls))
            return ("jump", src.owner[i])
        if kw == "DO":
            return None
        if kw == "DOWHILE":
            if cond():
                self.count_pass(src, src.owner[i], len(calls))
                return ("jump", src.owner[i] + 1)
            self.passes.pop((len(calls), src.index, src.owner[i]), None)
            return None
        if kw == "REPEAT":
            if not args:
                raise LineError(f"{oname(label)} repeat needs a [count]", col)
            n = evaluate(args[0], p)
            key = (len(calls), src.index, i)
            if n < 1:
                repeats.pop(key, None)
                return ("jump", src.end_of[i] + 1)
            if n > self.limits.max_loop:
                raise LineError(f"{oname(label)} repeat count {n:.0f} is beyond the loop limit of {self.limits.max_loop} "
                                "(--max-loop raises it)", col)
            repeats[key] = int(n)
            return None
        if kw == "ENDREPEAT":
            opener = src.owner[i]
            key = (len(calls), src.index, opener)
            left = repeats.get(key, 1) - 1
            if left > 0:
                repeats[key] = left
                return ("jump", opener + 1)
            repeats.pop(key, None)
            return None
        if kw == "BREAK":
            loop = src.owner[i]
            repeats.pop((len(calls), src.index, loop), None)
            self.passes.pop((len(calls), src.index, loop), None)
            end = src.end_of.get(loop)
            return None if end is None else ("jump", end + 1)  # a loop never closed was reported
        if kw == "CONTINUE":
            loop = src.owner[i]
            lk = src.kind[loop]
            if lk == "WHILE":
                self.count_pass(src, loop, len(calls))
                return ("jump", loop)
            end = src.end_of.get(loop)
            return None if end is None else ("jump", end)
        raise LineError(f"unknown o-word command {kw.lower()}", col)  # pragma: no cover


class _Lenient:
    """Parameters as a sub definition reads them: a named parameter not yet defined is 0."""

    def __init__(self, params):
        self.params = params

    def get_numbered(self, idx):
        return self.params.get_numbered(idx)

    def get_named(self, name):
        return self.params.get_named(name) if self.params.exists(name) else 0.0

    def exists(self, name):
        return self.params.exists(name)


def set_value(params, value: float | None) -> None:
    """#<_value> and #<_value_returned> after a return or endsub with ``value`` (None: none given)."""
    params.globals["_value"] = 0.0 if value is None else value
    params.globals["_value_returned"] = 0.0 if value is None else 1.0


def _read_tool_table(tool_table, machine_units: str):
    if tool_table is None or isinstance(tool_table, dict):
        return tool_table
    from sim.tooltable import read_tool_table

    return read_tool_table(tool_table, units=machine_units)


def _read_var(var_file):
    if var_file is None or isinstance(var_file, dict):
        return var_file
    from sim.gcode.varfile import read_var_file

    return read_var_file(var_file)


def interpret(text: str | bytes, filename: str = "<string>", dialect: str = "linuxcnc", tool_table=None,
              var_file=None, machine_units: str = "mm", keep_going: bool = False,
              subroutine_path=None, limits: Limits | None = None, block_delete: bool = False,
              fast: bool = True, after_tool_change: str = "machine") -> Program:
    """Interpret G-code ``text`` (str, or bytes decoded as UTF-8); return a :class:`Program`.

    ``tool_table`` is a path (LinuxCNC format, in ``machine_units``) or ``{n: ToolEntry}``;
    ``var_file`` a LinuxCNC .var path or ``{param: value}`` (in ``machine_units``).
    ``limits`` bounds loops, repeats, coordinates and the like (:class:`~sim.gcode.limits.Limits`).
    ``block_delete`` is the controller's block delete switch: off (the default, as LinuxCNC
    starts), '/' lines run; on, they are dropped unread.
    ``after_tool_change`` is where the program position is after an M6/M61 block:
    ``"machine"`` as LinuxCNC driving a machine, ``"rs274"`` as its stand-alone interpreter
    (see :func:`sim.gcode.tool_length.refresh_after_tool_change`).
    Raises :class:`GCodeError` at the first error unless ``keep_going``; bytes that are
    not text raise its subclass :class:`~sim.gcode.errors.ProgramFileError` whatever
    ``keep_going`` says. A program with no motion gets the warning "no motion in program".
    """
    if isinstance(text, (bytes, bytearray, memoryview)):
        text = check_text(text, filename)
    elif text.startswith("\ufeff"):
        text = text[1:]  # a byte order mark is no G-code character
    table = _read_tool_table(tool_table, machine_units)
    var = _read_var(var_file)
    it = Interpreter(dialect=dialect, machine_units=machine_units, tool_table=table, var_params=var,
                     filename=filename, block_delete=block_delete, limits=limits,
                     after_tool_change=after_tool_change)
    runner = _Runner(it, keep_going, subroutine_path, fast)
    main = runner.add_source(filename, text)
    runner.run(main)
    if it.comp_engine is not None and it.comp_engine.holds_moves():
        # LinuxCNC makes a compensated move only once the next one is known (or at G40/M2)
        runner.warnings.append(f"{filename}: the last move under cutter compensation is not made: "
                               "the program ends with compensation on and no M2/M30")
    moves, row_lines = it.assemble()
    kind = moves["kind"]
    if not ((kind <= 3) | (kind == 6)).any():  # MOTION_KINDS
        if not main.lines.data.strip():
            # the "no M2" warning says nothing more about an empty file
            runner.warnings[:] = [w for w in runner.warnings if "no M2" not in w]
            runner.warnings.insert(0, f"{filename}: no motion in program (the file is empty)")
        else:
            runner.warnings.insert(0, f"{filename}: no motion in program")
    return Program(moves, list(it.files), runner.errors, list(it.messages), runner.warnings,
                   runner.snapshots, runner.snap_lines, row_lines, dialect, machine_units)


def load_program(path, dialect: str = "linuxcnc", tool_table=None, var_file=None, machine_units: str = "mm",
                 keep_going: bool = False, subroutine_path=None, **kwargs) -> Program:
    """Read and interpret the G-code file ``path``; see :func:`interpret`.

    A missing, unreadable or binary file raises :class:`~sim.gcode.errors.ProgramFileError`
    (an :class:`~sim.errors.InputError`) with one plain line: ``no such program file: PATH``,
    ``PATH: not a text G-code file (binary data at byte N)``.
    """
    path = Path(path)
    data = read_program(path)
    # the bytes are passed on as they are: for an ASCII file they become the program's
    # only copy (no str of the whole text, no str per line)
    return interpret(data, filename=str(path), dialect=dialect, tool_table=tool_table, var_file=var_file,
                     machine_units=machine_units, keep_going=keep_going, subroutine_path=subroutine_path,
                     **kwargs)
