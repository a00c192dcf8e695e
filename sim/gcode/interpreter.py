"""Execute parsed blocks the way LinuxCNC's rs274ngc (or GRBL 1.1) does; emit move rows.

Internally every length is mm and every position is the machine position of the
controlled point; the work position is ``machine - g5x - g92 - tool offset``. Words
are converted from program units (G20/G21) as they are read.

The order of execution within a line is LinuxCNC's: comment, feed mode, F, S, T, M6,
M3/M4/M5, coolant, dwell, plane, units, cutter comp, tool length, coordinate system,
path mode, distance mode, retract mode, G10/G28/G30/G92, motion, stop.
"""

from __future__ import annotations

import math
import numpy as np

from sim.gcode import comp, mcodes, nonmodal
from sim.gcode.errors import GCodeError, LineError
from sim.gcode.expr import evaluate
from sim.gcode.limits import DEFAULT_LIMITS, MAX_LINEAR_MM, MAX_ROTARY_DEG, Limits
from sim.gcode.modal_groups import CYCLES, group_codes
from sim.gcode.motion import run_motion
from sim.gcode.moves import COOLANT_FLOOD, COOLANT_MIST, INCH, MOVE_DTYPE, MoveKind
from sim.gcode.params import LineParameters, Parameters
from sim.gcode.parser import AXES, Block, dialect_parts, is_deleted, parse_line
from sim.gcode.cycles import CycleMemory
from sim.gcode.state import ModalState
from sim.gcode.tool_length import CANON_MOTIONS, Pockets, refresh_after_tool_change, set_tool_length

NAN3 = (math.nan, math.nan, math.nan)

G0_AXIS_USERS = {100, 280, 300, 920}
PLANE_AXES = {170: (0, 1, 2), 180: (2, 0, 1), 190: (1, 2, 0)}  # first, second, normal axis
PLANE_CODE = {170: 0, 180: 1, 190: 2}
PLANE_OFFSET_WORDS = {170: ("I", "J", "K"), 180: ("K", "I", "J"), 190: ("J", "K", "I")}
COORD_INDEX = {540: 0, 550: 1, 560: 2, 570: 3, 580: 4, 590: 5, 591: 6, 592: 7, 593: 8}
_AXIS_BOUND = (MAX_LINEAR_MM,) * 3 + (MAX_ROTARY_DEG,) * 3


