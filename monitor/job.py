"""The job file (TOML): what is on the machine, what runs, what to watch for.

A job names the controller, the program, where the work is (work offset), the stock,
fixtures, tools, design model, resolution, tolerances, travel limits, how far to look
ahead and what to do on a finding. Example (every table optional except what the command
needs; paths are relative to the job file's folder)::

    [controller]
    url = "grbl:///dev/ttyUSB0?baud=115200"
    poll_hz = 50
    give_up_s = 600             # end the run (exit 2) when no fresh state came this long

    [program]
    path = "part.nc"
    dialect = "grbl"            # or "linuxcnc"
    var = "part.var"            # LinuxCNC parameter file: G54..G59.3 offsets, G28/G30, G92
    machine_units = "mm"        # units of the tool table and .var file ("mm" or "inch")
    subroutine_path = ["subs"]  # folders searched for o<name> call files (then the program's)
    work_system = "G54"         # the job's work system: stock, fixtures, design and
                                # work_offset are in it (G54..G59, G59.1..G59.3)
    max_loop = 100000           # passes of one o-word loop before it is called endless
                                # (and 10x as many blocks run beyond the file's lines)
    block_delete = false        # the controller's block delete switch: on skips '/' lines

    work_offset = [0, 0, 0]     # where the job's work system has its zero, machine coords
                                # (mm), or "controller" (from the WCO it reports)

    [stock]                     # in work coordinates, mm
    box = [0, 0, 0, 60, 40, 20] # or: cylinder = [cx, cy, radius, z0, z1]; or: stl = "stock.stl"
    offset = [0, 0, 0]          # moves an STL into place
    model = "z"                 # how simulate holds it: "z" (one grid of vertical rays) or
                                # "tri-dexel" (three grids, rays along X, Y and Z: walls
                                # and undercuts a tilted or turning tool makes; slower)
    # a bar on a 4th axis: cylinder = [cy, cz, radius, x0, x1] with axis = "x" (on the A
    # axis: cy, cz = rot_point's y, z less the work offset); axis = "y": [cx, cz, r, y0, y1]

    [[fixtures]]
    name = "clamp"
    box = [-5, 15, 20, 15, 25, 28]   # or stl = "vise.stl" (+ offset)
    on_table = true             # with a rotary table (xyza, xyzb, trunnions, head-table):
                                # the fixture sits on it and turns with the part (the
                                # default: what holds the part turns with it, a chuck's
                                # jaws, a clamp on the platter); false: it is fixed to the
                                # machine (a tailstock, a vise beside the 4th axis), given
                                # at A B C = 0

    [tools]
    table = "tools.tbl"         # LinuxCNC tool table; and/or inline tools:
    1 = "flat:6:L=20"
    [tools.2]
    spec = "ball:6:L=20"
    shank = [6, 30]             # diameter, length (mm)
    holder = [25, 40]

    [design]
    stl = "design.stl"

    resolution = 0.2            # dexel spacing, mm
    [tolerance]
    gouge = 0.05                # gouge band, mm
    interest = 1.0              # range of interest, mm
    [limits]                    # machine travel limits (machine coords, mm)
    x = [-300, 0]
    [lookahead]
    seconds = 5
    mm = 100
    [alerts]
    actions = ["log", "bell"]   # "feed_hold" lets dexmon hold the feed on a finding
    [machine]                   # program timing (lead times); each key overrides the controller's
    max_rate = [5000, 5000, 2000]   # mm/min (one number: every axis; six: + A B C deg/min)
    acceleration = [300, 300, 200]  # mm/s^2
    junction_deviation = 0.01       # mm
    start = [0, 0, 0]           # where the machine stands when the program starts: machine
                                # coords (mm, like [limits]), e.g. where it homes. Default:
                                # the top of [limits] z above the program's first point (else
                                # 10 mm above stock, fixtures and program); see monitor.start
    kinematics = "xyz"          # or xyza, xyzb (4th axis), xyzac-trt, xyzbc-trt (trunnion),
                                # xyzac-head-table, xyzbc-head-table, xyzac-head, xyzbc-head
                                # (LinuxCNC names trivkins, xyzac-trt-kins, xyzbc-trt-kins,
                                # 5axiskins too); see sim.kinematics
    rot_point = [0, 0, 0]       # mm, machine coords: a point of the 4th axis / the C table axis
    rot_offset = [0, 0, 0]      # trunnion: the tilt axis from rot_point, mm
    pivot_length = 0            # head: gauge point to the head's pivot, mm
    conventional_directions = false  # true: RS274 rotary directions, not LinuxCNC's

Errors name the file, the key and what was expected:
``job.toml: [stock] box: expected 6 numbers (mm), got "abc"``.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from sim.errors import InputError
from sim.kinematics import KINEMATICS, PARAMETERS as KINEMATICS_PARAMETERS, Kinematics, KinematicsError, \
    Trivial, kinematics_name, make_kinematics
from sim.tolerance import Tolerance

ALERT_ACTIONS = ("log", "bell", "feed_hold")
#: program timing for what neither the job's [machine] nor the controller says: brisk
#: enough that lead times err short
#: (an early alert is safe, a late one is not)
DEFAULT_MACHINE = {"max_rate": (5000.0, 5000.0, 5000.0), "acceleration": (500.0, 500.0, 500.0),
                   "junction_deviation": 0.02}
#: s without a fresh state from the controller before a live run gives up (exit 2)
DEFAULT_GIVE_UP_S = 600.0
#: the fastest poll rate a job may ask for (Hz): past it the loop polls faster than it
#: can follow, and a dry run's simulated clock (speed / poll_hz a poll) barely moves
MAX_POLL_HZ = 1000.0
#: the slowest (Hz): the monitor knows where the tool is only at a poll, and at 5000 mm/min
#: a tool goes 83 mm in a second; slower, a feed hold would come too late to matter
MIN_POLL_HZ = 1.0
DIALECTS = ("linuxcnc", "grbl")
MACHINE_UNITS = ("mm", "inch")
#: the work systems, in the order of the interpreter's offset table (G54 = 0 ... G59.3 = 8)
WORK_SYSTEMS = ("G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3")
AXES = ("x", "y", "z")
#: how a stock is modelled (``[stock] model``): one Z grid, or three grids (sim.tridexel)
STOCK_MODELS = ("z", "tri-dexel")


class JobError(InputError):
    """A job file or job flag that is not what was expected."""


@dataclass(frozen=True)
class Solid:
    """A placed solid: a box, a cylinder or an STL, in work coordinates (mm).

    ``box`` is (x0, y0, z0, x1, y1, z1); ``cylinder`` is (c1, c2, radius, lo, hi) along
    ``axis`` ("z": cx, cy, radius, z0, z1; "x": cy, cz, radius, x0, x1, a bar on a 4th
    axis; "y": cx, cz, radius, y0, y1); ``stl`` a path, moved by ``offset`` (3,) mm.
    ``on_table`` (fixtures): it sits on the rotary table and turns with the part (True),
    is fixed to the machine (False), or None: the default (:meth:`Job.fixture_on_table`).
    """

    kind: str
    box: tuple[float, ...] | None = None
    cylinder: tuple[float, ...] | None = None
    stl: Path | None = None
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    name: str = ""
    axis: str = "z"
    on_table: bool | None = None

    def cylinder_placement(self):
        """A cylinder's (base centre (3,), axis direction (3,), radius, height), mm."""
        c1, c2, r, lo, hi = self.cylinder
        k = AXES.index(self.axis)
        across = [i for i in range(3) if i != k]
        base = [0.0, 0.0, 0.0]
        base[across[0]], base[across[1]], base[k] = c1, c2, lo
        direction = [0.0, 0.0, 0.0]
        direction[k] = 1.0
        return tuple(b + o for b, o in zip(base, self.offset)), tuple(direction), r, hi - lo

    def bounds(self):
        """(lo (3,), hi (3,)) in mm, or None for an STL (known once loaded)."""
        o = self.offset
        if self.kind == "box":
            b = self.box
            return (b[0] + o[0], b[1] + o[1], b[2] + o[2]), (b[3] + o[0], b[4] + o[1], b[5] + o[2])
        if self.kind == "cylinder":
            base, direction, r, h = self.cylinder_placement()
            lo = tuple(b - r * (1 - d) for b, d in zip(base, direction))
            hi = tuple(b + r * (1 - d) + h * d for b, d in zip(base, direction))
            return lo, hi
        return None


