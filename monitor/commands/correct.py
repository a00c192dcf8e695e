"""``dexmon correct``: turn a gouging tool path into a safe one (Huang & Oliver 1994, section 4).

    dexmon correct PROGRAM --stock box:X0,Y0,Z0,X1,Y1,Z1 --tool ball:6 --design part.stl
                   [--tolerance 0.002] [--resolution 0.2] [--min-segment 0.02] -o fixed.nc [--json]
    dexmon correct JOB.toml [-o fixed.nc] [same flags, which replace the job's]

Every straight move whose sweep gouges the design deeper than ``--tolerance`` is moved
along the paper's guide vector (eq. 7) and split where its sweep still gouges (Fig. 14),
on the rays of the same dexel frame ``simulate`` uses (:mod:`sim.correct`). The program is
written in its own dialect and units: lines that need no change byte for byte, changed and
inserted lines marked ``(dexmon: corrected line N)`` / ``(dexmon: inserted for line N)``
(:mod:`sim.correct.rewrite`). An arc, a canned cycle or a move in a subroutine or loop that
needs a correction is refused, naming its line. The correction works on 3-axis lines
only: a line a rotary axis turns (as the check reads the job's machine, or A, B or C not
0 at either end of its move without one) is left exactly as written, and the report
names it (``left_turned``).

Then the written program is read again and cut through the checks ``dexmon simulate
--design`` runs (a fresh stock, the same design, tools and tolerance): the report says
whether it is gouge-free, and the undercut the correction leaves (material above the part
the corrected path no longer removes, against the original program's cut).
Exit status: 0 the written program is gouge-free, 1 it still gouges, 2 bad input or refused.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from monitor.options import number
from sim.errors import InputError

HELP = "correct a gouging program against its design (Huang & Oliver's guide vector); writes a new program"


def add_arguments(parser) -> None:
    parser.add_argument("program", help="G-code program (.nc/.ngc/.gcode) or a job file (.toml)")
    parser.add_argument("-o", "--output", default=None, metavar="FIXED.nc",
                        help="where to write the corrected program (default: PROGRAM with .corrected before "
                             "its suffix)")
    parser.add_argument("--stock", default=None, help="box:X0,Y0,Z0,X1,Y1,Z1 (mm) or a closed STL/OBJ mesh file")
    parser.add_argument("--tool", default=None, help="flat:D, ball:D, bull:D:r, vbit:D:angle, drill:D[:angle]")
    parser.add_argument("--resolution", type=float, default=None,
                        help="dexel spacing in mm of the correction and its check (default 0.2, or the job's)")
    parser.add_argument("--design", default=None, metavar="PART.stl", help="the design part (STL/OBJ)")
    parser.add_argument("--tolerance", type=float, default=None, metavar="MM",
                        help="gouge tolerance t_l in mm (default 0.002, or the job's)")
    parser.add_argument("--min-segment", type=float, default=0.02, metavar="MM",
                        help="pieces of a move shorter than this are lifted instead of split (default 0.02 mm)")
    parser.add_argument("--refine", type=int, default=1, metavar="N",
                        help="correct on rays N times denser than the check's (the correction sees the design "
                             "only on its rays: a gouge between them can stay; default 1)")
    parser.add_argument("--linearize", type=float, default=None, metavar="MM",
                        help="arcs that need a correction are written as straight chords within MM of the "
                             "arc (without it such an arc is refused, naming its line)")
    parser.add_argument("--no-verify", action="store_true", help="write the program without checking it again")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    parser.add_argument("--dialect", choices=("linuxcnc", "grbl"), default=None)
    parser.add_argument("--tool-table", default=None, help="LinuxCNC tool table (tools follow the T column)")
    parser.add_argument("--var", default=None, metavar="FILE.var", help="LinuxCNC parameter (.var) file")
    parser.add_argument("--machine-units", choices=("mm", "inch"), default=None,
                        help="units of the tool table and .var file (default mm)")
    parser.add_argument("--subroutine-path", action="append", metavar="DIRS", default=[],
                        help="directories searched for o<name> call subroutine files")
    parser.add_argument("--max-loop", type=int, default=None, metavar="N")
    parser.add_argument("--block-delete", action="store_true", default=None)
    parser.add_argument("--memory-limit", type=float, default=4096.0, metavar="MB",
                        help="refuse grids needing more than this (default 4096 MB)")


@dataclass
class Setup:
    """Everything one correction needs, read from a program and flags or a job.

    ``load(path, chord=None)`` reads a program the same way (job settings, start
    position, work frame) and returns ``(program, rows, moves)``: the interpreter's
    result, its table (arcs as chords within ``chord`` mm when given) and that table in
    the design's coordinates (tips). ``fresh_stock()`` a new stock grid; ``checker(grid)`` the
    checks ``simulate`` runs. ``placing``: the keywords (``kinematics``, ``origin``,
    ``tool_lengths``) that place a tool on a job's rotary machine, for every cut of the
    check (empty: 3-axis).
    """

    program_path: Path
    load: object
    fresh_stock: object
    checker: object
    design: object
    tools: dict
    tool: object
    tol: object
    #: the design on the rays the correction runs on (``--refine``: denser than the check's)
    fine: object = None
    placing: dict = field(default_factory=dict)

    @property
    def turning(self) -> dict:
        """The keywords that say which rows a rotary turns (``sim.correct.path.turned_rows``)."""
        return {k: self.placing[k] for k in ("kinematics", "origin") if k in self.placing}


def _program_setup(args) -> Setup:
    from monitor.commands import simulate as S
    from sim.checks.error_map import DesignModel
    from sim.tolerance import DEFAULT, Tolerance
    from sim.tools import parse_tool_spec
    from sim.tooltable import read_tool_table, tool_from_entry

    if not Path(args.program).is_file():
        raise InputError("no such program file", where=args.program)
    if args.design is None:
        raise InputError("give the design part as --design PART.stl: the correction is against it")
    if args.stock is None:
        raise InputError("give the stock as --stock box:X0,Y0,Z0,X1,Y1,Z1 (or a mesh)")
    if args.tool is None and args.tool_table is None:
        raise InputError("give the tool as --tool SPEC (e.g. --tool ball:6) or a --tool-table")
    resolution = 0.2 if args.resolution is None else args.resolution
    units = S.machine_units(args)
    table = read_tool_table(args.tool_table, units) if args.tool_table else None
    tool = parse_tool_spec(args.tool) if args.tool else None
    tools = {num: tool_from_entry(e) for num, e in (table or {}).items() if e.diameter > 0}
    if tool is None:
        tool = next(iter(tools.values()), None)
        if tool is None:
            raise InputError("the tool table has no tool with a diameter; give --tool", where=args.tool_table)
    grid = S.build_stock(args.stock, resolution, args.memory_limit)
    t_l = number(args.tolerance, "--tolerance")
    tol = Tolerance(gouge=t_l or DEFAULT.gouge)
    design = DesignModel(grid.frame, args.design)
    sub_dirs = S.subroutine_dirs(args)
    fine = design if args.refine == 1 else DesignModel(refined(grid.frame, args.refine), args.design)

    def load(path, chord=None):
        program = S.load_program(str(path), args.dialect or "linuxcnc", table, args.var, units, sub_dirs,
                                 args.max_loop, bool(args.block_delete))
        rows = _linearized(program.moves, chord)
        return program, rows, S._from_start(rows, grid, None)

    def checker(g):
        from sim.checks.checker import Checker

        return Checker(g, tool, design=design, tol=tol, tools=tools or None)

    return Setup(Path(args.program), load, lambda: S.build_stock(args.stock, resolution, args.memory_limit),
                 checker, design, tools, tool, tol, fine)


def _job_setup(args) -> Setup:
    import dataclasses

    from monitor.commands import simulate as S
    from monitor.job import load_job

    path = Path(args.program)
    if not path.is_file():
        raise InputError("no such job file", where=str(path))
    job = S.apply_job_flags(load_job(path), args)
    t_l = number(args.tolerance, "--tolerance")
    if t_l:
        job.tolerance = dataclasses.replace(job.tolerance, gouge=t_l)
    return setup_from_job(job, args.max_loop, bool(args.block_delete), S.subroutine_dirs(args), where=str(path),
                          refine=args.refine)


def setup_from_job(job, max_loop=None, block_delete: bool = False, sub_dirs=(), where: str = "job",
                   refine: int = 1) -> Setup:
    """The :class:`Setup` of a :class:`monitor.job.Job` (its program, stock, tools,
    design, tolerance, start position and work frame, as ``simulate`` reads them)."""
    from monitor.commands import simulate as S
    from monitor.job import require
    from monitor.predict import MIN_VOLUME
    from monitor.work_coords import reference_wco, work_moves
    from monitor.workpiece import build_workpiece
    from monitor.start import job_start, start_at
    from sim.tooltable import read_tool_table

    require(job, "program", "stock", "tools")
    if job.design is None:
        raise InputError("the job has no [design] and no --design was given: the correction is against it",
                         where=where)
    if not Path(job.program).is_file():
        raise InputError("no such program file", where=f"{where}: [program] path {job.program}")
    table = read_tool_table(job.tool_table, job.machine_units) if job.tool_table else None
    dirs = [str(d) for d in job.subroutine_path] + list(sub_dirs)
    ref = reference_wco(job)

    def machine_table(p, chord=None):
        """The interpreter's result, its rows and those rows from the job's start
        (machine coordinates, the G43 length in ``tool_length``)."""
        program = S.load_program(str(p), job.dialect, table, job.var_file, job.machine_units, dirs,
                                 max_loop or job.max_loop, block_delete or job.block_delete)
        rows = _linearized(program.moves, chord)
        return program, rows, start_at(rows, job_start(job, rows))

    def load(p, chord=None):
        program, rows, machine = machine_table(p, chord)
        return program, rows, work_moves(machine, ref)

    # the machine table, as simulate builds it: a turning head places its tools by the
    # G43 lengths this table holds (the work table's tool_length is 0)
    machine_moves = machine_table(job.program)[2]
    wp = build_workpiece(job, machine_moves)
    # a rotary job's tool is placed as simulate places it: turned by the kinematics, a
    # turning head's tool by its G43 length (the work table holds tips)
    placing = dict(kinematics=wp.kinematics, origin=wp.origin, tool_lengths=wp.tool_lengths)

    def checker(g):
        from sim.checks.checker import Checker

        return Checker(g, wp.default_tool, design=wp.design, fixtures=wp.fixtures, tol=job.tolerance,
                       tools=wp.tools, min_volume=MIN_VOLUME, **placing)

    fine = wp.design
    if refine > 1:
        from sim.checks.error_map import DesignModel

        offset = job.design.offset if job.design.kind == "stl" else (0.0, 0.0, 0.0)
        fine = DesignModel(refined(wp.frame, refine), wp.design.mesh, offset=offset, name=wp.design.name)
    return Setup(Path(job.program), load, lambda: build_workpiece(job, machine_moves).stock, checker, wp.design,
                 wp.tools, wp.default_tool, job.tolerance, fine, placing)


def refined(frame, n: int):
    """``frame`` with ``n`` times denser rays over the same rectangle (its rays among them)."""
    from sim.frame import Frame

    return Frame(frame.origin, frame.direction, frame.u, frame.spacing / n, (frame.nu - 1) * n + 1,
                 (frame.nv - 1) * n + 1)


def _linearized(moves: np.ndarray, chord: float | None) -> np.ndarray:
    """``moves`` with its arcs as chords within ``chord`` mm (unchanged without one)."""
    if chord is None:
        return moves
    from sim.gcode.linearize import linearize

    return linearize(moves, chord)


def default_output(program: Path) -> Path:
    """``part.nc`` -> ``part.corrected.nc`` beside it."""
    return program.with_name(f"{program.stem}.corrected{program.suffix or '.nc'}")


def run(args) -> int:
    from sim.correct.gouge import GougeProbe
    from sim.correct.path import check_fixed_rows, correct_moves
    from sim.correct.rewrite import rewrite_program

    from monitor.commands.simulate import check_numbers

    check_numbers(args)
    number(args.min_segment, "--min-segment")
    if not 1 <= args.refine <= 8:
        raise InputError(f"must be a whole number from 1 to 8, got {args.refine}", where="--refine")
    if args.linearize is not None:
        number(args.linearize, "--linearize")
    setup = _job_setup(args) if str(args.program).lower().endswith(".toml") else _program_setup(args)
    out_path = Path(args.output) if args.output else default_output(setup.program_path)
    if not out_path.parent.is_dir():
        raise InputError("directory does not exist", where=f"-o {out_path}")
    if out_path.resolve() == setup.program_path.resolve():
        raise InputError("the corrected program would overwrite the original; give another file", where="-o")
    program, rows, moves = setup.load(setup.program_path, args.linearize)
    probe = GougeProbe(setup.fine or setup.design, setup.tol)
    t0 = time.perf_counter()
    arcs = [] if args.linearize else check_fixed_rows(moves, probe, setup.tools, setup.tool, setup.tol,
                                                      setup.tol.chord, **setup.turning)
    correction = correct_moves(moves, probe, setup.tools, setup.tool, setup.tol, min_segment=args.min_segment,
                               **setup.turning)
    seconds = time.perf_counter() - t0
    refused = sorted(arcs + correction.refused, key=lambda r: r.row)
    name = str(setup.program_path)
    if refused:
        r = refused[0]
        more = f" ({len(refused) - 1} more lines need the same)" if len(refused) > 1 else ""
        hint = "; give --linearize MM to write it as chords" if "arc" in r.reason else ""
        raise InputError(f"needs a correction that cannot be made: {r.reason}{hint}{more}",
                         where=_where(program, moves, r.row, name))
    to_prog = _to_program(rows, moves)
    data = setup.program_path.read_bytes()
    written = rewrite_program(data, name, program, correction, to_prog, moves=rows)
    out_path.write_bytes(written.text)
    report = {
        "program": name,
        "output": str(out_path),
        "lines_changed": len(written.changed),
        "lines_inserted": written.inserted,
        "changed_lines": written.changed[:200],
        "left_turned": turned_lines(program, moves, correction.turned, name),
        "positions": correction.poses,
        "positions_corrected": correction.corrected,
        "guide_steps": correction.guide_steps,
        "splits": correction.splits,
        "lifts": correction.lifts,
        "gouge_before_mm": round(correction.worst_gouge, 6),
        "largest_shift_mm": round(correction.largest_shift, 6),
        "added_length_mm": round(correction.added_length, 4),
        "tolerance_mm": setup.tol.gouge,
        "seconds": round(seconds, 3),
        "positions_per_s": round(correction.poses / seconds, 1) if seconds > 0 else None,
    }
    status = 0
    if not args.no_verify:
        verified, undercut = verify(setup, out_path, moves)
        report["verified"] = verified
        report["undercut_left"] = undercut
        status = 0 if verified["gouges"] == 0 else 1
    if args.json:
        print(json.dumps(report))
    else:
        print(summary_text(report))
    return status


def turned_lines(program, moves, turned: np.ndarray, name: str) -> dict:
    """The lines left as written because a rotary axis turns them: ``{"count", "lines"
    (main-file line numbers, then "file:line" of other files; the first 200), "why"}``."""
    from sim.correct.path import TURNED_WHY

    rows = np.flatnonzero(turned)
    main = sorted({int(moves["line"][k]) for k in rows if int(moves["file"][k]) == 0})
    other = sorted({_where(program, moves, int(k), name) for k in rows if int(moves["file"][k]) != 0})
    lines = main + other
    return {"count": len(lines), "lines": lines[:200], "why": TURNED_WHY}


def _where(program, moves, row: int, name: str) -> str:
    f = int(moves["file"][row])
    files = getattr(program, "files", [name])
    return f"{files[f] if f < len(files) else name}:{int(moves['line'][row])}"


def _to_program(prog_moves: np.ndarray, moves: np.ndarray) -> np.ndarray:
    """(n, 3) mm per row: program work coordinates (``end - wco``) less the correction's tip."""
    from sim.gcode.moves import tip_positions

    return (prog_moves["end"][:, :3] - prog_moves["wco"][:, :3]) - tip_positions(moves, "end")


