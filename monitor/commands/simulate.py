"""``dexmon simulate``: cut a whole program into a stock model and report what it removed.

    dexmon simulate PROGRAM --stock box:X0,Y0,Z0,X1,Y1,Z1 --tool ball:6 --resolution 0.1
                    [--heights out.npy] [--stl out.stl] [--json]

The first motion row is not cut when it is a rapid: it starts from wherever the machine
was before the program (the interpreter assumes machine zero), so it is positioning.

``--heights`` writes the top-surface heights, float32 (ny, nx): element ``[j, i]`` is the
ray at ``X0 + i*resolution, Y0 + j*resolution`` (both ends of the stock included), NaN
where no material is left.
"""

from __future__ import annotations

import json
import math
import re
import sys
import time
from pathlib import Path

import numpy as np

from sim.errors import InputError

HELP = "cut a whole program into a stock model and report removal"

_NUM = r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"


def add_arguments(parser) -> None:
    parser.add_argument("program", help="G-code program (.nc/.ngc/.gcode)")
    parser.add_argument("--stock", default=None,
                        help="box:X0,Y0,Z0,X1,Y1,Z1 (mm, machine coords) or a closed STL/OBJ mesh file")
    parser.add_argument("--resume", default=None, metavar="RUN:STAGE",
                        help="start from the model rebuilt at STAGE of a recorded run (instead of --stock)")
    parser.add_argument("--tool", default=None,
                        help="flat:D, ball:D, bull:D:r, vbit:D:angle, drill:D[:angle], optionally :L=flute_length")
    parser.add_argument("--resolution", type=float, default=0.2, help="dexel spacing in mm (default 0.2)")
    parser.add_argument("--dialect", choices=("linuxcnc", "grbl"), default="linuxcnc")
    parser.add_argument("--tool-table", default=None, help="LinuxCNC tool table (tools follow the T column)")
    parser.add_argument("--tool-table-units", choices=("mm", "inch"), default="mm",
                        help="units of the numbers in the tool table (default mm)")
    parser.add_argument("--memory-limit", type=float, default=4096.0, metavar="MB",
                        help="refuse grids needing more than this (default 4096 MB)")
    parser.add_argument("--heights", default=None, metavar="OUT.npy", help="write top-surface heights (float32 ny x nx)")
    parser.add_argument("--stl", default=None, metavar="OUT.stl", help="write the cut stock as an STL mesh")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of text")


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


def _check_memory(nu: int, nv: int, limit_mb: float) -> None:
    from sim.grid import DexelGrid

    need = DexelGrid.estimate_bytes(nu * nv)
    if need > limit_mb * 2**20:
        raise InputError(f"a {nu} x {nv} dexel grid needs about {need / 2**20:.0f} MB, over the "
                         f"{limit_mb:.0f} MB limit; use a coarser --resolution or raise --memory-limit",
                         where="--resolution")


def build_stock(spec: str, resolution: float, memory_limit_mb: float = 4096.0):
    """The stock grid for ``--stock`` on a top frame at ``resolution`` mm."""
    from sim.frame import Frame
    from sim.grid import DexelGrid

    if not (math.isfinite(resolution) and resolution > 0):
        raise InputError(f"resolution must be a positive length in mm, got {resolution:g}", where="--resolution")
    if spec.strip().lower().startswith("box:"):
        lo, hi = parse_stock_box(spec)
        nu = int(round((hi[0] - lo[0]) / resolution)) + 1
        nv = int(round((hi[1] - lo[1]) / resolution)) + 1
        _check_memory(nu, nv, memory_limit_mb)
        frame = Frame.top(lo[0], lo[1], hi[0], hi[1], resolution)
        return DexelGrid.from_intervals(frame, np.full(frame.shape, lo[2]), np.full(frame.shape, hi[2]))
    path = Path(spec)
    if not path.is_file():
        raise InputError(f"no such stock mesh file, and not box:X0,Y0,Z0,X1,Y1,Z1", where=f"--stock {spec}")
    from sim.solids import load_mesh, mesh_grid

    mesh, _ = load_mesh(path)
    (x0, y0, _), (x1, y1, _) = mesh.bounds
    nu = int(round((x1 - x0) / resolution)) + 1
    nv = int(round((y1 - y0) / resolution)) + 1
    _check_memory(nu, nv, memory_limit_mb)
    return mesh_grid(Frame.top(x0, y0, x1, y1, resolution), path)