@dataclass(frozen=True)
class ToolDef:
    """One tool: its spec (``ball:6:L=20``) and optional shank/holder (diameter, length) mm."""

    number: int
    spec: str
    shank: tuple[float, float] | None = None
    holder: tuple[float, float] | None = None


@dataclass
class Job:
    """Everything a session needs to know besides the live states."""

    source: Path | None = None          # the job file, when there is one
    text: str = ""                      # its TOML text (recorded in the run file)
    controller: str | None = None       # controller URL
    poll_hz: float = 50.0
    give_up_s: float = DEFAULT_GIVE_UP_S  # s without a fresh state before the run ends (exit 2)
    program: Path | None = None
    dialect: str = "linuxcnc"
    var_file: Path | None = None        # LinuxCNC .var file (work offsets ...), in machine_units
    machine_units: str = "mm"           # units of the tool table and the .var file
    subroutine_path: list[Path] = field(default_factory=list)
    max_loop: int = 100_000             # passes of one o-word loop (sim.gcode.limits.Limits.max_loop)
    block_delete: bool = False          # the block delete switch: on, '/' lines are skipped
    work_system: str = "G54"            # the model frame: stock, fixtures, design are in it
    work_offset: tuple[float, float, float] | None = None  # None: read from the controller (WCO)
    stock: Solid | None = None
    #: how ``simulate`` models the stock, one of :data:`STOCK_MODELS` ([stock] model)
    stock_model: str = "z"
    fixtures: list[Solid] = field(default_factory=list)
    tools: dict[int, ToolDef] = field(default_factory=dict)
    default_tool: ToolDef | None = None  # used for any tool number not in ``tools``
    tool_table: Path | None = None
    design: Solid | None = None
    resolution: float = 0.5
    tolerance: Tolerance = field(default_factory=Tolerance)
    #: the job (or the command line) gave the undercut tolerance; else it is at least the
    #: scallop of the path's stepover (sim.checks.scallop)
    undercut_given: bool = False
    limits: dict[str, tuple[float, float]] = field(default_factory=dict)
    horizon_s: float = 5.0
    horizon_mm: float | None = None
    alerts: tuple[str, ...] = ("log",)
    #: machine limits for program timing, only the keys the job gives: {"max_rate": (3,)
    #: mm/min, "acceleration": (3,) mm/s^2, "junction_deviation": mm}; each key left out
    #: comes from the controller, else :data:`DEFAULT_MACHINE` (see monitor.machine)
    machine: dict | None = None
    #: where the machine stands when the program starts, machine coords (3,) mm; None: the
    #: default of :func:`monitor.start.job_start`
    start: tuple[float, float, float] | None = None
    #: the machine's kinematics ([machine] kinematics and its parameters): how A B C turn
    #: the part or the tool (sim.kinematics); plain 3-axis by default
    kinematics: Kinematics = field(default_factory=Trivial)

    def fixture_on_table(self, fixture: Solid) -> bool:
        """Whether ``fixture`` turns with the part: its ``on_table`` when given, else
        whether the kinematics has a rotary table (what holds the part sits on it)."""
        return bool(self.kinematics.table) if fixture.on_table is None else fixture.on_table

    @property
    def program_dialect(self) -> str:
        """The dialect the program is read in: ``dialect``, and on a grbl machine whose
        kinematics has rotaries, ``"grbl+"`` those letters (grblHAL with 4+ axes takes
        their words; plain Grbl 1.1 refuses A B C)."""
        if self.dialect == "grbl" and self.kinematics.rotaries:
            return "grbl+" + "".join(sorted(self.kinematics.rotaries))
        return self.dialect

    def tool(self, number: int) -> ToolDef | None:
        """The tool for tool number ``number`` (the default tool when it is not listed)."""
        return self.tools.get(int(number), self.default_tool)

    @property
    def feed_hold(self) -> bool:
        return "feed_hold" in self.alerts


