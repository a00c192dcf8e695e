"""LinuxCNC's parameters as the interpreter reads and sets them: numbered ones (#1..#5602,
those that mirror the interpreter's state -- stored positions, work offsets, tool, the
current position -- read live from it) and named ones (``#<_global>`` and the local
frames of subroutine calls, with LinuxCNC's predefined ``#<_x>``, ``#<_metric>``...)."""

from __future__ import annotations

from sim.gcode import mcodes
from sim.gcode.errors import LineError
from sim.gcode.moves import COOLANT_FLOOD, COOLANT_MIST, INCH
from sim.gcode.tool_length import tool_parameter


#: (#<_vmajor>, #<_vminor>) of the LinuxCNC dexmon follows, 2.9.0: interp_namedparams.cc
#: init_named_parameters reads PACKAGE_VERSION "2.9.0" with sscanf("%lf%lf"): 2.9 then .0
LINUXCNC_VERSION = (2.9, 0.0)


class Parameters:
    """LinuxCNC parameter store: numbered (with the offset parameters live) and named."""

    def __init__(self, interp):
        self.it = interp
        self.numbered: dict[int, float] = {}
        self.globals: dict[str, float] = {}
        self.frames: list[dict[str, float]] = [{}]

    # numbered parameters that mirror interpreter state (program units)
    def get_numbered(self, idx: float) -> float:
        i = int(round(idx))
        if abs(idx - i) > 1e-6 or not 1 <= i <= 5602:
            raise LineError(f"parameter number #{idx:g} out of range 1..5602")
        it = self.it
        if 5161 <= i <= 5166:
            return self._user_out(it.g28[i - 5161], i - 5161)
        if 5181 <= i <= 5186:
            return self._user_out(it.g30[i - 5181], i - 5181)
        if 5211 <= i <= 5216:
            return self._user_out(it.g92_saved[i - 5211], i - 5211)
        if i == 5210:
            return 1.0 if it.g92_enabled else 0.0
        if i == 5220:
            return float(it.coord + 1)
        if 5221 <= i <= 5390:
            k, a = divmod(i - 5221, 20)
            if k < 9 and a < 6:
                return self._user_out(it.g5x[k][a], a)
            if k < 9 and a == 9:
                return 0.0  # rotation
        tool = tool_parameter(it, i)
        if tool is not None:
            return tool
        if 5420 <= i <= 5428 and it.comp != 400:
            raise LineError(f"cannot read the current position (#{i}) with cutter radius compensation on")
        if 5420 <= i <= 5425:
            w = it.work()
            return self._out(w[i - 5420], i - 5420)
        return self.numbered.get(i, 0.0)

    def _out(self, v: float, axis: int) -> float:
        return v / self.it.factor if axis < 3 else v

    # stored positions and offsets (#5161.. #5181.. #5211.. #5221..) are in machine units,
    # LinuxCNC's "user units", whatever G20/G21 says
    def _user_out(self, v: float, axis: int) -> float:
        return v / INCH if axis < 3 and self.it.machine_units == "inch" else v

    def _user_in(self, v: float, axis: int) -> float:
        return v * INCH if axis < 3 and self.it.machine_units == "inch" else v

    def set_numbered(self, idx: float, v: float) -> None:
        i = int(round(idx))
        if abs(idx - i) > 1e-6 or not 1 <= i <= 5602:
            raise LineError(f"parameter number #{idx:g} out of range 1..5602")
        if 5381 <= i <= 5390 or 5400 <= i <= 5413 or 5420 <= i <= 5428:
            raise LineError(f"parameter #{i} is read-only")
        it = self.it
        if 5161 <= i <= 5166:
            it.g28[i - 5161] = self._user_in(v, i - 5161)
        elif 5181 <= i <= 5186:
            it.g30[i - 5181] = self._user_in(v, i - 5181)
        elif 5211 <= i <= 5216:
            it.g92_saved[i - 5211] = self._user_in(v, i - 5211)
        elif 5221 <= i <= 5380:
            k, a = divmod(i - 5221, 20)
            if a < 6:
                it.g5x[k][a] = self._user_in(v, a)
        self.numbered[i] = v

    def at(self, column: int) -> "Parameters":
        """The parameters as read at ``column`` of the line: these (see :class:`LineParameters`)."""
        return self

    def get_named(self, name: str) -> float:
        if name.startswith("_"):
            if name in self.globals:
                return self.globals[name]
            v = self._predefined(name)
            if v is None:
                raise LineError(f"named parameter #<{name}> is not defined" + mcodes.live_only(name))
            return v
        frame = self.frames[-1]
        if name not in frame:
            raise LineError(f"named parameter #<{name}> is not defined")
        return frame[name]

    def set_named(self, name: str, v: float) -> None:
        if name.startswith("_"):
            self.globals[name] = v
        else:
            self.frames[-1][name] = v

    def exists(self, name: str) -> bool:
        if name.startswith("_"):
            return name in self.globals or self._predefined(name) is not None
        return name in self.frames[-1]

    def _predefined(self, name: str):
        it = self.it
        w = it.work()
        axes = {"_x": 0, "_y": 1, "_z": 2, "_a": 3, "_b": 4, "_c": 5}
        if name in axes:
            return self._out(w[axes[name]], axes[name])
        table = {
            "_metric": 1.0 if it.units == 210 else 0.0,
            "_imperial": 1.0 if it.units == 200 else 0.0,
            "_absolute": 1.0 if it.distance == 900 else 0.0,
            "_incremental": 1.0 if it.distance == 910 else 0.0,
            # G codes times ten, as LinuxCNC keeps them: G59.1 is 591 (programs restore
            # the work offset with G[#<_coord_system>/10])
            "_coord_system": float(it.coord_code),
            "_feed": it.feed_word,
            "_rpm": it.spindle,
            "_current_tool": float(it.tool),
            "_selected_tool": float(it.selected_tool),
            "_motion_mode": float(it.motion),
            "_plane": float(it.plane),
            "_value": self.globals.get("_value", 0.0),
            "_value_returned": self.globals.get("_value_returned", 0.0),
            "_line": float(it.line),
            "_task": 0.0,
            "_call_level": float(len(self.frames) - 1),
            "_remap_level": 0.0,      # dexmon has no remaps
            # no INI file, as for rs274 stand-alone: LinuxCNC gives -1 then (inicheck)
            "_metric_machine": -1.0,
            # LinuxCNC reads its version "M.N.m" as two numbers, M.N and .m
            "_vmajor": LINUXCNC_VERSION[0],
            "_vminor": LINUXCNC_VERSION[1],
        }
        if name in table:
            return table[name]
        return self._machine_state(name)

    def _machine_state(self, name: str):
        """The predefined parameters of the modes and switches rs274 reports as 1.0 / 0.0
        (or a G code times ten), interp_namedparams.cc lookup_named_param."""
        it = self.it
        if name in ("_abs_x", "_abs_y", "_abs_z", "_abs_a", "_abs_b", "_abs_c"):
            axis = "xyzabc".index(name[-1])
            return self._out(it.pos[axis], axis)   # the machine position, in program units
        o = it.overrides
        flags = {
            "_spindle_on": it.spindle_dir != 0,
            "_spindle_cw": it.spindle_dir > 0,
            "_mist": bool(it.coolant & COOLANT_MIST),
            "_flood": bool(it.coolant & COOLANT_FLOOD),
            "_speed_override": o.speed,
            "_feed_override": o.feed,
            "_adaptive_feed": o.adaptive,
            "_feed_hold": o.hold,
            "_tool_offset": any(it.tlo),
            "_inverse_time": it.feed_mode == 930,
            "_units_per_minute": it.feed_mode == 940,
            "_units_per_rev": it.feed_mode == 950,
            "_spindle_css_mode": False,   # G96 is refused: dexmon is always in G97
            "_spindle_rpm_mode": True,
            "_ijk_absolute_mode": it.arc_distance == 901,
            "_retract_r_plane": it.retract == 990,
            "_retract_old_z": it.retract == 980,
            "_lathe_diameter_mode": False,   # G7 is refused (lathe)
            "_lathe_radius_mode": True,
            "_u": False, "_v": False, "_w": False,   # no U V W axes
        }
        if name in flags:
            return 1.0 if flags[name] else 0.0
        if name == "_ccomp":
            return float(it.comp)
        if name == "_current_pocket":
            return it.pockets.current_value()
        if name == "_selected_pocket":
            return it.pockets.selected_value()
        return None