def verify(setup: Setup, out_path: Path, original_moves: np.ndarray) -> tuple[dict, dict]:
    """The written program read again and cut through the checks ``simulate --design``
    runs; and the undercut it leaves against the original program's cut.

    Returns ``(verified, undercut)``: ``verified`` = {"gouges": count, "worst_mm",
    "findings": {kind: count}}; ``undercut`` = {"volume_mm3", "max_mm", "area_mm2", "at"}.
    """
    from sim.checks.report import final_findings
    from sim.cut import Cutter

    _, _, moves = setup.load(out_path)
    grid = setup.fresh_stock()
    checker = setup.checker(grid)
    checker.check_program(moves)
    found = final_findings(checker)
    gouges = [f for f in found if f.kind == "gouge"]
    kinds: dict = {}
    for f in found:
        kinds[f.kind] = kinds.get(f.kind, 0) + 1
    verified = {"gouges": len(gouges), "worst_mm": round(max((f.depth for f in gouges), default=0.0), 6),
                "gouge_lines": sorted({ln for f in gouges for ln in f.lines})[:50], "findings": kinds}
    before = setup.fresh_stock()
    Cutter(before, setup.tool, setup.tol, tools=setup.tools or None, **setup.placing).cut_moves(
        original_moves, record_changes=False)
    return verified, undercut_left(before.top(), grid.top(), setup.design)


