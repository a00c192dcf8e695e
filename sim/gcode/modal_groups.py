"""The modal groups of the G and M codes, and one line's codes sorted into them.

A line may hold one code of each modal group; which group a code is in decides the order
the interpreter (:mod:`sim.gcode.interpreter`) runs them in. G codes are kept in tenths
(G38.2 is 382). GRBL 1.1 knows a subset of LinuxCNC's codes and answers an unknown or
unsupported one with its own error numbers.
"""

from __future__ import annotations

from sim.gcode import mcodes
from sim.gcode.errors import LineError
from sim.gcode.lathe import lathe_message
from sim.gcode.mcodes import M_GROUP

#: the modal group of each G code (in tenths); 0 = non-modal
G_GROUP = {
    0: 1, 10: 1, 20: 1, 30: 1, 382: 1, 383: 1, 384: 1, 385: 1, 730: 1, 800: 1, 810: 1, 820: 1,
    830: 1, 850: 1, 860: 1, 890: 1, 740: 1, 840: 1, 870: 1, 880: 1, 50: 1, 51: 1, 330: 1, 331: 1,
    170: 2, 180: 2, 190: 2,
    900: 3, 910: 3,
    901: 4, 911: 4,
    930: 5, 940: 5, 950: 5,
    200: 6, 210: 6,
    400: 7, 410: 7, 411: 7, 420: 7, 421: 7,
    430: 8, 431: 8, 432: 8, 490: 8,
    980: 10, 990: 10,
    540: 12, 550: 12, 560: 12, 570: 12, 580: 12, 590: 12, 591: 12, 592: 12, 593: 12,
    610: 13, 611: 13, 640: 13,
    970: 14,
    40: 0, 100: 0, 280: 0, 281: 0, 300: 0, 301: 0, 530: 0, 920: 0,
    921: 16, 922: 16, 923: 16,   # LinuxCNC's own group, run after G10/G28/G30/G92 (GRBL: group 0)
}
#: the G and M codes GRBL 1.1 supports
GRBL_G = {0, 10, 20, 30, 382, 383, 384, 385, 40, 100, 170, 180, 190, 200, 210, 280, 281, 300, 301,
          400, 431, 490, 530, 540, 550, 560, 570, 580, 590, 610, 800, 900, 910, 911, 920, 921, 930, 940}
GRBL_M = {0, 1, 2, 30, 3, 4, 5, 8, 9, 56}
#: the canned cycles of the motion group (G73, G74, G81-G89)
CYCLES = {730, 740, 810, 820, 830, 840, 850, 860, 870, 880, 890}


def _code10(v: float) -> int:
    return int(round(v * 10.0))


def group_codes(glist, mlist, grbl: bool) -> tuple[dict[int, tuple[int, int]], dict[int, tuple[int, int]]]:
    """``(gmodes, mmodes)``: group -> (code, column) of a line's G codes (``glist``, (value,
    column) pairs; codes in tenths) and M codes (``mlist``). Raises LineError for an
    unknown code, one the dialect does not support, two codes of one group (LinuxCNC lets
    G80 give way to another motion code) or more than four M codes."""
    gmodes: dict[int, tuple[int, int]] = {}
    for v, col in glist:
        c = _code10(v)
        if abs(v * 10.0 - c) > 1e-6 or c not in G_GROUP:
            if grbl:
                raise LineError(f"G{v:g} is not a GRBL command", col, 23 if (c // 10 * 10) in GRBL_G and c % 10 else 20)
            raise LineError(lathe_message(c) or f"unknown G code G{v:g}", col)
        if grbl and c not in GRBL_G:
            raise LineError(f"GRBL does not support G{v:g}", col, 20)
        grp = 0 if grbl and G_GROUP[c] == 16 else G_GROUP[c]
        if grp in gmodes and not grbl and 800 in (c, gmodes[grp][0]):
            if c != 800:
                gmodes[grp] = (c, col)   # LinuxCNC: G80 gives way to another motion code
            continue
        if grp in gmodes:
            raise LineError(f"G{v:g} and G{gmodes[grp][0] / 10:g} are in the same modal group", col, 21)
        gmodes[grp] = (c, col)
    mmodes: dict[int, tuple[int, int]] = {}
    for v, col in mlist:
        c = int(round(v))
        if abs(v - c) > 1e-6 or c not in M_GROUP:
            if grbl:
                raise LineError(f"M{v:g} is not a GRBL command", col, 23 if abs(v - c) > 1e-6 else 20)
            raise LineError(mcodes.unknown_message(v), col)
        if grbl and c not in GRBL_M:
            raise LineError(f"GRBL does not support M{c}", col, 20)
        grp = M_GROUP[c]
        if grp in mmodes:  # M7 M8 too: rs274 2.9 and GRBL 1.1 refuse both on one line
            raise LineError(f"M{c} and M{mmodes[grp][0]} are in the same modal group", col, 21)
        mmodes[grp] = (c, col)
    if len(mlist) > 4:
        raise LineError("more than four M words on one line", mlist[4][1])
    return gmodes, mmodes
