"""The M codes of LinuxCNC that move nothing, as rs274 takes them.

Digital and analog I/O (M62-M68: M66 waits on an input, which a simulation takes as
already there), overrides (M48-M53), spindle orientation (M19), modal state save and
restore (M70-M73), the ``$`` spindle number (one spindle), M99 (in the main program: its end, as M2) and user M codes (M100-M199,
refused: LinuxCNC runs a program file for each, which dexmon cannot; M98 Fanuc-style calls
too). The words each one takes (P, Q, E, L, R) are marked used and
checked as LinuxCNC checks them (interp_check.cc, interp_convert.cc ``convert_m``).

M70 saves the modal state in the current call level's context, M73 too and marks it to be
restored when the subroutine returns, M71 invalidates it, M72 restores it. Restoring
runs the G and M codes LinuxCNC generates from the difference (``restore_settings``):
units first, then F (to 0.1), S (to 1), plane, cutter compensation, distance mode, feed
mode, coordinate system, G43/G49, retract mode, arc distance mode, G92.2/G92.3 and path
mode on one line, then spindle and coolant. The motion mode is not restored.
"""

from __future__ import annotations

from dataclasses import dataclass

from sim.gcode.errors import LineError
from sim.gcode.moves import COOLANT_FLOOD, COOLANT_MIST

#: LinuxCNC's modal group of each M code it knows (interp_array.cc ``_ems``): 4 stopping,
#: 5 I/O, 6 tool change, 7 spindle and modal state, 8 coolant, 9 overrides, 10 user codes
M_GROUP = {0: 4, 1: 4, 2: 4, 30: 4, 60: 4, 99: 4, 6: 6, 61: 6, 3: 7, 4: 7, 5: 7, 19: 7, 70: 7, 71: 7, 72: 7, 73: 7,
           7: 8, 8: 8, 9: 8, **{m: 9 for m in range(48, 54)}, **{m: 5 for m in range(62, 69)},
           **{m: 10 for m in range(100, 200)}}


def unknown_message(value: float) -> str:
    """Why ``M<value>`` is refused (it is in no group of :data:`M_GROUP`)."""
    if value == 98:
        return "M98 calls a Fanuc-style subprogram, which dexmon does not run: use o<name> call"
    if value > 199 and value == int(value):
        return f"unknown M code M{value:g}: LinuxCNC has none above M199 but those a remap defines"
    return f"unknown M code M{value:g}"


def live_only(name: str) -> str:
    """The end of the message refusing named parameter ``name``: why a HAL pin or INI
    value is not there (rs274 refuses them too)."""
    if name.startswith("_hal["):
        return " (it reads a HAL pin of a running LinuxCNC)"
    if name.startswith("_ini["):
        return " (it reads the machine's INI file, which dexmon does not have)"
    return ""


def m99_as_end(it, mode) -> int:
    """The stop code M0 M1 M2 M30 M60 as which ``mode`` (code, column) runs: M99 ends the
    main program as M2 does (rs274 with no loop_on_main_m99); in an o-word sub it is refused."""
    code, col = mode
    if code != 99:
        return code
    if len(it.contexts.frames) > 1:
        raise LineError("M99 returns from a Fanuc-style subprogram: end an o-word sub with endsub or return", col)
    return 2


#: the spindles rs274 has (num_spindles without an INI file)
SPINDLES = 1


def spindle_select(words, cols, mmodes, gmodes, motion, used) -> None:
    """LinuxCNC's ``$`` word (spindle number, -1: all) checked as rs274 checks it; dexmon
    has the one spindle, so the word changes nothing."""
    n = words["$"]
    col = cols["$"]
    code7 = mmodes.get(7, (None,))[0]
    code9 = mmodes.get(9, (None,))[0]
    spindle_mode = 14 in gmodes or gmodes.get(5, (None,))[0] == 950
    if not ("S" in words or code7 in (3, 4, 5, 19) or code9 == 51 or spindle_mode or motion in (330, 331)):
        raise LineError("$ word with no M3, M4, M5, M19, M51, G33, G33.1, G95 or G97 to use it", col)
    lowest = -1 if "S" in words or code7 in (3, 4, 5) else 1 if code9 == 51 else 0
    if not (n == int(n) and lowest <= n < SPINDLES):
        if lowest == 1:
            raise LineError(f"M51 ${n:g}: LinuxCNC's M51 takes spindle $1 or above, and rs274 has spindle $0 only",
                            col)
        raise LineError(f"there is no spindle ${n:g}: rs274 has spindle $0 only ($-1: all)", col)
    used.add("$")