# --- parsing helpers: each names file, table and key --------------------------------------

class _Ctx:
    def __init__(self, name: str, base: Path):
        self.name = name
        self.base = base

    def err(self, where: str, expected: str, got=None) -> JobError:
        tail = "" if got is None else f", got {_show(got)}"
        return JobError(f"{where}: expected {expected}{tail}", self.name)

    def numbers(self, value, n: int, where: str, what: str = "mm") -> tuple[float, ...]:
        given = value
        if isinstance(value, str):
            value = _split_numbers(value)
        if not isinstance(value, (list, tuple)) or len(value) != n:
            raise self.err(where, f"{n} numbers ({what})", given)
        out = []
        for v in value:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise self.err(where, f"{n} numbers ({what})", given)
            out.append(float(v))
        return tuple(out)

    def positive(self, value, where: str, what: str = "mm") -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (value > 0) \
                or not math.isfinite(value):
            raise self.err(where, f"a positive number ({what})", value)
        return float(value)

    def path(self, value, where: str, must_exist: bool = True) -> Path:
        if not isinstance(value, str) or not value:
            raise self.err(where, "a file path", value)
        p = Path(value).expanduser()
        if not p.is_absolute():
            p = self.base / p
        if must_exist and not p.is_file():
            raise JobError(f"{where}: file {str(p)!r} not found", self.name)
        return p

    def table(self, value, where: str) -> dict:
        if not isinstance(value, dict):
            raise self.err(where, "a table", value)
        return value

    def no_unknown(self, table: dict, known, where: str) -> None:
        extra = sorted(set(table) - set(known))
        if extra:
            raise JobError(f"{where}: unknown key {extra[0]!r}; expected one of {', '.join(sorted(known))}",
                           self.name)


def _show(v) -> str:
    return f'"{v}"' if isinstance(v, str) else repr(v)


