"""The non-modal commands that set offsets or go home: G10 (work offsets, tool table
entries), G28/G30 and their .1 forms, G92 and G92.1/.2/.3, run on an interpreter
(:mod:`sim.gcode.interpreter`) in LinuxCNC's order (after the modal groups, before motion).
"""

from __future__ import annotations

from dataclasses import replace

from sim.gcode import comp
from sim.gcode.errors import LineError
from sim.gcode.parser import AXES
from sim.tooltable import ToolEntry


def non_modal(it, code: int, col: int, words, cols, used) -> None:
    """Execute G10, G28/G30 (.1) or G92 (.1/.2/.3) (``code`` in tenths) on interpreter ``it``."""
    f = it.factor
    if code == 100:
        g10(it, col, words, cols, used)
    elif code in (280, 300):
        if it.comp != 400:
            raise LineError(f"G{code // 10} cannot be used with cutter compensation on", col)
        home = it.g28 if code == 280 else it.g30
        if any(a in words for a in AXES):
            mid_work = it._axis_values(words, cols, used)
            mid = it.to_machine(mid_work)
            it._rapid_to(mid)
            end = list(mid)
            for i, a in enumerate(AXES):
                if a in words:
                    end[i] = home[i]
            it._rapid_to(end)
        else:
            if not it.grbl:  # LinuxCNC's waypoint: where the tool is (GRBL goes home at once)
                it._rapid_to(list(it.pos))
            it._rapid_to(list(home))
    elif code in (281, 301):
        target = it.g28 if code == 281 else it.g30
        target[:] = list(it.pos)
        used.update(a for a in AXES if a in words)  # LinuxCNC ignores axis words here
    elif code in (920, 921, 922, 923) and it.comp != 400:
        comp.refuse_while_on(it, "change the G92 offsets", col)
    elif code == 920:
        if not any(a in words for a in AXES):
            raise LineError("G92 needs at least one axis word", col, 26)
        g = it.g5x[it.coord]
        for i, v in axis_words(words, f, used):
            it.g92[i] = it.pos[i] - g[i] - it.tlo[i] - v
        it.g92_saved = list(it.g92)
        it.g92_enabled = True
    elif code == 921:
        it.g92 = [0.0] * 6
        it.g92_saved = [0.0] * 6
        it.g92_enabled = False
    elif code == 922:
        it.g92 = [0.0] * 6
        it.g92_enabled = False  # #5210 = 0, as LinuxCNC (the saved #5211.. stay for G92.3)
    elif code == 923:
        it.g92 = list(it.g92_saved)
        it.g92_enabled = True



def g10(it, col: int, words, cols, used) -> None:
    """G10 L2/L20 (a work offset) or L1/L10/L11 (a tool table entry) on interpreter ``it``."""
    f = it.factor
    if "L" not in words or "P" not in words:
        raise LineError("G10 needs L and P words", col, 28)
    used.update(("L", "P"))
    L = words["L"]
    P = words["P"]
    if L != int(L) or int(L) not in (1, 2, 10, 11, 20):
        raise LineError(f"G10 L{L:g} is not supported (L1, L2, L10, L11, L20)", cols["L"], 20)
    if P != int(P):
        raise LineError("G10 P must be an integer", cols["P"], 23)
    L, P = int(L), int(P)
    if it.grbl and L not in (2, 20):
        raise LineError(f"GRBL supports only G10 L2 and L20, not L{L}", cols["L"], 20)
    if L in (2, 20):
        if not 0 <= P <= (6 if it.grbl else 9):
            raise LineError(f"G10 L{L} P must be 0..{6 if it.grbl else 9}", cols["P"], 29)
        k = it.coord if P == 0 else P - 1
        if k == it.coord:
            comp.refuse_while_on(it, "change the active coordinate system", col)
        if "R" in words:
            used.add("R")
            if words["R"] != 0.0:
                raise LineError("coordinate system rotation (G10 L2 R) is not supported", cols["R"], 20)
        g = it.g5x[k]
        for i, v in axis_words(words, f, used):
            g[i] = v if L == 2 else it.pos[i] - it.g92[i] - it.tlo[i] - v
        return
    # tool table edits
    if P < 1 and L != 1 or P < 0:
        raise LineError("G10 L1/L10/L11 P must be a tool number", cols["P"])
    if not any(k in words for k in AXES + "RQIJ"):
        raise LineError(f"G10 L{L} without offsets has no effect: give an axis or R word", col)
    entry = it.tool_table.get(P) or ToolEntry(number=P, pocket=P)
    offsets = dict(entry.offsets)
    diameter = entry.diameter
    if "R" in words:
        diameter = 2.0 * words["R"] * f
        used.add("R")
    for k in ("I", "J", "Q"):
        if k in words:
            used.add(k)
    for i, v in axis_words(words, f, used):
        if L == 1:
            offsets[AXES[i]] = v
        elif L == 10:
            offsets[AXES[i]] = it.pos[i] - it.g5x[it.coord][i] - it.g92[i] - v
        else:   # L11: as if in G59.3
            offsets[AXES[i]] = it.pos[i] - it.g5x[8][i] - v
    it.tool_table[P] = replace(entry, diameter=diameter, z_offset=offsets.get("Z", 0.0), offsets=offsets)


def axis_words(words, factor: float, used: set) -> list[tuple[int, float]]:
    """(axis index, value) of the line's axis words, X Y Z in mm (times ``factor``, the
    program units), A B C in degrees; marks them ``used``."""
    out = []
    for i, a in enumerate(AXES):
        if a in words:
            out.append((i, words[a] * (factor if i < 3 else 1.0)))
            used.add(a)
    return out
