"""Tool length offsets (G43, G43.1, G43.2, G49) and the loaded tool's parameters, as LinuxCNC's rs274.

Where the program position goes when the offset changes. G43/G43.1/G49 keep the machine
position and shift the program position by the change (rs274's convert_tool_length_offset:
``current_z += old - new``), so a move after ``G43 H1`` on a line of its own ends one tool
length lower in program Z than before, at the same machine height.

A tool change (M6, M61) ends with the interpreter reading its position back from the
canon (rs274's read_inputs -> refresh_actual_position), and there the two LinuxCNC canons
differ. LinuxCNC driving a machine (emccanon.cc GET_EXTERNAL_POSITION) takes the machine
position less the offsets in force, new tool length included: the machine stays where it
is and the program position shifts, as for any G43. rs274's stand-alone canon
(saicanon.cc), like AXIS's preview, gives back the program position of the last motion it
was sent, which an offset change (USE_TOOL_LENGTH_OFFSET) does not move: a ``G43`` on the
tool change line (``T1 M6 G43 H1``), or one since the last motion, is undone in program
coordinates, and the next move without Z lifts or lowers the machine by the change.
dexmon watches machines, so it follows the machine canon by default; the differential
tests against rs274 ask for the stand-alone one (``after_tool_change="rs274"``). The two
differ only in moves after a tool change that do not name the axis whose offset changed.

The loaded tool's parameters #5400-#5413 are its tool table entry in machine units (what
LinuxCNC calls user units), whatever G20/G21 says: rs274's set_tool_parameters.
"""

from __future__ import annotations

from sim.gcode.errors import LineError
from sim.gcode.moves import INCH, MoveKind
from sim.gcode.parser import AXES

#: rows whose end the canon takes as its position: traverse, feed, arcs, probe (MoveKind)
CANON_MOTIONS = frozenset((0, 1, 2, 3, 6))


def set_tool_length(it, mode, words, cols, used) -> None:
    """Execute G43 / G43.1 / G43.2 / G49 (``mode`` = (code in tenths, column)) on ``it``.

    ``G43 H0`` and ``G43`` without H take the loaded tool's offsets (LinuxCNC's index 0,
    the spindle); ``G43 Hn`` tool n's; ``G43.2 Hn`` adds tool n's to those in force.
    """
    code, col = mode
    if it.comp != 400 and not it.grbl:
        raise LineError("cannot change the tool length offset with cutter radius compensation on (G40 first)", col)
    if code == 490:
        it.tlo = [0.0] * 6
    elif code == 430:
        it.tlo = _table_offsets(it, words, cols, used, col)
    elif code == 432:  # G43.2 Hn: add tool n's offsets to those in force
        if not any(a in words for a in AXES) and "H" not in words:
            raise LineError("G43.2 needs an H word (the tool whose offsets it adds)", col)
        if "H" not in words:
            # rs274 2.9.0 looks up tool H-1 here and refuses the block
            raise LineError("G43.2 with axis words is not supported by LinuxCNC 2.9: use G43.2 H", col)
        if any(a in words for a in AXES):
            raise LineError("G43.2 cannot have both an H word and axis words", cols["H"])
        add = _table_offsets(it, words, cols, used, col)
        it.tlo = [it.tlo[i] + add[i] for i in range(6)]
    else:  # G43.1: dynamic offsets from the axis words
        new = list(it.tlo)
        for i, a in enumerate(AXES):
            if a in words:
                if it.grbl and a != "Z":
                    raise LineError("G43.1 takes only a Z word", cols[a], 37)
                new[i] = words[a] * (it.factor if i < 3 else 1.0)
                used.add(a)
        if it.grbl and "Z" not in words:
            raise LineError("G43.1 needs a Z word", col, 37)
        it.tlo = new
    it.tlo_mode = code


def _table_offsets(it, words, cols, used, col) -> list:
    """X Y Z A B C offsets (mm/deg) of the tool the H word names; the loaded tool without
    one or for H0 (LinuxCNC's index 0, the spindle)."""
    if words.get("H") == 0.0:
        used.add("H")
        words = {k: v for k, v in words.items() if k != "H"}
    entry = it._tool_word_entry("H", words, cols, used, col)
    new = [0.0] * 6
    if entry is not None:
        for k, v in entry.offsets.items():
            if k in AXES:
                new[AXES.index(k)] = v
    return new


def refresh_after_tool_change(it) -> None:
    """The interpreter re-reads its position after an M6/M61 block (see the module docstring).

    With ``it.after_tool_change == "machine"`` the machine position stays. With ``"rs274"``
    offset changes no motion has carried since (``it.canon_tlo``, the offsets of the last
    motion row) move the machine position, not the program position.
    """
    if it.canon_tlo is it.tlo:
        return
    if it.after_tool_change == "machine":
        it.canon_tlo = it.tlo
        return
    old = list(it.pos)
    new = [old[i] + it.tlo[i] - it.canon_tlo[i] for i in range(6)]
    it.canon_tlo = it.tlo
    if new != old:
        # the rows chain: the shift shows as a tool change row from the old to the new place
        it.emit(MoveKind.TOOL_CHANGE, old, new)
        it.pos = new


def tool_parameter(it, number: int) -> float | None:
    """#5400 (loaded tool), #5401-#5409 (its X Y Z A B C U V W offsets), #5410 (diameter),
    #5411/#5412 (front/back angle), #5413 (orientation), in machine units; None for
    another parameter number. All 0 with no tool loaded or a tool not in the table."""
    if not 5400 <= number <= 5413:
        return None
    if number == 5400:
        return float(it.tool)
    entry = it.tool_table.get(it.tool) if it.tool else None
    if entry is None:
        return 0.0
    unit = INCH if it.machine_units == "inch" else 1.0
    if number <= 5409:
        axis = "XYZABCUVW"[number - 5401]
        v = entry.offsets.get(axis, 0.0)
        return v if axis in "ABC" else v / unit
    if number == 5410:
        return entry.diameter / unit
    v = (entry.front_angle, entry.back_angle, entry.orientation)[number - 5411]
    return float(v or 0.0)


class Pockets:
    """The tool table pockets rs274 reports as ``#<_current_pocket>`` and ``#<_selected_pocket>``
    (interp_namedparams.cc, a non-random tool changer): the pocket (P) of a table entry.

    rs274 keeps table indices; entry 0 is the spindle, a copy of the entry last loaded by M6
    or M61 (pocket -1 before any). Here an index is the tool number of its entry, 0 the
    spindle. rs274's stand-alone canon starts with the table's first entry loaded (slot 1),
    which is what ``#<_current_pocket>`` shows before any tool change.
    """

    def __init__(self, tool_table: dict):
        self.table = tool_table
        first = min(tool_table.values(), key=lambda e: e.line, default=None)
        self.current = first.number if first is not None else 0
        self.selected = 0
        self.spindle = -1

    def _pocket(self, tool: int) -> int:
        if tool == 0:
            return self.spindle
        entry = self.table.get(tool)
        return entry.pocket if entry is not None else tool   # no table: pocket = tool number

    def select(self, tool: int) -> None:
        """T word."""
        self.selected = tool

    def load(self, tool: int) -> None:
        """M6 (the selected tool) or M61 Q: the entry becomes current and the spindle's copy."""
        self.current = tool
        if tool != 0:
            self.spindle = self._pocket(tool)

    def current_value(self) -> float:
        return float(self._pocket(self.current))

    def selected_value(self) -> float:
        pocket = self._pocket(self.selected)
        return -1.0 if pocket == 0 else float(pocket)   # pocket 0: none selected