class Interpreter:
    """A G-code interpreter for one program or one stream of lines.

    ``dialect`` is ``"linuxcnc"`` or ``"grbl"``. ``tool_table`` is ``{number: ToolEntry}``
    (lengths in mm) or None (any tool allowed, zero offsets). ``var_params`` is
    ``{parameter: value}`` from a .var file, in ``machine_units``.
    """

    def __init__(self, dialect: str = "linuxcnc", machine_units: str = "mm", tool_table=None,
                 var_params: dict | None = None, filename: str = "<string>", block_delete: bool = False,
                 limits: Limits | None = None, after_tool_change: str = "machine"):
        try:
            base, _ = dialect_parts(dialect)
        except ValueError as exc:
            raise GCodeError(str(exc), filename, 0) from None
        if machine_units not in ("mm", "inch"):
            raise GCodeError(f"machine units must be 'mm' or 'inch', got {machine_units!r}", filename, 0)
        if after_tool_change not in ("machine", "rs274"):
            raise GCodeError(f"after_tool_change must be 'machine' or 'rs274', got {after_tool_change!r}", filename, 0)
        self.dialect = dialect
        self.grbl = base == "grbl"
        self.after_tool_change = after_tool_change   # see tool_length.refresh_after_tool_change
        self.machine_units = machine_units
        self.tool_table = dict(tool_table) if tool_table else {}
        self.has_tool_table = tool_table is not None
        self.filename = filename
        self.files: list[str] = [filename]
        self.block_delete = block_delete
        self.limits = limits or DEFAULT_LIMITS
        # positions and offsets, mm / degrees
        self.pos = [0.0] * 6
        self.g5x = [[0.0] * 6 for _ in range(9)]
        self.coord = 0
        self.g92 = [0.0] * 6
        self.g92_saved = [0.0] * 6
        self.g92_enabled = False
        self.tlo = [0.0] * 6
        self.canon_tlo = self.tlo   # the offsets of the last motion (see tool_length)
        self.g28 = [0.0] * 6
        self.g30 = [0.0] * 6
        # modal codes (tenths)
        self.motion = 0
        self.plane = 170
        self.distance = 900
        self.arc_distance = 911
        self.feed_mode = 940
        self.units = 210
        self.factor = 1.0
        self.comp = 400
        self.comp_radius = 0.0
        self.tlo_mode = 490
        self.path_mode = 610
        self.retract = 990          # LinuxCNC's initial retract mode is R_PLANE
        self.feed_word = 0.0
        self.feed_set = False
        self.spindle = 0.0
        self.spindle_dir = 0
        self.tool = 0
        self.selected_tool = 0
        self.coolant = 0
        # M48-M53 state: rs274 starts with the overrides enabled and feed hold allowed
        # (its stand-alone canon's answers; a live machine's come from its HAL setup)
        self.overrides = mcodes.Overrides()
        self.pockets = Pockets(self.tool_table)
        self.cycle = CycleMemory()
        self.prev_motion = 0        # the motion mode before the block being executed
        self.last_spline_ctrl = None
        self.file_index = 0
        self.line = 0
        self.ended = False
        self.messages: list[tuple[int, str]] = []
        self._rows: list[tuple] = []
        self._row_line: list[int] = []   # main-file line that caused each row
        # sealed rows live in one table grown in place (ndarray.resize: no second copy)
        self._table = np.zeros(0, dtype=MOVE_DTYPE)
        self._table_lines = np.zeros(0, dtype=np.int32)
        self._n = 0
        self.main_line = 0
        self.params = Parameters(self)
        self.comp_engine = None    # sim.gcode.comp.CompEngine while compensation offsets moves
        self.tool_pos = None       # machine position of the tool when it is not at pos (after G40)
        self.arc_not_allowed = False  # just after G40: the next move must be straight
        self.contexts = mcodes.Contexts()   # M70-M73 saved modal states, per call level
        if var_params:
            self._load_var(var_params)

    # ----------------------------------------------------------------- public helpers
    @property
    def coord_code(self) -> int:
        return (540, 550, 560, 570, 580, 590, 591, 592, 593)[self.coord]

    def offsets(self) -> list[float]:
        """Total offset machine - work for each axis (mm)."""
        g = self.g5x[self.coord]
        return [g[i] + self.g92[i] + self.tlo[i] for i in range(6)]

    def work(self) -> list[float]:
        off = self.offsets()
        return [self.pos[i] - off[i] for i in range(6)]

    @property
    def state(self) -> ModalState:
        """A snapshot of the modal state (a new object each time)."""
        off = np.array(self.offsets())
        pos = np.array(self.pos)
        return ModalState(
            motion=self.motion, plane=self.plane, distance=self.distance, arc_distance=self.arc_distance,
            feed_mode=self.feed_mode, units=self.units, cutter_comp=self.comp, tool_length_mode=self.tlo_mode,
            coord_system=self.coord_code, path_mode=self.path_mode, retract_mode=self.retract,
            feed=self.feed_word * self.factor, feed_word=self.feed_word, spindle=self.spindle,
            spindle_dir=self.spindle_dir, tool=self.tool, selected_tool=self.selected_tool,
            tool_length=self.tlo[2], comp_radius=self.comp_radius, coolant=self.coolant,
            position=pos, work_position=pos - off, work_offset=np.array(self.g5x[self.coord]),
            g92_offset=np.array(self.g92), tool_offset=np.array(self.tlo), file=self.file_index,
            line=self.line,
        )

    def modal_key(self) -> tuple:
        """Cheap tuple that changes whenever anything in :class:`ModalState` but position does."""
        return (self.motion, self.plane, self.distance, self.arc_distance, self.feed_mode, self.units,
                self.comp, self.comp_radius, self.tlo_mode, self.coord, self.path_mode, self.retract,
                self.feed_word, self.spindle, self.spindle_dir, self.tool, self.selected_tool,
                self.coolant, tuple(self.g5x[self.coord]), tuple(self.g92), tuple(self.tlo))

    def set_work_offset(self, index: int, values, axes: str = "XYZ") -> None:
        """Set G54..G59.3 (``index`` 1..9; 0 = active) offsets, mm, for the named axes."""
        k = self.coord if index == 0 else index - 1
        if not 0 <= k < 9:
            raise ValueError(f"work offset index {index} out of range 0..9")
        for a, v in zip(axes, values):
            self.g5x[k][AXES.index(a)] = float(v)

    def work_offsets(self) -> list[list[float]]:
        """G54..G59.3 offsets in mm, 9 lists of 6."""
        return [list(g) for g in self.g5x]

    def set_position(self, machine) -> None:
        """Set the machine position (mm), e.g. after a jog or a probe."""
        for i, v in enumerate(machine):
            self.pos[i] = float(v)

    def set_home(self, which: int, machine) -> None:
        """Set the stored G28 (``which=28``) or G30 position, machine mm."""
        target = self.g28 if which == 28 else self.g30
        for i, v in enumerate(machine):
            target[i] = float(v)

    def reset_modes(self) -> None:
        """Program end / soft reset modes (LinuxCNC's and GRBL's M2 defaults)."""
        self.motion = 10 if not self.grbl else 10
        self.coord = 0
        self.plane = 170
        self.distance = 900
        self.feed_mode = 940
        self.comp = 400
        self.comp_radius = 0.0
        self.spindle_dir = 0
        self.coolant = 0
        self.path_mode = 610
        if not self.grbl:  # GRBL 1.1 keeps G92 offsets through program end
            self.g92 = [0.0] * 6
            self.g92_enabled = False
        if self.comp_engine is not None:
            self.comp_engine = None

    def expect(self, rows: int) -> None:
        """Size the (still empty) table for about ``rows`` rows.

        ``np.zeros`` takes fresh zero pages from the OS that cost no memory until written,
        so a generous guess is free, while growing later (``ndarray.resize`` zero-fills
        what it adds) is not.
        """
        if self._n == 0 and rows > len(self._table):
            self._table = np.zeros(rows, dtype=MOVE_DTYPE)
            self._table_lines = np.zeros(rows, dtype=np.int32)

    def reserve(self, extra: int) -> int:
        """Make room for ``extra`` more sealed rows; return the index of the first one.

        Grows in place (``ndarray.resize``: no second copy) by at most 64k rows beyond the
        need, so a large table overshoots by a bounded amount.
        """
        need = self._n + extra
        if need > len(self._table):
            cap = max(need, len(self._table) + max(1024, min(len(self._table) // 4, 1 << 16)))
            self._table.resize(cap, refcheck=False)
            self._table_lines.resize(cap, refcheck=False)
        return self._n

    def _seal(self) -> None:
        """Move the pending row tuples into the table."""
        if self._rows:
            k = len(self._rows)
            i = self.reserve(k)
            self._table[i:i + k] = np.array(self._rows, dtype=MOVE_DTYPE)
            self._table_lines[i:i + k] = self._row_line
            self._n += k
            self._rows.clear()
            self._row_line.clear()

    def assemble(self) -> tuple[np.ndarray, np.ndarray]:
        """All rows so far as one MOVE_DTYPE array (and their main-file lines)."""
        self._seal()
        table, lines = self._table, self._table_lines
        table.resize(self._n, refcheck=False)
        lines.resize(self._n, refcheck=False)
        self._table = np.zeros(0, dtype=MOVE_DTYPE)
        self._table_lines = np.zeros(0, dtype=np.int32)
        self._n = 0
        return table, lines

    def take_rows(self) -> np.ndarray:
        """The rows produced since the last call, as a MOVE_DTYPE array; clears the buffer."""
        rows = np.array(self._rows, dtype=MOVE_DTYPE) if self._rows else np.zeros(0, MOVE_DTYPE)
        self._rows.clear()
        self._row_line.clear()
        return rows

    def execute_line(self, text: str, line_no: int | None = None, file_index: int = 0) -> np.ndarray:
        """Execute one streamed line; return the MOVE_DTYPE rows it produced.

        Raises :class:`GCodeError` (with ``grbl_code`` in the grbl dialect) when the
        controller would refuse the line; the state is then unchanged by the line's
        motion (parameter settings of LinuxCNC lines are also not applied).
        """
        line_no = self.line + 1 if line_no is None else int(line_no)
        self.line = line_no
        self.main_line = line_no
        self._rows.clear()
        self._row_line.clear()
        saved = self._checkpoint()
        try:
            if self.grbl and text.lstrip().startswith("%"):
                raise LineError("'%' is not a G-code command", 1, grbl_code=1)
            if self.block_delete and is_deleted(text):
                return self.take_rows()  # dropped unread, as LinuxCNC with the switch on
            block = parse_line(text, self.dialect)
            if block.oword is not None:
                raise LineError("o-word control flow needs the whole program (use load_program/interpret)",
                                block.oword[3])
            self.execute_block(block, line_no, file_index)
        except LineError as exc:
            self._rows.clear()
            self._restore(saved)
            raise self.error(exc, text, line_no) from None
        except (ArithmeticError, ValueError, OverflowError) as exc:
            self._rows.clear()
            self._restore(saved)
            raise self.error(LineError(f"cannot compute this line: {exc}"), text, line_no) from None
        return self.take_rows()

    _NOT_SAVED = ("_rows", "_row_line", "_table", "_table_lines", "params", "messages", "files")

    def _checkpoint(self) -> dict:
        """The state a refused streamed line must not change (a controller refuses the whole line)."""
        import copy

        state = {k: v for k, v in self.__dict__.items() if k not in self._NOT_SAVED}
        return copy.deepcopy(state)

    def _restore(self, saved: dict) -> None:
        self.__dict__.update(saved)

    def error(self, exc: LineError, text: str, line_no: int, file_index: int | None = None) -> GCodeError:
        fi = self.file_index if file_index is None else file_index
        name = self.files[fi] if 0 <= fi < len(self.files) else self.filename
        code = exc.grbl_code if self.grbl else None
        if self.grbl and code is None:
            code = 20
        return GCodeError(exc.message, name, line_no, exc.column, text, code)

    # ----------------------------------------------------------------- var file
    def _load_var(self, params: dict) -> None:
        unit = INCH if self.machine_units == "inch" else 1.0
        for num, v in params.items():
            num = int(num)
            if 5161 <= num <= 5166:
                a = num - 5161
                self.g28[a] = v * unit if a < 3 else v
            elif 5181 <= num <= 5186:
                a = num - 5181
                self.g30[a] = v * unit if a < 3 else v
            elif 5211 <= num <= 5216:
                a = num - 5211
                self.g92_saved[a] = v * unit if a < 3 else v
            elif num == 5210:
                self.g92_enabled = bool(v)
            elif num == 5220:
                k = int(round(v)) - 1
                if 0 <= k < 9:
                    self.coord = k
            elif 5221 <= num <= 5390:
                k, a = divmod(num - 5221, 20)
                if k < 9 and a < 6:
                    self.g5x[k][a] = v * unit if a < 3 else v
            else:
                self.params.numbered[num] = v
        if self.g92_enabled:
            self.g92 = list(self.g92_saved)

    # ----------------------------------------------------------------- rows
    def meta(self) -> tuple:
        """The row attributes taken from the current state (file, line, spindle ...)."""
        return (self.file_index, self.line, self.spindle, self.spindle_dir, self.tool, self.tlo[2],
                self.coolant, PLANE_CODE[self.plane], self.main_line)

    def emit(self, kind: int, start, end, center=NAN3, turns: int = 0, feed: float = 0.0,
             inverse: float = 0.0, dwell: float = 0.0, meta: tuple | None = None) -> None:
        """Append one move row; ``start``/``end`` machine coordinates (6), mm/deg.

        Raises LineError for a coordinate beyond any machine (or not finite): nothing the
        dexel kernels cannot handle gets into the table."""
        for axis, v, top in zip(AXES, end, _AXIS_BOUND):
            if not abs(v) <= top:  # also catches NaN
                raise LineError(coordinate_message(axis, v))
        m = meta or self.meta()
        if kind in CANON_MOTIONS:
            self.canon_tlo = self.tlo
        if self.tool_pos is not None:  # just after G40 the tool is not where the program is
            start, end = comp.row_ends(self, kind, start, end)
        self._rows.append((
            m[0], m[1], kind, tuple(start), tuple(end), tuple(self.offsets()), center,
            m[7], turns, feed, inverse, m[2], m[3], m[4], m[5], m[6], dwell,
        ))
        self._row_line.append(m[8])

    # ----------------------------------------------------------------- block execution
    def evaluate_block(self, block: Block):
        """(words, g codes, m codes) with every value a float; applies parameter settings."""
        if not block.has_expr:
            return block.words, block.g, block.m
        p = self.params
        if any(target[0] == "n" for target, _value, _col in block.assigns):
            p = LineParameters(p, block.assigns)
        words = {k: evaluate(v, p.at(block.cols.get(k, 0))) for k, v in block.words.items()}
        g = [(evaluate(v, p.at(c)), c) for v, c in block.g]
        m = [(evaluate(v, p.at(c)), c) for v, c in block.m]
        if block.assigns:
            values = []
            for target, value, col in block.assigns:
                try:
                    values.append((target, evaluate(value, p.at(col + 1))))   # the value follows the name
                except LineError as exc:
                    exc.column = col
                    raise
            p = self.params
            for target, v in values:
                if target[0] == "n":
                    p.set_named(target[1], v)
                else:
                    p.set_numbered(evaluate(target[1], p), v)
        return words, g, m

    def execute_block(self, block: Block, line_no: int, file_index: int = 0) -> None:
        """Execute one parsed block (no o-word). Raises LineError."""
        self.line = line_no
        self.file_index = file_index
        if block.message is not None:
            self.messages.append((line_no, block.message))
        if block.empty or block.percent or (block.deleted and self.block_delete):
            return
        if self.ended:
            return
        words, glist, mlist = self.evaluate_block(block)
        cols = block.cols
        grbl = self.grbl

        # ---- classify G and M words into modal groups
        gmodes, mmodes = group_codes(glist, mlist, grbl)

        used = {"N"}
        has_axes = any(a in words for a in AXES) or "@" in words or "^" in words
        g0 = gmodes.get(0)
        g0code = g0[0] if g0 else None
        explicit_motion = gmodes.get(1)
        axis_owner = None  # which code takes the axis words
        if g0code in G0_AXIS_USERS and (has_axes or not grbl):   # LinuxCNC: even without axes
            if explicit_motion and explicit_motion[0] not in (800,):
                raise LineError("two G codes that both use axis words on one line", explicit_motion[1], 24)
            axis_owner = g0code if has_axes else None
        if gmodes.get(8, (0,))[0] == 431 and has_axes:
            if explicit_motion:
                raise LineError("G43.1 and a motion both use the axis words", explicit_motion[1], 24)
            axis_owner = 431
        motion = None
        if explicit_motion:
            motion = explicit_motion[0]
        elif has_axes and axis_owner is None:
            motion = self.motion
        if motion == 800 and has_axes and axis_owner is None:
            col = min(cols.get(a, 10**6) for a in AXES + "@^" if a in words)
            raise LineError("axis words with no command to use them (G80 is active)", col, 31)
        if explicit_motion and not has_axes and not grbl and motion not in (0, 10, 20, 30, 800):
            raise LineError(f"G{motion / 10:g} needs axis words (LinuxCNC: all axes missing with motion code)",
                            explicit_motion[1])

        if "$" in words:
            mcodes.spindle_select(words, cols, mmodes, gmodes, motion, used)
        # ---- 1. feed mode, F, S, T
        if 5 in gmodes:
            self.feed_mode = gmodes[5][0]
            if not grbl and self.feed_mode != 930:
                self.feed_word = 0.0   # LinuxCNC: G94 and G95 reset the feed rate
        if "F" in words:
            f = words["F"]
            if f < 0:
                raise LineError("F must not be negative", cols["F"], 4)
            if grbl or self.feed_mode != 930:   # LinuxCNC: a G93 F is the move's, not the feed rate
                self.feed_word = f
            self.feed_set = True
            used.add("F")
        if "S" in words:
            s = words["S"]
            if s < 0:
                raise LineError("S (spindle speed) must not be negative", cols["S"], 4)
            self.spindle = s
            used.add("S")
        if "T" in words:
            t = words["T"]
            used.add("T")
            if t < 0 or t != int(t):
                raise LineError(f"T must be a non-negative integer, got {t:g}", cols["T"], 4 if t < 0 else 23)
            if t > self.limits.max_tool:
                raise LineError(f"tool number T{t:.0f} is beyond any tool table (at most {self.limits.max_tool})",
                                cols["T"], 38 if grbl else None)
            t = int(t)
            if grbl and t > 255:
                raise LineError("tool number greater than 255", cols["T"], 38)
            if not grbl and self.has_tool_table and t != 0 and t not in self.tool_table:
                raise LineError(f"unknown tool T{t}: it is not in the tool table", cols["T"])
            self.selected_tool = t
            self.pockets.select(t)
        # ---- 2. I/O (M62-M68), M6 / M61
        if 5 in mmodes:
            mcodes.convert_io(self, mmodes[5], words, cols, used)
        m6 = mmodes.get(6)
        if m6:
            comp.tool_change(self, m6[0], m6[1])
            if m6[0] == 6:
                if self.comp != 400 and not grbl:
                    raise LineError("cannot change tools with cutter radius compensation on (G40 first)", m6[1])
                if not grbl:
                    self.spindle_dir = 0   # LinuxCNC stops the spindle for a tool change
                old = list(self.pos)
                self.tool = self.selected_tool
                self.pockets.load(self.selected_tool)
                self.emit(MoveKind.TOOL_CHANGE, old, old)
            else:  # M61 Qn
                if "Q" not in words:
                    raise LineError("M61 needs a Q word (tool number)", m6[1])
                q = words["Q"]
                used.add("Q")
                if q < 0 or q != int(q) or q > self.limits.max_tool:
                    raise LineError(f"M61 Q must be a tool number from 0 to {self.limits.max_tool}", cols["Q"])
                if self.has_tool_table and int(q) != 0 and int(q) not in self.tool_table:
                    raise LineError(f"unknown tool T{int(q)}: it is not in the tool table", cols["Q"])
                self.tool = self.selected_tool = int(q)
                self.pockets.load(int(q))
        if 9 in mmodes:
            comp.refuse_while_on(self, "change the overrides (M48-M53)", mmodes[9][1])
        # ---- 3. spindle (M19, M70-M73 too), coolant, overrides, user M codes
        sp = mmodes.get(7)
        if sp and sp[0] in (3, 4, 5):
            self.spindle_dir = {3: 1, 4: -1, 5: 0}[sp[0]]
        elif sp:
            mcodes.convert_state(self, sp, words, cols, used)
        cool = mmodes.get(8)
        if cool:
            if cool[0] == 7:
                self.coolant |= COOLANT_MIST
            elif cool[0] == 8:
                self.coolant |= COOLANT_FLOOD
            else:
                self.coolant = 0
        if 9 in mmodes:
            mcodes.convert_overrides(self, mmodes[9], words, used)
        if 10 in mmodes:
            mcodes.convert_user(mmodes[10])
        # ---- 4. dwell
        if g0code == 40:
            if "P" not in words:
                raise LineError("G4 needs a P word (seconds)", g0[1], 28)
            p = words["P"]
            if p < 0:
                raise LineError("G4 P must not be negative", cols["P"], 4)
            used.add("P")
            comp.dwell(self, p)
        # ---- 5. plane, units
        if 2 in gmodes:
            if self.comp != 400 and gmodes[2][0] != self.plane:
                raise LineError("cannot change the plane with cutter compensation on", gmodes[2][1])
            self.plane = gmodes[2][0]
        if 6 in gmodes:
            self.units = gmodes[6][0]
            self.factor = INCH if self.units == 200 else 1.0
        # ---- 6. cutter compensation
        if 7 in gmodes:
            comp.set_mode(self, gmodes[7], words, cols, used)
        # ---- 7. tool length
        if 8 in gmodes:
            self._set_tool_length(gmodes[8], words, cols, used)
        # ---- 8. coordinate system
        if 12 in gmodes:
            c, col = gmodes[12]
            if self.comp != 400:
                raise LineError("cannot change the coordinate system with cutter compensation on", col)
            self.coord = COORD_INDEX[c]
        # ---- 9. path mode, distance modes, retract mode, spindle mode
        if 13 in gmodes:
            self.path_mode = gmodes[13][0]
            if self.path_mode == 640:
                used.update(k for k in ("P", "Q") if k in words)
        if 3 in gmodes:
            self.distance = gmodes[3][0]
        if 4 in gmodes:
            self.arc_distance = gmodes[4][0]
        if 10 in gmodes:
            self.retract = gmodes[10][0]
        # ---- 10. G10 G28 G30 G92 G53
        g53 = g0code == 530
        if g0code in (100, 280, 281, 300, 301, 920, 921, 922, 923):
            nonmodal.non_modal(self, g0code, g0[1], words, cols, used)
        if 16 in gmodes:
            nonmodal.non_modal(self, gmodes[16][0], gmodes[16][1], words, cols, used)
        if g53:
            # GRBL checks the motion mode in force; LinuxCNC the block's motion: no axis
            # words and no G0/G1 on the line is none
            eff = motion if motion is not None or not grbl else self.motion
            if eff not in (0, 10):
                raise LineError("G53 needs G0 or G1 motion", g0[1], 30)
            if self.distance == 910 and not grbl:
                raise LineError("G53 cannot be used in incremental (G91) mode", g0[1])
            if self.comp != 400:
                raise LineError("G53 cannot be used with cutter compensation on", g0[1])
        # ---- 11. motion
        if motion is not None and motion not in CYCLES:
            self.cycle.il = None    # any other motion ends a sequence of canned cycles
        self.prev_motion = self.motion
        if explicit_motion:
            self.motion = explicit_motion[0]
            if motion in CYCLES and grbl:
                raise LineError("GRBL has no canned cycles", explicit_motion[1], 20)
            if motion != 50:
                self.last_spline_ctrl = None
        if motion is not None and motion != 800 and (has_axes or explicit_motion):
            run_motion(self, motion, bool(explicit_motion), words, cols, used, g53, has_axes)
        # ---- 12. stops
        stop = mmodes.get(4)
        if stop:
            c = mcodes.m99_as_end(self, stop)
            here = comp.stop(self)
            if c in (2, 30):
                self.emit(MoveKind.END, here, here)
                self.reset_modes()
                self.ended = not grbl
            else:
                self.emit(MoveKind.PAUSE, here, here)
        # ---- unused words
        for letter in words:
            if letter not in used:
                raise LineError(self._unused_message(letter), cols.get(letter, 1), 36 if letter not in AXES else 31)
        if m6 and not grbl:
            refresh_after_tool_change(self)

    def _unused_message(self, letter: str) -> str:
        if letter in AXES:
            return f"{letter} word with no command that uses it"
        uses = {"I": "G2/G3", "J": "G2/G3", "K": "G2/G3", "R": "G2/G3, G10 or a canned cycle",
                "P": "G4, G10, G2/G3, G64, a dwelling canned cycle, M50-M53 or M62-M66", "Q": "G73/G83, M61 or M66-M68",
                "L": "G10, a canned cycle or M66", "E": "M66, M67 or M68",
                "H": "G43", "D": "G41/G42", "@": "a motion", "^": "a motion"}
        return f"{letter} word with no {uses.get(letter, 'command')} to use it"

    # ----------------------------------------------------------------- modal helpers
    def _tool_word_entry(self, letter: str, words, cols, used, col: int):
        """The tool table entry a D (G41/G42) or H (G43) word names (``letter``), the
        current tool without the word; None for tool 0, or for a tool not in the table
        when the program runs without one (no radius, no length). Raises LineError for a
        word that is not a non-negative integer or a tool missing from a loaded table."""
        if letter in words:
            n = words[letter]
            used.add(letter)
            if n < 0 or n != int(n):
                raise LineError(f"{letter} must be a non-negative integer (tool number)", cols[letter])
            n = int(n)
        else:
            n = self.tool
        if n == 0:
            return None
        entry = self.tool_table.get(n)
        if entry is None and self.has_tool_table:
            raise LineError(f"unknown tool {letter}{n}: it is not in the tool table", cols.get(letter, col))
        return entry

    def _set_tool_length(self, mode, words, cols, used) -> None:
        set_tool_length(self, mode, words, cols, used)

    def _axis_values(self, words, cols, used, absolute_machine: bool = False) -> list:
        """Target work position (6) from the axis words of this line (G90/G91, polar)."""
        cur = self.work()
        target = list(cur)
        f = self.factor
        inc = self.distance == 910 and not absolute_machine
        for i, a in enumerate(AXES):
            if a in words:
                v = words[a] * (f if i < 3 else 1.0)
                target[i] = cur[i] + v if inc else v
                used.add(a)
        if "@" in words or "^" in words:
            if self.plane != 170 or "X" in words or "Y" in words:
                col = cols.get("@", cols.get("^", 1))
                raise LineError("polar words @ ^ need G17 and no X or Y word", col)
            r0 = math.hypot(cur[0], cur[1])
            t0 = math.atan2(cur[1], cur[0])
            if inc:
                r = r0 + words.get("@", 0.0) * f
                t = t0 + math.radians(words.get("^", 0.0))
            else:
                r = words["@"] * f if "@" in words else r0
                t = math.radians(words["^"]) if "^" in words else t0
            target[0] = r * math.cos(t)
            target[1] = r * math.sin(t)
            used.update(k for k in ("@", "^") if k in words)
        return target

    def to_machine(self, work) -> list:
        off = self.offsets()
        return [work[i] + off[i] for i in range(6)]

    # ----------------------------------------------------------------- motion
    def _feed_rate(self, col: int, words, length: float) -> tuple[float, float]:
        """(feed mm/min, inverse-time 1/min) for a feed move of ``length`` mm."""
        if self.feed_mode == 930:
            if "F" not in words:
                raise LineError("inverse time mode (G93) needs an F word on every feed move", col, 22)
            inv = words["F"]
            if inv <= 0:
                raise LineError("F must be positive in inverse time mode", col, 22)
            return length * inv, inv
        if self.grbl and not self.feed_set:
            raise LineError("undefined feed rate: give an F word", col, 22)
        feed = self.feed_word * self.factor
        if self.feed_mode == 950:
            feed *= self.spindle
        if feed <= 0:
            raise LineError("cannot feed with a zero feed rate: give an F word", col, 22)
        return feed, 0.0

    def _rapid_to(self, end) -> None:
        start = list(self.pos)
        self.emit(MoveKind.RAPID, start, end)
        self.pos = list(end)

    def _line_to(self, end, kind, feed, inverse) -> None:
        start = list(self.pos)
        self.emit(kind, start, end, feed=feed, inverse=inverse)
        self.pos = list(end)

    def work_of(self, machine) -> list:
        off = self.offsets()
        return [machine[i] - off[i] for i in range(6)]


def coordinate_message(axis: str, value: float) -> str:
    """Why coordinate ``value`` (mm, or deg for A/B/C) of ``axis`` is refused."""
    top = MAX_LINEAR_MM if axis in "XYZ" else MAX_ROTARY_DEG
    unit = "mm" if axis in "XYZ" else "deg"
    if not math.isfinite(value):
        return f"{axis} is not a finite number (the value overflows)"
    return f"{axis}{value:.6g} {unit} is beyond any machine's travel (at most {top:g} {unit})"