def _split_numbers(text: str):
    try:
        return [float(t) for t in text.replace(";", ",").split(",") if t.strip()]
    except ValueError:
        return text


def _solid(ctx: _Ctx, t: dict, where: str, allow=("box", "cylinder", "stl"), extra=()) -> Solid:
    """A solid from its table; ``extra``: further keys the caller reads (ignored here)."""
    t = ctx.table(t, where)
    ctx.no_unknown(t, set(allow) | {"offset", "name"} | set(extra) | ({"axis"} if "cylinder" in t else set()),
                   where)
    given = [k for k in allow if k in t]
    if len(given) != 1:
        raise JobError(f"{where or 'solid'}: expected exactly one of {', '.join(allow)}, got "
                       f"{', '.join(given) or 'none'}", ctx.name)
    kind = given[0]
    offset = ctx.numbers(t.get("offset", [0, 0, 0]), 3, f"{where} offset".strip())
    name = str(t.get("name", ""))
    if kind == "box":
        b = ctx.numbers(t["box"], 6, f"{where} box".strip(), "mm: x0, y0, z0, x1, y1, z1")
        if not (b[3] > b[0] and b[4] > b[1] and b[5] > b[2]):
            raise ctx.err(f"{where} box".strip(), "x0 < x1, y0 < y1, z0 < z1", list(b))
        return Solid("box", box=b, offset=offset, name=name)
    if kind == "cylinder":
        axis = t.get("axis", "z")
        if not isinstance(axis, str) or axis.lower() not in AXES:
            raise ctx.err(f"{where} axis".strip(), '"x", "y" or "z" (the cylinder\'s axis)', axis)
        axis = axis.lower()
        a, b = [c for c in AXES if c != axis]
        c = ctx.numbers(t["cylinder"], 5, f"{where} cylinder".strip(),
                        f"mm: c{a}, c{b}, radius, {axis}0, {axis}1")
        if not (c[2] > 0 and c[4] > c[3]):
            raise ctx.err(f"{where} cylinder".strip(), f"radius > 0 and {axis}0 < {axis}1", list(c))
        return Solid("cylinder", cylinder=c, offset=offset, name=name, axis=axis)
    return Solid("stl", stl=ctx.path(t["stl"], f"{where} stl".strip()), offset=offset, name=name)


def _fixture(ctx: _Ctx, t, where: str) -> Solid:
    """A [[fixtures]] entry: a box or STL solid, and ``on_table`` (true or false) when given."""
    t = dict(ctx.table(t, where))
    ctx.no_unknown(t, {"box", "stl", "offset", "name", "on_table"}, where)
    on_table = t.pop("on_table", None)
    if on_table is not None and not isinstance(on_table, bool):
        raise ctx.err(f"{where} on_table", "true (it sits on the rotary table and turns with the part) or "
                                           "false (fixed to the machine)", on_table)
    return dataclasses.replace(_solid(ctx, t, where, allow=("box", "stl")), on_table=on_table)


def parse_solid_spec(spec: str, where: str, base: Path = Path(".")) -> Solid:
    """A solid from a flag: ``box:x0,y0,z0,x1,y1,z1``, ``cylinder:cx,cy,r,z0,z1`` or ``stl:PATH``
    (a bare path ending in .stl is an STL too). ``where`` names the flag in errors."""
    kind, _, rest = spec.partition(":")
    if kind not in ("box", "cylinder", "stl") and spec.lower().endswith(".stl"):
        kind, rest = "stl", spec
    if kind not in ("box", "cylinder", "stl"):
        raise JobError(f"expected box:x0,y0,z0,x1,y1,z1, cylinder:cx,cy,r,z0,z1 or stl:PATH, got {_show(spec)}",
                       where)
    return _solid(_Ctx(where, base), {kind: rest}, "", allow=(kind,))


#: help text of ``--max-loop`` (job, moves and simulate commands)
MAX_LOOP_HELP = "passes of one o-word loop (and the largest repeat count) before the program is refused " \
                "as endless (default 100000)"


#: help text of ``--block-delete`` (job, moves and simulate commands)
BLOCK_DELETE_HELP = "skip the lines that start with '/', as a controller with its block delete switch on " \
                    "(default: they run, as LinuxCNC starts with the switch off)"


def _stock_model(ctx: _Ctx, value, where: str) -> str:
    if value not in STOCK_MODELS:
        raise ctx.err(where, '"z" (one grid of vertical rays) or "tri-dexel" (grids along X, Y and Z)', value)
    return value