def undercut_left(top_before: np.ndarray, top_after: np.ndarray, design) -> dict:
    """Material above the part that the corrected path leaves and the original removed:
    per ray ``top_after - max(top_before, design top)`` where positive (mm)."""
    f = design.frame
    part = design.top()
    floor = np.fmax(top_before.astype(np.float64), np.where(np.isnan(part), -np.inf, part))
    left = np.asarray(top_after, np.float64) - floor
    left = np.where(np.isfinite(left) & (left > 0), left, 0.0)
    # the error map's own noise (float32 faces) is no undercut
    left[left < 1e-4] = 0.0
    if not left.any():
        return {"volume_mm3": 0.0, "max_mm": 0.0, "area_mm2": 0.0, "at": None}
    j, i = np.unravel_index(int(np.argmax(left)), left.shape)
    x, y, _ = f.to_world(np.array([i * f.spacing, j * f.spacing, 0.0]))
    return {"volume_mm3": round(float(left.sum()) * f.spacing**2, 4), "max_mm": round(float(left.max()), 5),
            "area_mm2": round(float((left > 0).sum()) * f.spacing**2, 3),
            "at": [round(float(x), 4), round(float(y), 4), round(float(top_after[j, i]), 4)]}


def summary_text(r: dict) -> str:
    lines = [f"{r['program']}: {r['lines_changed']} lines changed, {r['lines_inserted']} inserted "
             f"({r['positions_corrected']} positions moved, {r['splits']} splits, {r['lifts']} lifts) "
             f"in {r['seconds']:.2f} s",
             f"deepest gouge before {r['gouge_before_mm']:.4f} mm; largest shift {r['largest_shift_mm']:.4f} mm; "
             f"path length {r['added_length_mm']:+.3f} mm"]
    left = r["left_turned"]
    if left["count"]:
        more = " ..." if left["count"] > 20 else ""
        lines.append(f"left as written, {left['why']}: {left['count']} lines {left['lines'][:20]}{more}")
    lines.append(f"wrote {r['output']}")
    v = r.get("verified")
    if v is not None:
        if v["gouges"]:
            lines.append(f"check: STILL GOUGES ({v['gouges']} regions, worst {v['worst_mm']:.4f} mm, lines "
                         f"{v['gouge_lines'][:10]})")
        else:
            lines.append(f"check: gouge-free at {r['tolerance_mm']:g} mm (dexmon simulate's checks)")
        others = {k: n for k, n in v["findings"].items() if k not in ("gouge", "undercut")}
        if others:
            lines.append("other findings of the check (not the correction's to fix): "
                         + ", ".join(f"{k} {n}" for k, n in sorted(others.items())))
        u = r["undercut_left"]
        if u["max_mm"] > 0:
            lines.append(f"undercut left by the correction: {u['volume_mm3']:.3f} mm^3 over {u['area_mm2']:.2f} mm^2, "
                         f"at most {u['max_mm']:.4f} mm (X{u['at'][0]} Y{u['at'][1]})")
        else:
            lines.append("undercut left by the correction: none")
    return "\n".join(lines)