def load_moves(path: str, dialect: str = "linuxcnc", tool_table=None) -> np.ndarray:
    """The move table of a program, through the project's G-code interpreter."""
    try:
        from sim.gcode import load_program
    except ImportError:
        raise InputError("the G-code interpreter (sim.gcode.load_program) is not available in this build") from None
    return load_program(path, dialect=dialect, tool_table=tool_table).moves


def run(args) -> int:
    from sim.cut import Cutter
    from sim.gcode.moves import MoveKind
    from sim.tools import parse_tool_spec
    from sim.tooltable import read_tool_table, tool_from_entry

    if args.tool is None and args.tool_table is None:
        raise InputError("give the tool as --tool SPEC (e.g. --tool ball:6) or a --tool-table")
    if not Path(args.program).is_file():
        raise InputError("no such program file", where=args.program)
    table = read_tool_table(args.tool_table, args.tool_table_units) if args.tool_table else None
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

        grid, _ = resume_grid(args.resume)
    elif args.stock:
        grid = build_stock(args.stock, args.resolution, args.memory_limit)
    else:
        raise InputError("give the stock as --stock box:X0,Y0,Z0,X1,Y1,Z1 (or a mesh), or --resume RUN:STAGE")
    stock_volume = grid.volume()
    moves = load_moves(args.program, args.dialect, table)
    kinds = moves["kind"]
    cutting = np.isin(kinds, [MoveKind.RAPID, MoveKind.FEED, MoveKind.ARC_CW, MoveKind.ARC_CCW])
    if not cutting.any():
        raise InputError("the program has no motion to simulate (empty program?)", where=args.program)

    cutter = Cutter(grid, tool, tools=tools or None)
    t0 = time.perf_counter()
    # the machine's position before the program is unknown (the interpreter starts at
    # machine zero), so a leading rapid is positioning, not a move into the stock
    first = int(np.argmax(cutting))
    skip_first = bool(kinds[first] == MoveKind.RAPID)
    todo = moves.copy()
    if skip_first:
        todo["kind"][first] = MoveKind.PAUSE
    res = cutter.cut_moves(todo, record_changes=False)
    seconds = time.perf_counter() - t0
    removed = float(res.removed.sum())
    rapid_removed = float(res.removed[kinds == MoveKind.RAPID].sum())

    out = {
        "program": str(args.program),
        "moves": int(len(moves)),
        "motion_moves": int(cutting.sum()),
        "cutting_moves": int((res.removed > 0).sum()),
        "removed_mm3": round(removed, 3),
        "removed_by_rapids_mm3": round(rapid_removed, 3),
        "first_rapid_skipped": skip_first,
        "stock_mm3": round(stock_volume, 3),
        "remaining_mm3": round(grid.volume(), 3),
        "seconds": round(seconds, 4),
        "moves_per_s": round(len(moves) / seconds, 1) if seconds > 0 else None,
        "tool": tool.describe(),
        "resolution": grid.frame.spacing,
        "grid": [grid.frame.nu, grid.frame.nv],
    }
    if args.heights:
        hp = Path(args.heights)
        if not hp.parent.is_dir():
            raise InputError("directory does not exist", where=f"--heights {args.heights}")
        np.save(hp, grid.top().astype(np.float32))
        out["heights"] = str(hp)
    if args.stl:
        from sim.surface import export_stl

        export_stl(grid, args.stl)
        out["stl"] = str(args.stl)

    if args.json:
        print(json.dumps(out))
    else:
        w = sys.stdout.write
        w(f"{out['program']}: {out['moves']} moves ({out['cutting_moves']} removed material), "
          f"tool {out['tool']}, grid {grid.frame.nu} x {grid.frame.nv} rays at {grid.frame.spacing:g} mm\n")
        pct = 100.0 * removed / stock_volume if stock_volume > 0 else 0.0
        w(f"removed {removed:.3f} mm^3 of {stock_volume:.3f} mm^3 stock ({pct:.1f}%) in {seconds:.3f} s"
          + (f" ({out['moves_per_s']:.0f} moves/s)\n" if out["moves_per_s"] else "\n"))
        if rapid_removed > 0:
            w(f"warning: rapid moves removed {rapid_removed:.3f} mm^3\n")
        for key in ("heights", "stl"):
            if key in out:
                w(f"wrote {out[key]}\n")
    return 0