def _comp_off(it, what: str, col: int) -> None:
    if it.comp != 400:
        raise LineError(f"cannot {what} with cutter compensation on", col)


def _index(words, cols, letter: str, code: int) -> int:
    v = words[letter]
    n = int(round(v))
    if n < 0:
        raise LineError(f"M{code} {letter} must be an input/output number of 0 or more", cols[letter])
    return n


def convert_io(it, mode, words, cols, used) -> None:
    """M62-M65 (digital outputs), M66 (wait on an input), M67/M68 (analog outputs)."""
    code, col = mode
    used.update(k for k in ("P", "E", "L", "Q") if k in words)
    if code in (62, 63, 64, 65):
        _comp_off(it, "set a digital output", col)
        if "P" not in words:
            raise LineError(f"M{code} needs a P word (output number)", col)
        _index(words, cols, "P", code)
    elif code == 66:
        if "P" in words and "E" in words:
            raise LineError("M66 takes a P (digital input) or an E (analog input), not both", cols["E"])
        q = words.get("Q", -1.0)
        mode_l = int(round(words["L"])) if "L" in words else 0
        if q <= 0 and mode_l > 0:
            raise LineError("M66 L1-L4 waits for an edge or level and needs a timeout Q above 0", cols["L"])
        if "E" in words and mode_l != 0:
            raise LineError("M66 on an analog input (E) only reads it: L must be 0", cols["L"])
        if "P" not in words and "E" not in words:
            raise LineError("M66 needs a P (digital input) or E (analog input) word", col)
        _index(words, cols, "P" if "P" in words else "E", code)
        _comp_off(it, "wait for an input", col)
    else:  # M67 M68
        _comp_off(it, "set an analog output", col)
        if "E" not in words:
            raise LineError(f"M{code} needs an E word (analog output number)", col)
        _index(words, cols, "E", code)


@dataclass
class Overrides:
    """What M48-M53 switch, as rs274 keeps it for ``#<_feed_override>`` and the like.
    The start values are rs274's stand-alone canon's: overrides enabled, feed hold allowed."""

    feed: bool = True        # M50, M48/M49
    speed: bool = True       # M51, M48/M49
    adaptive: bool = False   # M52
    hold: bool = True        # M53


def convert_overrides(it, mode, words, used) -> None:
    """M48/M49 (all overrides on/off), M50-M53 P (feed / spindle override, adaptive feed,
    feed hold): no effect on the move table, only on the parameters that report them."""
    code, col = mode
    if code >= 50 and "P" in words:
        used.add("P")
    _comp_off(it, "change overrides", col)
    o = it.overrides
    on = words.get("P", -1.0) != 0.0   # rs274: a missing P is -1, which enables
    if code in (48, 49):
        o.feed = o.speed = code == 48
    elif code == 50:
        o.feed = on
    elif code == 51:
        o.speed = on
    elif code == 52:
        o.adaptive = on
    else:
        o.hold = on


def convert_user(mode) -> None:
    """M100-M199: LinuxCNC runs the program file of that name from its user M code folder;
    rs274 (and dexmon) has none, so the code is refused as rs274 refuses it."""
    code, col = mode
    raise LineError(f"unknown M code M{code}: user M codes (M100-M199) run a program file from LinuxCNC's "
                    "USER_M_PATH, which dexmon cannot", col)