class LineParameters:
    """The parameters as rs274 reads one line that sets named parameters.

    rs274 reads a line left to right and defines a new named parameter as 0 when it reads
    its setting ``#<name>=`` (interp_read.cc read_named_parameter_setting -> add_named_param);
    values change only once the line is read. So on its line a name set there reads as its
    old value, or 0 when new, from the setting on (``#<d>=3 #<h>=[#<d>/2]`` gives h 0,
    ``#<q>=[#<q>+1]`` gives q 1), and is not defined before it (``G0 X#<z> #<z>=1`` fails).
    """

    def __init__(self, params: Parameters, assigns):
        self.params = params
        self.column = 0
        #: name -> column of its first setting on the line
        self.set_at: dict[str, int] = {}
        for target, _value, col in assigns:
            if target[0] == "n":
                self.set_at.setdefault(target[1], col)

    def at(self, column: int) -> "LineParameters":
        self.column = column
        return self

    def _new_here(self, name: str) -> bool:
        """``name`` was not defined before the line and its setting comes before the column."""
        return self.set_at.get(name, self.column) < self.column and not self.params.exists(name)

    def get_numbered(self, idx: float) -> float:
        return self.params.get_numbered(idx)

    def get_named(self, name: str) -> float:
        return 0.0 if self._new_here(name) else self.params.get_named(name)

    def exists(self, name: str) -> bool:
        return self._new_here(name) or self.params.exists(name)
