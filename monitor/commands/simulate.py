"""``dexmon simulate``: cut a whole program into a stock model, check it, report.

    dexmon simulate PROGRAM --stock box:X0,Y0,Z0,X1,Y1,Z1 --tool ball:6 --resolution 0.1
                    [--design part.stl --tolerance 0.002] [--fixture box:...] [--limits ...]
                    [--heights out.npy] [--stl out.stl] [--png out.png] [--json] [--tri-dexel]
    dexmon simulate JOB.toml [same flags, which replace the job's]

The whole program is cut with no controller and checked on the way (gouge and undercut
against ``--design``, rapids into stock, shank / holder contact, fixtures, travel limits,
depth of cut, a stopped spindle). Exit status: 0 clean, 1 findings, 2 bad input.
A JOB file (TOML, see ``monitor.job``) gives program (with its .var file, machine units
and subroutine path), stock, fixtures, tools (with shank and holder), design, tolerances,
limits and resolution; everything is in its work system's coordinates (G54 unless
``[program] work_system`` says otherwise), and program rows in other work systems
(G55 ... of a multi-fixture program) are placed at their offsets from it.

The program runs from where the machine starts, not from machine zero (where the
interpreter starts): the job's ``[machine] start``, by default the top of the Z travel
(``[limits] z``, ``--limits Z..``) above the program's first point, else 10 mm above the
stock and the program (:mod:`monitor.start`). The first move, from there to the first
point, is cut and checked like any other (``dry-run`` starts its machine there too);
``start`` in the JSON says where it was (the tool tip, work coordinates).

``--tri-dexel`` (a job's ``[stock] model = "tri-dexel"``) holds the stock in three dexel
grids whose rays run along X, Y and Z (:mod:`sim.tridexel`) instead of one along Z: the
walls a tilted or turning tool leaves, and the thin walls the Z rays step over, are then
in the model, and the checks (gouge, shank and holder contact, rapids into stock) look at
all three grids (:mod:`sim.checks.tri`); findings are reported as usual. It costs about
three times the memory and the time. ``--heights`` is the Z grid's then, and ``--stl``
and ``--png`` the model's closed surface (:mod:`sim.tridexel_surface`), with no view
direction: side walls and undercuts are drawn as they are.

``--heights`` writes the top-surface heights, float32 (ny, nx): element ``[j, i]`` is the
ray at ``X0 + i*resolution, Y0 + j*resolution`` (both ends of the stock included), NaN
where no material is left.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import time
from pathlib import Path

import numpy as np

from monitor.job import BLOCK_DELETE_HELP, DEFAULT_MACHINE, MAX_LOOP_HELP
from sim.errors import InputError

HELP = "cut and check a whole program (or a JOB.toml) without a machine; findings table or --json"

#: moves cut and checked per call (bounds the changed-ray log: ~500 rays a move at 0.1 mm)
SIM_BATCH = 2048

_NUM = r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"


def add_arguments(parser) -> None:
    parser.add_argument("program", help="G-code program (.nc/.ngc/.gcode) or a job file (.toml)")
    parser.add_argument("--stock", default=None,
                        help="box:X0,Y0,Z0,X1,Y1,Z1 (mm, machine coords) or a closed STL/OBJ mesh file")
    parser.add_argument("--resume", default=None, metavar="RUN:STAGE",
                        help="start from the model rebuilt at STAGE of a recorded run (instead of --stock)")
    parser.add_argument("--tool", default=None,
                        help="flat:D, ball:D, bull:D:r, vbit:D:angle, drill:D[:angle], optionally :L=flute_length")
    parser.add_argument("--resolution", type=float, default=None,
                        help="dexel spacing in mm (default 0.2, or the job's)")
    parser.add_argument("--dialect", choices=("linuxcnc", "grbl"), default=None)
    parser.add_argument("--tool-table", default=None,
                        help="LinuxCNC tool table (tools follow the T column; in --machine-units)")
    parser.add_argument("--var", default=None, metavar="FILE.var",
                        help="LinuxCNC parameter (.var) file: work offsets G54..G59.3, G28/G30 "
                             "(in --machine-units)")
    parser.add_argument("--machine-units", choices=("mm", "inch"), default=None,
                        help="units of the tool table and .var file (default mm)")
    parser.add_argument("--tool-table-units", choices=("mm", "inch"), default=None,
                        help=argparse.SUPPRESS)  # deprecated alias of --machine-units
    parser.add_argument("--subroutine-path", action="append", metavar="DIRS", default=[],
                        help="directories searched for o<name> call subroutine files (<name>.ngc), "
                             f"'{os.pathsep}'-separated like LinuxCNC's SUBROUTINE_PATH; repeatable; "
                             "the program's own directory is searched last")
    parser.add_argument("--max-loop", type=int, default=None, metavar="N", help=MAX_LOOP_HELP)
    parser.add_argument("--block-delete", action="store_true", default=None, help=BLOCK_DELETE_HELP)
    parser.add_argument("--memory-limit", type=float, default=4096.0, metavar="MB",
                        help="refuse grids needing more than this (default 4096 MB)")
    parser.add_argument("--heights", default=None, metavar="OUT.npy", help="write top-surface heights (float32 ny x nx)")
    parser.add_argument("--stl", default=None, metavar="OUT.stl", help="write the cut stock as an STL mesh")
    parser.add_argument("--png", default=None, metavar="OUT.png",
                        help="write a picture of the cut stock (3-D, offscreen), faces coloured by the move that made them")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    parser.add_argument("--no-checks", action="store_true", help="only cut (no findings, exit 0)")
    parser.add_argument("--tri-dexel", action="store_true", default=None,
                        help="model the stock with three dexel grids (rays along X, Y and Z): the walls a tilted "
                             "or turning tool makes, and holder contact on them, are seen; slower (a job's "
                             '[stock] model = "tri-dexel")')
    from sim.checks.report import add_check_arguments

    add_check_arguments(parser)


def parse_stock_box(spec: str) -> tuple[np.ndarray, np.ndarray]:
    """``box:X0,Y0,Z0,X1,Y1,Z1`` -> (lo, hi) float64 (3,) mm; InputError naming --stock."""
    m = re.fullmatch(r"\s*box\s*:\s*(.*)", spec)
    vals = m.group(1).split(",") if m else []
    if len(vals) != 6 or not all(re.fullmatch(_NUM, v.strip()) for v in vals):
        raise InputError(f"bad stock {spec!r}: expected box:X0,Y0,Z0,X1,Y1,Z1 (six numbers, mm) "
                         "or a mesh file", where="--stock")
    v = np.array([float(x) for x in vals])
    lo, hi = v[:3], v[3:]
    if not np.all(hi > lo):
        raise InputError(f"bad stock {spec!r}: each of X1 Y1 Z1 must be greater than X0 Y0 Z0",
                         where="--stock")
    return lo, hi


def _check_memory(nu: int, nv: int, limit_mb: float, nz: int | None = None) -> None:
    """Refuse a grid of ``nu`` x ``nv`` rays (with ``nz``: the three grids of a tri-dexel
    lattice of nu x nv x nz nodes) needing more than ``limit_mb``."""
    from sim.grid import DexelGrid

    rays = nu * nv if nz is None else nu * nv + nv * nz + nz * nu
    need = DexelGrid.estimate_bytes(rays)
    what = f"a {nu} x {nv} dexel grid" if nz is None else f"a {nu} x {nv} x {nz} tri-dexel model"
    if need > limit_mb * 2**20:
        raise InputError(f"{what} needs about {need / 2**20:.0f} MB, over the "
                         f"{limit_mb:.0f} MB limit; use a coarser --resolution or raise --memory-limit",
                         where="--resolution")


def _tri_stock(lo, hi, resolution: float, memory_limit_mb: float, build):
    """A tri-dexel stock whose box is ``[lo, hi]`` (mm) on :func:`sim.tridexel.stock_lattice`
    (no ray on a face of the box), refused before it is made when it needs more than
    ``memory_limit_mb``; ``build()`` makes it (``TriDexel.box`` or ``.mesh``)."""
    from sim.tridexel import lattice_shape, stock_lattice

    a, b = stock_lattice(lo, hi, resolution)
    nx, ny, nz = lattice_shape(a, b, resolution)
    _check_memory(nx, ny, memory_limit_mb, nz)
    return build()


def build_stock(spec: str, resolution: float, memory_limit_mb: float = 4096.0, tri_dexel: bool = False):
    """The stock grid for ``--stock`` on a top frame at ``resolution`` mm (``tri_dexel``:
    a :class:`sim.tridexel.TriDexel` whose Z grid is that one)."""
    from sim.frame import Frame
    from sim.grid import DexelGrid

    if not (math.isfinite(resolution) and resolution > 0):
        raise InputError(f"resolution must be a positive length in mm, got {resolution:g}", where="--resolution")
    if tri_dexel:
        from sim.tridexel import TriDexel
    if spec.strip().lower().startswith("box:"):
        lo, hi = parse_stock_box(spec)
        nu = int(round((hi[0] - lo[0]) / resolution)) + 1
        nv = int(round((hi[1] - lo[1]) / resolution)) + 1
        _check_memory(nu, nv, memory_limit_mb)
        if tri_dexel:
            return _tri_stock(lo, hi, resolution, memory_limit_mb, lambda: TriDexel.box(lo, hi, resolution))
        frame = Frame.top(lo[0], lo[1], hi[0], hi[1], resolution)
        return DexelGrid.from_intervals(frame, np.full(frame.shape, lo[2]), np.full(frame.shape, hi[2]))
    path = Path(spec)
    if not path.is_file():
        raise InputError("no such stock mesh file, and not box:X0,Y0,Z0,X1,Y1,Z1", where=f"--stock {spec}")
    from sim.solids import load_mesh, mesh_grid

    mesh, _ = load_mesh(path)
    (x0, y0, z0), (x1, y1, z1) = mesh.bounds
    nu = int(round((x1 - x0) / resolution)) + 1
    nv = int(round((y1 - y0) / resolution)) + 1
    _check_memory(nu, nv, memory_limit_mb)
    if tri_dexel:
        return _tri_stock(*mesh.bounds, resolution, memory_limit_mb, lambda: TriDexel.mesh(mesh, resolution))
    frame = Frame.top(x0, y0, x1, y1, resolution)
    return mesh_grid(frame, path)


def machine_units(args) -> str:
    """``--machine-units`` (or its deprecated alias ``--tool-table-units``), default mm."""
    mu = getattr(args, "machine_units", None)
    alias = getattr(args, "tool_table_units", None)
    if mu and alias and mu != alias:
        raise InputError(f"--machine-units {mu} contradicts --tool-table-units {alias} "
                         "(the latter is an old name of the former)", where="--machine-units")
    return mu or alias or "mm"


def subroutine_dirs(args) -> list[str]:
    """The ``--subroutine-path`` directories, split at the path separator; InputError for one
    that is not a directory."""
    dirs = [d for arg in (getattr(args, "subroutine_path", None) or []) for d in arg.split(os.pathsep) if d]
    for d in dirs:
        if not os.path.isdir(d):
            raise InputError("not a directory", where=f"--subroutine-path {d}")
    return dirs


def apply_job_flags(job, args):
    """``job`` with what the command-line flags replace: ``--stock``, ``--tri-dexel``
    (``[stock] model``), ``--tool`` (the job's tools dropped), ``--tool-table``, ``--dialect``,
    ``--var``, ``--machine-units``,
    ``--subroutine-path``, ``--resolution``, ``--design`` (``simulate`` and ``correct``
    read a job the same way). InputError naming the flag for a bad value."""
    from monitor.job import ToolDef, parse_solid_spec

    if getattr(args, "stock", None):
        spec = args.stock if ":" in args.stock else f"stl:{args.stock}"
        job.stock = parse_solid_spec(spec, "--stock")
    if getattr(args, "tri_dexel", None):
        job.stock_model = "tri-dexel"
    if getattr(args, "tool", None):
        job.default_tool = ToolDef(0, args.tool)
        job.tools = {}
    if getattr(args, "tool_table", None):
        job.tool_table = Path(args.tool_table)
    if getattr(args, "dialect", None):
        job.dialect = args.dialect
    # the job's [program] var / machine_units / subroutine_path, each replaced by its flag
    if getattr(args, "var", None):
        if not Path(args.var).is_file():
            raise InputError("no such parameter (.var) file", where=f"--var {args.var}")
        job.var_file = Path(args.var)
    if getattr(args, "machine_units", None) or getattr(args, "tool_table_units", None):
        job.machine_units = machine_units(args)
    sub_dirs = subroutine_dirs(args)
    if sub_dirs:
        job.subroutine_path = [Path(d) for d in sub_dirs]
    if getattr(args, "resolution", None) is not None:
        if not (math.isfinite(args.resolution) and args.resolution > 0):
            raise InputError(f"must be a positive length in mm, got {args.resolution:g}", where="--resolution")
        job.resolution = float(args.resolution)
    if getattr(args, "design", None):
        spec = args.design
        job.design = parse_solid_spec(spec if ":" in spec and not spec.lower().endswith((".stl", ".obj"))
                                      else f"stl:{spec}", "--design")
    return job


def stock_true_volume(spec: str | None = None, solid=None) -> float | None:
    """The stock's exact volume in mm^3 (a box's product of sides, a cylinder's pi r^2 h,
    a closed mesh's ``mesh.volume``), from a ``--stock`` spec or a job's ``Solid``; None when
    unknown."""
    if solid is not None:
        if solid.kind == "box":
            b = solid.box
            return float((b[3] - b[0]) * (b[4] - b[1]) * (b[5] - b[2]))
        if solid.kind == "cylinder":
            cx, cy, r, z0, z1 = solid.cylinder
            return float(math.pi * r * r * (z1 - z0))
        spec = str(solid.stl) if solid.stl is not None else None
        if spec is None:
            return None
    if spec is None:
        return None
    if spec.strip().lower().startswith("box:"):
        lo, hi = parse_stock_box(spec)
        return float(np.prod(hi - lo))
    from sim.solids import load_mesh

    mesh, _ = load_mesh(Path(spec))
    return float(abs(mesh.volume)) if mesh.is_watertight else None


def flute_note(label: str, spec: str | None, tool) -> str | None:
    """The note saying a flute length was assumed (``spec`` without ``L=``, or a tool
    table entry, which has no flute length), else None."""
    if spec is not None and re.search(r"(^|:)\s*L\s*=", spec, re.IGNORECASE):
        return None
    L = tool.flute_length
    how = f"4xD = {L:g} mm" if abs(L - 4.0 * tool.diameter) < 1e-9 else f"{L:g} mm"
    return f"flute length not given for {label}: assumed {how} (give it as :L=)"


def design_note(checker, name) -> str | None:
    """The note saying an open design surface is read as a height field."""
    if checker is None or checker.design is None or checker.design.closed:
        return None
    return f"design {name} is an open surface: material is taken as everything below it"


def load_program(path: str, dialect: str = "linuxcnc", tool_table=None, var_file=None, units: str = "mm",
                 subroutine_path=None, max_loop: int | None = None, block_delete: bool = False):
    """The program (a :class:`sim.gcode.Program`: its move table is ``.moves``), through
    the project's G-code interpreter.

    ``var_file``: LinuxCNC .var path (work offsets, G28/G30), in ``units`` like the tool table.
    ``max_loop``: passes of one o-word loop before it is refused (None: the default).
    ``block_delete``: the block delete switch (on: '/' lines are skipped).
    """
    from sim.gcode import Limits
    from sim.gcode import load_program as sim_load_program

    if var_file is not None and not Path(var_file).is_file():
        raise InputError("no such parameter (.var) file", where=f"--var {var_file}")
    if max_loop is not None and max_loop < 1:
        raise InputError(f"must be a positive whole number, got {max_loop}", where="--max-loop")
    limits = Limits() if max_loop is None else Limits(max_loop=max_loop)
    return sim_load_program(path, dialect=dialect, tool_table=tool_table, var_file=var_file,
                            machine_units=units, subroutine_path=subroutine_path or None, limits=limits,
                            block_delete=block_delete)


def _cutting_rows(moves: np.ndarray) -> np.ndarray:
    """bool (n,): rows that can remove material (rapids, feeds, arcs)."""
    from sim.gcode.moves import MoveKind

    lut = np.zeros(256, bool)
    lut[[int(MoveKind.RAPID), int(MoveKind.FEED), int(MoveKind.ARC_CW), int(MoveKind.ARC_CCW)]] = True
    return lut[moves["kind"]]


def _from_start(moves: np.ndarray, grid, limits_text: str | None) -> np.ndarray:
    """``moves`` (a program read without a job: its machine coordinates are the stock's)
    starting at the default start position (:func:`monitor.start.start_point`): the top
    of ``--limits`` Z, else above the stock's material and the program."""
    from monitor.start import start_at, start_point
    from sim.checks.travel import parse_limits
    from sim.checks.setup import material_box

    from sim.checks.tri import z_part

    z = parse_limits(limits_text).get("Z") if limits_text else None
    box = material_box(z_part(grid))
    start = start_point(moves, z_top=None if z is None else z[1],
                        material_top=None if box is None else float(box[1][2]))
    return moves if start is None else start_at(moves, start)


def check_numbers(args) -> None:
    """The numeric options ``simulate`` and ``correct`` share: a memory limit of nan or inf
    would let any grid through to fail in numpy, 0 or less refuse every grid; a
    ``--max-loop`` of 0 would read as "not given" where a job gives one."""
    from monitor.options import number

    number(args.memory_limit, "--memory-limit")
    number(args.max_loop, "--max-loop", whole=True)


def run(args) -> int:
    check_numbers(args)
    if str(args.program).lower().endswith(".toml"):
        return _run_job(args)
    from sim.tools import parse_tool_spec
    from sim.tooltable import read_tool_table, tool_from_entry

    if args.tool is None and args.tool_table is None:
        raise InputError("give the tool as --tool SPEC (e.g. --tool ball:6) or a --tool-table")
    if not Path(args.program).is_file():
        raise InputError("no such program file", where=args.program)
    resolution = 0.2 if args.resolution is None else args.resolution
    units = machine_units(args)
    sub_dirs = subroutine_dirs(args)
    table = read_tool_table(args.tool_table, units) if args.tool_table else None
    tool = parse_tool_spec(args.tool) if args.tool else None
    tools = {}
    if table:
        for num, entry in table.items():
            if entry.diameter > 0:
                tools[num] = tool_from_entry(entry)
        if tool is None:
            tool = next(iter(tools.values()), None)
            if tool is None:
                raise InputError("the tool table has no tool with a diameter; give --tool", where=args.tool_table)

    if args.resume:
        from monitor.resume import resume_grid

        if args.tri_dexel:
            raise InputError("a recorded run holds one Z grid; --tri-dexel cannot start from it", where="--resume")
        grid, _ = resume_grid(args.resume)
    elif args.stock:
        grid = build_stock(args.stock, resolution, args.memory_limit, tri_dexel=bool(args.tri_dexel))
    else:
        raise InputError("give the stock as --stock box:X0,Y0,Z0,X1,Y1,Z1 (or a mesh), or --resume RUN:STAGE")
    program = load_program(args.program, args.dialect or "linuxcnc", table, args.var, units, sub_dirs,
                           args.max_loop, bool(args.block_delete))
    moves = _from_start(program.moves, grid, getattr(args, "limits", None))
    checker = None
    if not args.no_checks:
        from sim.checks.report import checker_from_args

        checker = checker_from_args(args, grid, tool, tools)
    true_volume = stock_true_volume(args.stock) if args.stock and not args.resume else None
    notes = []
    if args.tool:
        notes.append(flute_note(f"--tool {args.tool}", args.tool, tool))
    for num in sorted(set(int(t) for t in moves["tool"]) & set(tools)):
        notes.append(flute_note(f"T{num} (tool table)", None, tools[num]))
    notes.append(design_note(checker, args.design))
    return _simulate(args, str(args.program), moves, grid, tool, tools, checker, true_volume=true_volume,
                     notes=[n for n in notes if n], inch=program.inch)


def _run_job(args) -> int:
    """``dexmon simulate JOB.toml``: the job's program, stock, fixtures, tools, design,
    tolerances, limits and resolution; the flags given replace the job's."""
    import dataclasses

    from monitor.job import load_job, parse_solid_spec, require
    from monitor.options import number
    from monitor.predict import MIN_VOLUME
    from monitor.work_coords import limits_in_work, reference_wco, work_moves
    from monitor.workpiece import build_workpiece
    from monitor.start import job_start, start_at
    from sim.checks.travel import parse_limits
    from sim.tooltable import read_tool_table

    path = Path(args.program)
    if not path.is_file():
        raise InputError("no such job file", where=str(path))
    if args.resume:
        raise InputError("--resume is not available with a job file; give a program", where="--resume")
    job = apply_job_flags(load_job(path), args)
    if args.fixture:
        job.fixtures = [parse_solid_spec(f, "--fixture") for f in args.fixture]
    if args.limits:
        job.limits = parse_limits(args.limits)
    t_l = number(args.tolerance, "--tolerance")
    t_h = number(args.undercut_tolerance, "--undercut-tolerance")
    if t_l or t_h:
        job.tolerance = dataclasses.replace(job.tolerance, gouge=t_l or job.tolerance.gouge,
                                            undercut=t_h or job.tolerance.undercut)
    require(job, "program", "stock", "tools")
    if not Path(job.program).is_file():
        raise InputError("no such program file", where=f"{path}: [program] path {job.program}")
    table = read_tool_table(job.tool_table, job.machine_units) if job.tool_table else None
    # one frame: the job's work system; rows in other systems land at their offsets from it
    program = load_program(job.program, job.program_dialect, table, job.var_file, job.machine_units,
                           [str(d) for d in job.subroutine_path], args.max_loop or job.max_loop,
                           bool(args.block_delete) or job.block_delete)
    # from where the machine starts, as a dry run does (monitor.start)
    machine_moves = start_at(program.moves, job_start(job, program.moves))
    moves = work_moves(machine_moves, reference_wco(job))
    wp = build_workpiece(job, machine_moves, model=job.stock_model, memory_limit_mb=args.memory_limit,
                         memory_hint="use a coarser --resolution or raise --memory-limit")
    checker = None
    if not args.no_checks:
        from sim.checks.checker import Checker

        # machine = model + the job system's zero (the .var file's when the job takes the
        # offset from the controller)
        wco = job.work_offset if job.work_offset is not None else tuple(reference_wco(job)[:3])
        checker = Checker(wp.stock, wp.default_tool, design=wp.design, fixtures=wp.fixtures,
                          limits=limits_in_work(job.limits, wco), tol=job.tolerance, tools=wp.tools,
                          max_depth_of_cut=number(args.max_depth_of_cut, "--max-depth-of-cut"),
                          min_volume=MIN_VOLUME, undercut_from_path=not (job.undercut_given or t_h),
                          kinematics=wp.kinematics, origin=wp.origin, tool_lengths=wp.tool_lengths)
    out = {"job": str(path)}
    notes = []
    used = set(int(t) for t in moves["tool"])
    for num, td in sorted(job.tools.items()):
        if num in used and num in wp.tools:
            notes.append(flute_note(f"T{num}", td.spec, wp.tools[num]))
    if job.default_tool is not None and (not job.tools or used - set(job.tools)):
        notes.append(flute_note(f"T{job.default_tool.number}" if job.default_tool.number else "the tool",
                                job.default_tool.spec, wp.default_tool))
    notes.append(design_note(checker, job.design.stl if job.design is not None else None))
    return _simulate(args, str(job.program), moves, wp.stock, wp.default_tool, wp.tools, checker, out,
                     true_volume=stock_true_volume(solid=job.stock), notes=[n for n in notes if n], inch=program.inch,
                     machine={**DEFAULT_MACHINE, **(job.machine or {})}, kinematics=wp.kinematics,
                     origin=wp.origin, tool_lengths=wp.tool_lengths)


def _setup_findings(moves, grid, tool, tools, checker, inch: bool) -> list:
    """:func:`sim.checks.setup.setup_findings` of a simulation: the stock's material box,
    the largest tool radius, the design's box from the checker."""
    from sim.checks.setup import design_box, material_box, setup_findings
    from sim.checks.tri import z_part

    grid = z_part(grid)  # a tri-dexel model's top view
    reach = max([t.radius for t in (tools or {}).values()] + [tool.radius])
    design = getattr(checker, "design", None)
    if getattr(checker, "kinematics", None) is not None:
        from monitor.setup_check import placed_on_part

        moves = placed_on_part(moves, checker.kinematics, checker.origin, checker.tool_lengths)
    return setup_findings(moves, material_box(grid), reach, design_box(design) if design is not None else None,
                          inch=inch)


def move_start_times(moves: np.ndarray, machine=None) -> np.ndarray:
    """Machine time (s from the program start) at which each row starts, float64 (n,):
    the GRBL-like planner of ``sim.gcode.timing`` with ``machine`` (default
    :data:`monitor.job.DEFAULT_MACHINE`)."""
    from sim.gcode.timing import cycle_time

    _, per_row = cycle_time(moves, machine or DEFAULT_MACHINE)
    return np.concatenate([[0.0], np.cumsum(per_row)[:-1]]) if len(per_row) else np.zeros(0)


def _simulate(args, program: str, moves, grid, tool, tools, checker, out=None, true_volume=None,
              notes=(), inch: bool = False, machine=None, kinematics=None, origin=None,
              tool_lengths=None) -> int:
    """Cut (and check) ``moves`` into ``grid``; print the report; return the exit status.
    ``kinematics``/``origin``/``tool_lengths``: the job's rotaries for the unchecked cut
    (the checker has its own).

    With checks, a setup that cannot be meant (:mod:`sim.checks.setup`: the path never
    reaches the stock, the design is not in the stock) is reported first, as findings.

    Volumes shown are the stock's exact volume (``true_volume`` when known, else the grid's
    trapezoid-rule volume) and what the cut removed by the trapezoid rule (edge rays count
    half a cell, corners a quarter), so a box does not gain its edge half-cells."""
    from sim.checks.report import final_findings
    from sim.checks.tri import TriModelCutter, is_tri, z_part
    from sim.cut import Cutter
    from sim.gcode.moves import MoveKind
    from sim.tolerance import DEFAULT

    kinds = moves["kind"]
    cutting = _cutting_rows(moves)
    if not cutting.any():
        raise InputError("the program has no motion to simulate (empty program?)", where=program)
    setup = _setup_findings(moves, grid, tool, tools, checker, inch) if checker is not None else []
    tri = is_tri(grid)
    zgrid = z_part(grid)  # volumes and heights: a tri-dexel model's Z grid
    grid_before = zgrid.volume(weights="trapezoid")
    stock_volume = grid_before if true_volume is None else float(true_volume)
    t0 = time.perf_counter()
    if checker is not None:
        checker.set_move_times(move_start_times(moves, machine))
        # in batches: one batch's changed-ray log alive at a time, whatever the length
        per_move = checker.check_program(moves, batch=SIM_BATCH)
        findings = setup + final_findings(checker)
        if checker.undercut_basis is not None:
            from sim.checks.scallop import note

            notes = [*notes, note(*checker.undercut_basis, checker.tol.undercut)]
    else:
        placing = dict(tools=tools or None, kinematics=kinematics, origin=origin, tool_lengths=tool_lengths)
        cutter = TriModelCutter(grid, tool, DEFAULT, **placing) if tri else Cutter(grid, tool, **placing)
        per_move = cutter.cut_moves(moves, record_changes=False).removed
        findings = []
    seconds = time.perf_counter() - t0
    grid_after = zgrid.volume(weights="trapezoid")
    removed = max(grid_before - grid_after, 0.0)
    rapid_removed = float(per_move[kinds == MoveKind.RAPID].sum())

    out = dict(out or {})
    out.update({
        "program": program,
        "moves": int(len(moves)),
        "motion_moves": int(cutting.sum()),
        "cutting_moves": int((per_move > 0).sum()),
        "removed_mm3": round(removed, 3),
        "removed_by_rapids_mm3": round(rapid_removed, 3),
        "start": _start_tip(moves),
        "stock_mm3": round(stock_volume, 3),
        "remaining_mm3": round(max(stock_volume - removed, 0.0), 3),
        "seconds": round(seconds, 4),
        "moves_per_s": round(len(moves) / seconds, 1) if seconds > 0 else None,
        "tool": tool.describe(),
        "resolution": zgrid.frame.spacing,
        "grid": [zgrid.frame.nu, zgrid.frame.nv],
        "model": "tri-dexel" if tri else "z",
        "checked": checker is not None,
        "findings": [f.to_json() for f in findings],
        "notes": list(notes),
    })
    if args.heights:
        hp = Path(args.heights)
        if not hp.parent.is_dir():
            raise InputError("directory does not exist", where=f"--heights {args.heights}")
        np.save(hp, zgrid.top().astype(np.float32))
        out["heights"] = str(hp)
    if tri:
        out["lattice"] = list(grid.shape)
    if args.stl:
        _export_stl(grid, args.stl)
        out["stl"] = str(args.stl)
    if args.png:
        _export_png(grid, args.png, f"{Path(program).name}: {'tri-dexel' if tri else 'Z grid'}")
        out["png"] = str(args.png)

    if args.json:
        print(json.dumps(out))
    else:
        for n in notes:
            print(f"note: {n}", file=sys.stderr)
        w = sys.stdout.write
        model = (f"tri-dexel model {' x '.join(str(n) for n in grid.shape)} nodes" if tri
                 else f"grid {grid.frame.nu} x {grid.frame.nv} rays")
        w(f"{out['program']}: {out['moves']} moves ({out['cutting_moves']} removed material), "
          f"tool {out['tool']}, {model} at {zgrid.frame.spacing:g} mm\n")
        pct = 100.0 * removed / stock_volume if stock_volume > 0 else 0.0
        w(f"removed {removed:.3f} mm^3 of {stock_volume:.3f} mm^3 stock ({pct:.1f}%) in {seconds:.3f} s"
          + (f" ({out['moves_per_s']:.0f} moves/s)\n" if out["moves_per_s"] else "\n"))
        if rapid_removed > 0 and checker is None:
            w(f"warning: rapid moves removed {rapid_removed:.3f} mm^3\n")
        if checker is not None:
            w(findings_table(findings))
        for key in ("heights", "stl", "png"):
            if key in out:
                w(f"wrote {out[key]}\n")
    return 1 if findings else 0


def _export_stl(grid, path) -> None:
    """Write the cut stock's surface as an STL: a Z grid's column surface
    (:mod:`sim.surface`), a tri-dexel model's closed surface (:mod:`sim.tridexel_surface`)."""
    from sim.checks.tri import is_tri

    if not is_tri(grid):
        from sim.surface import export_stl

        export_stl(grid, path)
        return
    from sim.tridexel_surface import export_stl as export_tri

    export_tri(grid, path)


def _export_png(grid, path, title: str) -> None:
    """Picture the cut stock's closed surface from the front left and above, faces coloured
    by move (:func:`monitor.render.view3d.part_png`): a tri-dexel model's own surface, a
    Z grid's column surface."""
    from sim.checks.tri import is_tri

    out = Path(path)
    if not out.parent.is_dir():
        raise InputError("directory does not exist", where=f"--png {path}")
    try:
        from monitor.render.view3d import part_png
    except ImportError as e:   # pyvista is a dependency; a broken VTK install says so here
        raise InputError(f"cannot render ({e})", where="--png") from None
    if is_tri(grid):
        part_png(grid, path_out=str(out), title=title)
    else:
        from sim.surface import surface_mesh

        part_png(surface_mesh(grid), path_out=str(out), title=title)


def _start_tip(moves: np.ndarray) -> list[float] | None:
    """Where the program started: the tool tip at the start of its first motion (the
    table's coordinates, mm), None without motion."""
    from monitor.start import first_motion_row

    k = first_motion_row(moves)
    if k is None:
        return None
    tip = np.array(moves["start"][k, :3], np.float64)
    tip[2] -= float(moves["tool_length"][k])
    return [round(float(v), 4) for v in tip]


#: one short sentence per kind for the text table
WHAT = {
    "gouge": "cut into the part",
    "undercut": "material left on the part",
    "rapid_into_stock": "a rapid (G0) went through material",
    "holder_contact": "the tool holder touches material",
    "shank_contact": "the shank touches material",
    "above_flute_contact": "the tool above its flutes touches material",
    "fixture_collision": "the tool enters a fixture",
    "spindle_stopped_cutting": "cuts with the spindle stopped",
    "non_center_cutting_plunge": "plunges a tool that does not cut at its centre",
    "depth_of_cut": "cuts deeper than --max-depth-of-cut",
    "travel_limit": "an axis goes past its travel limit",
}

#: a kind with more findings than this gets a summary line and only its worst rows
MAX_ROWS_PER_KIND = 5


def _lines_text(f) -> str:
    return str(f.line) if len(f.lines) <= 1 else f"{f.lines[0]}-{f.lines[-1]}"


def _size_text(f) -> str:
    parts = []
    if not math.isnan(f.depth):
        parts.append(f"{f.depth:.3f} mm" + (" deep" if f.kind in ("gouge", "depth_of_cut") else ""))
    if not math.isnan(f.volume):
        parts.append(f"{f.volume:.1f} mm^3")
    elif not math.isnan(f.area):
        parts.append(f"{f.area:.1f} mm^2")
    return ", ".join(parts)


def _what_text(f) -> str:
    from sim.checks.reach import MENTION_SHARE, UNREACHABLE_SHARE

    what = WHAT.get(f.kind, f.kind.replace("_", " "))
    share = f.detail.get("unreachable_share", 0.0) if f.kind == "undercut" else 0.0
    if share >= UNREACHABLE_SHARE:
        what = f"material left where the {f.detail['finishing_tool']} cannot reach (a smaller tool would)"
    elif share >= MENTION_SHARE:
        what += f" ({100 * share:.0f} % of it where the {f.detail['finishing_tool']} cannot reach)"
    group = f.detail.get("group")
    if group and f.kind in ("fixture_collision", "travel_limit"):
        what += f" ({group})"
    hits = f.detail.get("hits")
    if hits and hits > 1:
        what += f", on {hits} passes"
    return what


def _severity(f) -> float:
    for v in (f.depth, f.volume, f.area):
        if not math.isnan(v):
            return v
    return 0.0


def findings_table(findings) -> str:
    """The findings as a fixed-width text table: kind, lines, X Y Z, size, one short
    sentence; a kind with many findings gets a summary line and only its worst rows."""
    if not findings:
        return "no findings\n"
    by_kind: dict[str, list] = {}
    for f in findings:
        by_kind.setdefault(f.kind, []).append(f)
    head = [f"{len(findings)} finding{'s' if len(findings) != 1 else ''}:"]
    shown = []
    for kind, fs in by_kind.items():
        if len(fs) > MAX_ROWS_PER_KIND:
            worst = max(fs, key=_severity)
            lines = sorted({ln for f in fs for ln in f.lines})
            x, y, z = worst.position
            head.append(f"{kind}: {len(fs)} findings on lines {lines[0]}-{lines[-1]}, worst at line {worst.line} "
                        f"(X{x:.3f} Y{y:.3f} Z{z:.3f}, {_size_text(worst)}); the {MAX_ROWS_PER_KIND} worst "
                        "are listed (--json lists all)")
            keep = set(map(id, sorted(fs, key=_severity, reverse=True)[:MAX_ROWS_PER_KIND]))
            fs = [f for f in fs if id(f) in keep]
        shown += fs
    shown.sort(key=lambda f: (f.stages[0] if f.stages else f.stage))
    rows = [("kind", "lines", "X", "Y", "Z", "size", "what")]
    for f in shown:
        rows.append((f.kind, _lines_text(f), *(f"{v:.3f}" for v in f.position), _size_text(f), _what_text(f)))
    widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]) - 1)]
    out = head
    for r in rows:
        out.append("  ".join(c.ljust(w) if k in (0, 1, 5) else c.rjust(w)
                             for k, (c, w) in enumerate(zip(r, widths))) + "  " + r[-1])
    return "\n".join(out) + "\n"