def convert_state(it, mode, words, cols, used) -> None:
    """The group-7 M codes that are no spindle turn: M19 (orient, stops the spindle),
    M70-M73 (modal state save and restore)."""
    code, col = mode
    if code == 19:
        _orient(it, col, words, cols, used)
    elif code in (70, 73):
        frame = it.contexts.frames[-1]
        frame.saved = _modes(it)
        if code == 73:
            if len(it.contexts.frames) == 1:
                it.messages.append((it.line, "M73 at the top level: nothing to return to; the state is saved anyway"))
            else:
                frame.restore_on_return = True
    elif code == 71:
        it.contexts.frames[-1].saved = None
    else:  # 72
        saved = it.contexts.frames[-1].saved
        if saved is None:
            raise LineError("M72 has no saved modal state to restore here: M70 or M73 first "
                            "(at this subroutine level; M71 discards it)", col)
        restore(it, saved, col)


def _orient(it, col, words, cols, used) -> None:
    if "P" in words:
        p = words["P"]
        if abs(round(p) - p) > 0.001 or not 0 <= round(p) <= 2:
            raise LineError("M19 P must be 0, 1 or 2 (direction)", cols["P"])
    if "R" in words and not 0.0 <= words["R"] <= 360.0:
        raise LineError("M19 R must be an angle from 0 to 360", cols["R"])
    if "Q" in words and words["Q"] <= 0.0:
        raise LineError("M19 Q (timeout) must be above 0", cols["Q"])
    used.update(k for k in ("P", "R", "Q") if k in words)
    it.spindle_dir = 0


# --- M70-M73 -------------------------------------------------------------------------------

@dataclass
class _Frame:
    """One call level's context: the state M70/M73 saved (None: nothing valid)."""

    saved: dict | None = None
    restore_on_return: bool = False   # M73: the return from this call level restores it


class Contexts:
    """LinuxCNC's saved modal states, one frame per subroutine call level."""

    def __init__(self):
        self.frames = [_Frame()]

    def enter(self) -> None:
        """A subroutine call: a new level with nothing saved."""
        self.frames.append(_Frame())

    def leave(self, it) -> None:
        """A subroutine return: after M73 in it, the caller's saved state comes back."""
        frame = self.frames.pop() if len(self.frames) > 1 else _Frame()
        if frame.restore_on_return and frame.saved is not None:
            restore(it, frame.saved, 1)


def _modes(it) -> dict:
    """What LinuxCNC's save_settings keeps: the active G and M codes, F and S."""
    coolant = it.coolant
    return {
        "units": it.units, "F": it.feed_word, "S": it.spindle,
        # the G codes of one restore line, in LinuxCNC's slot order
        "g": (it.plane, it.comp, it.distance, it.feed_mode, it.coord_code, 430 if any(it.tlo) else 490,
              it.retract, it.arc_distance, 923 if it.g92_enabled else 922, it.path_mode),
        # the M codes restored one per line: spindle, mist (M9 when neither), flood
        "m": ({1: 3, -1: 4}.get(it.spindle_dir, 5),
              7 if coolant & COOLANT_MIST else (None if coolant & COOLANT_FLOOD else 9),
              8 if coolant & COOLANT_FLOOD else None),
    }


def _g(code: int) -> str:
    return f"G{code // 10}" if code % 10 == 0 else f"G{code // 10}.{code % 10}"


def restore(it, saved: dict, col: int) -> None:
    """Bring back the state ``saved`` by running the lines LinuxCNC's restore_settings makes."""
    if it.units != saved["units"]:
        _run(it, _g(saved["units"]), col)
    now = _modes(it)
    words = []
    if saved["F"] != now["F"]:
        words.append(f"F{saved['F']:.1f}")   # LinuxCNC writes F with one decimal
    if saved["S"] != now["S"]:
        words.append(f"S{saved['S']:.0f}")
    words += [_g(code) for code, cur in zip(saved["g"], now["g"]) if code != cur]
    if words:
        _run(it, " ".join(words), col)
    for code, cur in zip(saved["m"], now["m"]):
        if code is not None and code != cur:
            _run(it, f"M{code}", col)


def _run(it, text: str, col: int) -> None:
    from sim.gcode.parser import parse_line

    try:
        it.execute_block(parse_line(text, it.dialect), it.line, it.file_index)
    except LineError as exc:
        raise LineError(f"restoring the saved modal state ({text}) failed: {exc.message}", col) from None