def _count(ctx: _Ctx, value, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ctx.err(where, "a positive whole number", value)
    return value


def _machine_units(ctx: _Ctx, value, where: str) -> str:
    if value not in MACHINE_UNITS:
        raise ctx.err(where, '"mm" or "inch"', value)
    return value


def _work_system(ctx: _Ctx, value, where: str) -> str:
    name = value.strip().upper() if isinstance(value, str) else value
    if name not in WORK_SYSTEMS:
        raise ctx.err(where, f"one of {', '.join(WORK_SYSTEMS)}", value)
    return name


def _dirs(ctx: _Ctx, value, where: str) -> list[Path]:
    """Folders from a list of paths or one string (``os.pathsep``-separated, like
    LinuxCNC's SUBROUTINE_PATH); each must exist."""
    import os

    if isinstance(value, str):
        value = [d for d in value.split(os.pathsep) if d]
    if not isinstance(value, list) or not all(isinstance(d, str) and d for d in value):
        raise ctx.err(where, "a list of folder paths", value)
    out = []
    for d in value:
        p = Path(d).expanduser()
        if not p.is_absolute():
            p = ctx.base / p
        if not p.is_dir():
            raise JobError(f"{where}: folder {str(p)!r} not found", ctx.name)
        out.append(p)
    return out


def work_system_index(name: str) -> int:
    """Index of a work system in the interpreter's offset table (G54 = 0 ... G59.3 = 8)."""
    return WORK_SYSTEMS.index(name.upper())


def _tool(ctx: _Ctx, number: int, value, where: str) -> ToolDef:
    if isinstance(value, str):
        return ToolDef(number, _spec(ctx, value, where))
    t = ctx.table(value, where)
    ctx.no_unknown(t, {"spec", "shank", "holder"}, where)
    if "spec" not in t:
        raise ctx.err(f"{where} spec", 'a tool spec like "ball:6:L=20"')
    shank = ctx.numbers(t["shank"], 2, f"{where} shank", "mm: diameter, length") if "shank" in t else None
    holder = ctx.numbers(t["holder"], 2, f"{where} holder", "mm: diameter, length") if "holder" in t else None
    for dims, key in ((shank, "shank"), (holder, "holder")):
        if dims is not None and not (dims[0] > 0 and dims[1] > 0):
            raise ctx.err(f"{where} {key}", "positive diameter and length (mm)", list(dims))
    return ToolDef(number, _spec(ctx, t["spec"], f"{where} spec"), shank, holder)


def _spec(ctx: _Ctx, value, where: str) -> str:
    if not isinstance(value, str) or ":" not in value:
        raise ctx.err(where, 'a tool spec like "flat:6" or "ball:6:L=20"', value)
    return value.strip()


def _kinematics(ctx: _Ctx, given: dict) -> Kinematics:
    """The kinematics [machine] names, with its parameters (``given``: the keys as in the file)."""
    name = given.pop("kinematics", "xyz")
    key = kinematics_name(name) if isinstance(name, str) else None
    if key is None:
        raise ctx.err("[machine] kinematics", f"one of {', '.join(KINEMATICS)}", name)
    takes = KINEMATICS[key][2]
    params = {}
    for k, v in given.items():
        where = f"[machine] {k}"
        if k not in takes:
            raise JobError(f"{where}: not used by kinematics {key!r}"
                           + (f" (it takes {', '.join(takes)})" if takes else " (plain 3-axis: give kinematics)"),
                           ctx.name)
        if k == "rot_point":
            params[k] = ctx.numbers(v, 3, where, "mm, machine coords: a point of the rotary axis")
        elif k == "rot_offset":
            params[k] = ctx.numbers(v, 3, where, "mm: the tilt axis from rot_point")
        elif k == "pivot_length":
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (v >= 0) or not math.isfinite(v):
                raise ctx.err(where, "a number >= 0 (mm, gauge point to the head's pivot)", v)
            params[k] = float(v)
        else:  # conventional_directions
            if not isinstance(v, bool):
                raise ctx.err(where, "true or false", v)
            params[k] = v
    try:
        return make_kinematics(key, **params)
    except KinematicsError as exc:  # what the checks above let through: still one clear line
        raise JobError(f"[machine]: {exc}", ctx.name) from None


def parse_job_text(text: str, name: str = "job.toml", base: Path | None = None) -> Job:
    """Parse job TOML ``text``; ``name`` is used in errors, ``base`` resolves relative paths."""
    base = Path(".") if base is None else base
    ctx = _Ctx(name, base)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise JobError(f"not valid TOML ({exc})", name) from None
    known = {"controller", "program", "work_offset", "stock", "fixtures", "tools", "design",
             "resolution", "tolerance", "limits", "lookahead", "alerts", "machine"}
    ctx.no_unknown(doc, known, "top level")
    job = Job(text=text)

    if "controller" in doc:
        t = ctx.table(doc["controller"], "[controller]")
        ctx.no_unknown(t, {"url", "poll_hz", "give_up_s"}, "[controller]")
        if "url" in t:
            if not isinstance(t["url"], str) or "://" not in t["url"]:
                raise ctx.err("[controller] url", 'a controller URL like "grbl:///dev/ttyUSB0"', t["url"])
            job.controller = t["url"]
        if "poll_hz" in t:
            job.poll_hz = ctx.positive(t["poll_hz"], "[controller] poll_hz", "Hz")
            if job.poll_hz < MIN_POLL_HZ:
                raise ctx.err("[controller] poll_hz", f"at least {MIN_POLL_HZ:g} Hz (the monitor sees the tool only "
                              "when it polls: at 5000 mm/min the tool goes 83 mm in a second, and a feed hold "
                              "comes a poll late)", t["poll_hz"])
            if job.poll_hz > MAX_POLL_HZ:
                raise ctx.err("[controller] poll_hz", f"at most {MAX_POLL_HZ:g} Hz (a poll a millisecond: each "
                              "state's cut and checks take about that long, and controllers answer 50 polls a "
                              "second or fewer)", t["poll_hz"])
        if "give_up_s" in t:
            job.give_up_s = ctx.positive(t["give_up_s"], "[controller] give_up_s", "s")

    if "program" in doc:
        t = doc["program"]
        if isinstance(t, str):
            t = {"path": t}
        t = ctx.table(t, "[program]")
        ctx.no_unknown(t, {"path", "dialect", "var", "machine_units", "subroutine_path", "work_system",
                           "max_loop", "block_delete"}, "[program]")
        if "path" in t:
            job.program = ctx.path(t["path"], "[program] path")
        if "dialect" in t:
            if t["dialect"] not in DIALECTS:
                raise ctx.err("[program] dialect", " or ".join(DIALECTS), t["dialect"])
            job.dialect = t["dialect"]
        if "var" in t:
            job.var_file = ctx.path(t["var"], "[program] var")
        if "machine_units" in t:
            job.machine_units = _machine_units(ctx, t["machine_units"], "[program] machine_units")
        if "subroutine_path" in t:
            job.subroutine_path = _dirs(ctx, t["subroutine_path"], "[program] subroutine_path")
        if "work_system" in t:
            job.work_system = _work_system(ctx, t["work_system"], "[program] work_system")
        if "max_loop" in t:
            job.max_loop = _count(ctx, t["max_loop"], "[program] max_loop")
        if "block_delete" in t:
            if not isinstance(t["block_delete"], bool):
                raise ctx.err("[program] block_delete", "true or false", t["block_delete"])
            job.block_delete = t["block_delete"]

    if "work_offset" in doc:
        v = doc["work_offset"]
        job.work_offset = None if v == "controller" else ctx.numbers(v, 3, "work_offset",
                                                                      'mm, or "controller"')

    if "stock" in doc:
        job.stock = _solid(ctx, doc["stock"], "[stock]", extra=("model",))
        if "model" in doc["stock"]:
            job.stock_model = _stock_model(ctx, doc["stock"]["model"], "[stock] model")
    if "fixtures" in doc:
        fx = doc["fixtures"]
        if not isinstance(fx, list):
            raise ctx.err("[[fixtures]]", "an array of tables ([[fixtures]])", fx)
        job.fixtures = [_fixture(ctx, f, f"[[fixtures]] #{k + 1}") for k, f in enumerate(fx)]
    if "design" in doc:
        job.design = _solid(ctx, doc["design"], "[design]", allow=("stl", "box"))

    if "tools" in doc:
        t = ctx.table(doc["tools"], "[tools]")
        for key, value in t.items():
            if key == "table":
                job.tool_table = ctx.path(value, "[tools] table")
            elif key == "default":
                job.default_tool = _tool(ctx, 0, value, "[tools] default")
            elif key.isdigit():
                job.tools[int(key)] = _tool(ctx, int(key), value, f"[tools] {key}")
            else:
                raise JobError(f'[tools]: unknown key {key!r}; expected "table", "default" or a tool number',
                               name)

    if "resolution" in doc:
        job.resolution = ctx.positive(doc["resolution"], "resolution")

    if "tolerance" in doc:
        t = ctx.table(doc["tolerance"], "[tolerance]")
        ctx.no_unknown(t, {"gouge", "undercut", "interest"}, "[tolerance]")
        job.tolerance = dataclasses.replace(
            job.tolerance, **{k: ctx.positive(v, f"[tolerance] {k}") for k, v in t.items()})
        job.undercut_given = "undercut" in t

    if "limits" in doc:
        t = ctx.table(doc["limits"], "[limits]")
        ctx.no_unknown(t, AXES, "[limits]")
        for axis, v in t.items():
            lo, hi = ctx.numbers(v, 2, f"[limits] {axis}", "mm: min, max")
            if not lo < hi:
                raise ctx.err(f"[limits] {axis}", "min < max", v)
            job.limits[axis] = (lo, hi)

    if "lookahead" in doc:
        t = ctx.table(doc["lookahead"], "[lookahead]")
        ctx.no_unknown(t, {"seconds", "mm"}, "[lookahead]")
        if "seconds" in t:
            job.horizon_s = ctx.positive(t["seconds"], "[lookahead] seconds", "s")
        if "mm" in t:
            job.horizon_mm = ctx.positive(t["mm"], "[lookahead] mm")

    if "alerts" in doc:
        t = ctx.table(doc["alerts"], "[alerts]")
        ctx.no_unknown(t, {"actions"}, "[alerts]")
        acts = t.get("actions", [])
        if not isinstance(acts, list) or any(a not in ALERT_ACTIONS for a in acts):
            raise ctx.err("[alerts] actions", f"a list of {', '.join(ALERT_ACTIONS)}", acts)
        job.alerts = tuple(acts)

    if isinstance(doc.get("machine"), dict) and "start" in doc["machine"]:
        # where the machine stands, not a timing limit: taken out first (alone, the
        # timing stays the default)
        rest = dict(doc["machine"])
        job.start = ctx.numbers(rest.pop("start"), 3, "[machine] start", "mm, machine coords: x, y, z")
        doc["machine"] = rest
        if not rest:
            del doc["machine"]
    if isinstance(doc.get("machine"), dict) and set(doc["machine"]) & ({"kinematics"} | set(KINEMATICS_PARAMETERS)):
        # the machine's build, not a timing limit: taken out like start
        rest = dict(doc["machine"])
        given = {k: rest.pop(k) for k in ("kinematics",) + KINEMATICS_PARAMETERS if k in rest}
        job.kinematics = _kinematics(ctx, given)
        doc["machine"] = rest
        if not rest:
            del doc["machine"]
    if "machine" in doc:
        t = ctx.table(doc["machine"], "[machine]")
        ctx.no_unknown(t, {"max_rate", "acceleration", "junction_deviation", "start", "kinematics",
                           *KINEMATICS_PARAMETERS}, "[machine]")
        m = {}  # only what the job says: the rest comes from the controller, else the defaults
        for key, unit in (("max_rate", "mm/min"), ("acceleration", "mm/s^2")):
            if key in t:
                v = t[key]
                if isinstance(v, (int, float)) and not isinstance(v, bool):
                    v = [v, v, v]
                # six: X Y Z and the rotaries A B C (deg/min, deg/s^2)
                count = 6 if isinstance(v, list) and len(v) == 6 else 3
                vals = ctx.numbers(v, count, f"[machine] {key}", f"{unit}, one, three (X Y Z) or six (+ A B C)")
                if min(vals) <= 0:
                    raise ctx.err(f"[machine] {key}", f"positive numbers ({unit})", t[key])
                m[key] = vals
        if "junction_deviation" in t:
            m["junction_deviation"] = ctx.positive(t["junction_deviation"], "[machine] junction_deviation")
        job.machine = m
    for k, f in enumerate(job.fixtures):
        if f.on_table and not job.kinematics.table:
            raise JobError(f"[[fixtures]] #{k + 1} on_table: kinematics {job.kinematics.name!r} has no rotary "
                           "table to turn it (on_table = true needs xyza, xyzb, a trunnion or a head-table "
                           "machine in [machine] kinematics)", name)
    return job


def load_job(path: str | Path) -> Job:
    """Read and parse a job file; relative paths in it resolve against its folder."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise JobError("job file not found", str(path)) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise JobError(f"cannot read the job file ({exc})", str(path)) from None
    job = parse_job_text(text, name=path.name if path.parent == Path(".") else str(path),
                         base=path.resolve().parent)
    job.source = path
    return job


# --- command-line flags -----------------------------------------------------------------

def add_job_arguments(parser) -> None:
    """The flags that override a job file (or make a job without one)."""
    g = parser.add_argument_group("job (override the job file)")
    g.add_argument("--program", help="G-code program file")
    g.add_argument("--dialect", choices=DIALECTS, help="G-code dialect")
    g.add_argument("--controller", help="controller URL, e.g. grbl:///dev/ttyUSB0")
    g.add_argument("--stock", help="box:x0,y0,z0,x1,y1,z1 | cylinder:cx,cy,r,z0,z1 | stl:PATH (work coords, mm)")
    g.add_argument("--fixture", action="append", default=None, help="box:... or stl:PATH; repeatable")
    g.add_argument("--tool", help="tool spec used for every tool number, e.g. ball:6:L=20")
    g.add_argument("--tool-table", help="LinuxCNC tool table")
    g.add_argument("--var", metavar="FILE.var",
                   help="LinuxCNC parameter (.var) file: work offsets G54..G59.3, G28/G30 (in --machine-units)")
    g.add_argument("--machine-units", choices=MACHINE_UNITS, help="units of the tool table and .var file")
    g.add_argument("--subroutine-path", action="append", metavar="DIRS", default=None,
                   help="folders searched for o<name> call files, os.pathsep-separated; repeatable")
    g.add_argument("--work-system", help="the job's work system (G54..G59.3) stock and fixtures are in")
    g.add_argument("--max-loop", type=int, metavar="N", help=MAX_LOOP_HELP)
    g.add_argument("--block-delete", action="store_true", default=None, help=BLOCK_DELETE_HELP)
    g.add_argument("--design", help="design model STL")
    g.add_argument("--resolution", type=float, help="dexel spacing, mm")
    g.add_argument("--gouge-tol", type=float, help="gouge band, mm")
    g.add_argument("--horizon", type=float, help="look-ahead horizon, s")
    g.add_argument("--horizon-mm", type=float, help="look-ahead horizon, mm of path")
    g.add_argument("--work-offset", help='work zero in machine coords "x,y,z" (mm) or "controller"')
    g.add_argument("--give-up", type=float, metavar="SECONDS",
                   help="end the run (exit 2) when the controller gave no fresh state this long (default 600)")
    g.add_argument("--feed-hold", action="store_true", default=None,
                   help="hold the feed when a finding is predicted (off unless given)")


def job_from_args(args, job_path: str | Path | None = None) -> Job:
    """Load ``job_path`` (if any) and apply the flags in ``args`` over it."""
    job = load_job(job_path) if job_path else Job()
    ctx = _Ctx("command line", Path("."))
    g = lambda name: getattr(args, name, None)  # noqa: E731
    if g("program"):
        job.program = ctx.path(g("program"), "--program")
    if g("dialect"):
        job.dialect = g("dialect")
    if g("controller"):
        job.controller = g("controller")
    if g("stock"):
        job.stock = parse_solid_spec(g("stock"), "--stock")
    if g("fixture"):
        job.fixtures = [parse_solid_spec(s, "--fixture") for s in g("fixture")]
    if g("tool"):
        job.default_tool = ToolDef(0, _spec(_Ctx("--tool", Path(".")), g("tool"), "value"))
        job.tools = {}
    if g("tool_table"):
        job.tool_table = ctx.path(g("tool_table"), "--tool-table")
    if g("var"):
        job.var_file = ctx.path(g("var"), "--var")
    if g("machine_units"):
        job.machine_units = _machine_units(ctx, g("machine_units"), "--machine-units")
    if g("subroutine_path"):
        job.subroutine_path = [d for arg in g("subroutine_path")
                               for d in _dirs(ctx, arg, "--subroutine-path")]
    if g("work_system"):
        job.work_system = _work_system(ctx, g("work_system"), "--work-system")
    if g("max_loop") is not None:
        job.max_loop = _count(ctx, g("max_loop"), "--max-loop")
    if g("block_delete"):
        job.block_delete = True
    if g("design"):
        spec = g("design")
        job.design = parse_solid_spec(spec if ":" in spec and not spec.lower().endswith(".stl")
                                      else f"stl:{spec}", "--design")
    if g("resolution") is not None:
        job.resolution = ctx.positive(g("resolution"), "--resolution")
    if g("gouge_tol") is not None:
        job.tolerance = dataclasses.replace(job.tolerance, gouge=ctx.positive(g("gouge_tol"), "--gouge-tol"))
    if g("horizon") is not None:
        job.horizon_s = ctx.positive(g("horizon"), "--horizon", "s")
    if g("horizon_mm") is not None:
        job.horizon_mm = ctx.positive(g("horizon_mm"), "--horizon-mm")
    if g("work_offset"):
        v = g("work_offset")
        job.work_offset = None if v == "controller" else ctx.numbers(v, 3, "--work-offset", 'mm, or "controller"')
    if g("give_up") is not None:
        job.give_up_s = ctx.positive(g("give_up"), "--give-up", "s")
    if g("feed_hold"):
        job.alerts = tuple(dict.fromkeys(job.alerts + ("feed_hold",)))
    return job


def require(job: Job, *what: str) -> None:
    """Raise a clear error when the job lacks a piece the command needs."""
    flags = {"program": "--program", "stock": "--stock", "controller": "--controller"}
    for w in what:
        if getattr(job, w) is None:
            where = str(job.source) if job.source else "command line"
            raise JobError(f"no {w}: give [{w}] in the job file or {flags.get(w, '--' + w)}", where)
    if "tools" in what and not job.tools and job.default_tool is None and job.tool_table is None:
        raise JobError("no tool: give [tools] in the job file or --tool", str(job.source or "command line"))
