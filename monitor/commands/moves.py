"""``dexmon moves PROGRAM``: print a program's move table as JSON lines or CSV."""

from __future__ import annotations

import csv
import json
import math
import os
import sys

from monitor.job import BLOCK_DELETE_HELP, MAX_LOOP_HELP

HELP = "print a program's move table (jsonl or csv)"

KIND_NAMES = {0: "rapid", 1: "feed", 2: "arc_cw", 3: "arc_ccw", 4: "dwell", 5: "tool_change", 6: "probe",
              7: "pause", 8: "end"}
PLANE_NAMES = {0: "xy", 1: "xz", 2: "yz"}


def add_arguments(parser) -> None:
    parser.add_argument("program", help="G-code file")
    parser.add_argument("--dialect", choices=("linuxcnc", "grbl"), default="linuxcnc",
                        help="controller dialect (default linuxcnc)")
    parser.add_argument("--tool-table", help="LinuxCNC tool table (in --machine-units)")
    parser.add_argument("--var", help="LinuxCNC parameter (.var) file: work offsets, G28/G30 (in --machine-units)")
    parser.add_argument("--machine-units", choices=("mm", "inch"), default="mm",
                        help="units of the tool table and .var file (default mm)")
    parser.add_argument("--subroutine-path", action="append", metavar="DIRS", default=[],
                        help="directories searched for o<name> call subroutine files (<name>.ngc), "
                             f"'{os.pathsep}'-separated like LinuxCNC's SUBROUTINE_PATH; repeatable; "
                             "the program's own directory is searched last")
    parser.add_argument("--format", choices=("jsonl", "csv"), default="jsonl", help="output format (default jsonl)")
    parser.add_argument("--max-loop", type=int, default=None, metavar="N", help=MAX_LOOP_HELP)
    parser.add_argument("--block-delete", action="store_true", help=BLOCK_DELETE_HELP)
    parser.add_argument("--keep-going", action="store_true",
                        help="list every error (on stderr) instead of stopping at the first")
    parser.add_argument("--linearize", type=float, metavar="MM",
                        help="replace arcs by chords within this chordal tolerance (mm)")
    parser.add_argument("--time", action="store_true",
                        help="add each row's planned time (s, GRBL default limits) and print the total on stderr")


def _axes(vec, n_axes: int) -> list:
    return [round(float(v), 6) for v in vec[:n_axes]]


def rows_as_dicts(prog, moves, times=None):
    """One dict per move row (work coordinates of the active system, mm)."""
    rotary = bool(len(moves)) and bool((moves["end"][:, 3:] != 0).any() or (moves["start"][:, 3:] != 0).any())
    n_axes = 6 if rotary else 3
    for i, r in enumerate(moves):
        kind = int(r["kind"])
        d = {
            "file": prog.files[int(r["file"])] if int(r["file"]) else None,
            "line": int(r["line"]),
            "kind": KIND_NAMES.get(kind, str(kind)),
            "start": _axes(r["start"] - r["wco"], n_axes),
            "end": _axes(r["end"] - r["wco"], n_axes),
            "end_machine": _axes(r["end"], n_axes),
            "feed": round(float(r["feed"]), 6),
            "spindle": float(r["spindle"]),
            "spindle_dir": int(r["spindle_dir"]),
            "tool": int(r["tool"]),
            "tool_length": round(float(r["tool_length"]), 6),
            "coolant": int(r["coolant"]),
        }
        if d["file"] is None:
            del d["file"]
        if kind in (2, 3):
            d["center"] = [round(float(c), 6) for c in (r["center"] - r["wco"][:3])]
            d["plane"] = PLANE_NAMES[int(r["plane"])]
            d["turns"] = int(r["turns"])
        if float(r["inverse_time"]):
            d["inverse_time"] = float(r["inverse_time"])
        if kind == 4:
            d["dwell"] = float(r["dwell"])
        if times is not None:
            d["time"] = round(float(times[i]), 6)
        yield d


def run(args) -> int:
    from sim.gcode import Limits, load_program

    if args.max_loop is not None and args.max_loop < 1:
        print("dexmon moves: error: --max-loop needs a positive whole number", file=sys.stderr)
        return 2
    limits = Limits() if args.max_loop is None else Limits(max_loop=args.max_loop)
    sub_path = [d for arg in args.subroutine_path for d in arg.split(os.pathsep) if d]
    for d in sub_path:
        if not os.path.isdir(d):
            print(f"dexmon moves: error: --subroutine-path {d!r} is not a directory", file=sys.stderr)
            return 2
    prog = load_program(args.program, dialect=args.dialect, tool_table=args.tool_table, var_file=args.var,
                        machine_units=args.machine_units, keep_going=args.keep_going, subroutine_path=sub_path,
                        limits=limits, block_delete=args.block_delete)
    moves = prog.moves
    if args.linearize is not None:
        if not (args.linearize > 0 and math.isfinite(args.linearize)):
            print("dexmon moves: error: --linearize needs a positive tolerance in mm", file=sys.stderr)
            return 2
        moves = prog.linearize(args.linearize)
    times = None
    if args.time:
        from sim.gcode.timing import cycle_time

        total, times = cycle_time(moves)
        print(f"cycle time: {total:.1f} s", file=sys.stderr)
    out = sys.stdout
    rows = rows_as_dicts(prog, moves, times)
    if args.format == "jsonl":
        for d in rows:
            out.write(json.dumps(d, separators=(",", ":")) + "\n")
    else:
        writer = None
        for d in rows:
            flat = {}
            for k, v in d.items():
                if isinstance(v, list):
                    for axis, x in zip("xyzabc", v):
                        flat[f"{k}_{axis}"] = x
                else:
                    flat[k] = v
            if writer is None:
                fields = ["line", "kind", "start_x", "start_y", "start_z", "end_x", "end_y", "end_z",
                          "end_machine_x", "end_machine_y", "end_machine_z", "center_x", "center_y", "center_z",
                          "plane", "turns", "feed", "spindle", "spindle_dir", "tool", "tool_length", "coolant",
                          "dwell", "inverse_time", "time", "file"]
                extra = [k for k in flat if k not in fields]
                writer = csv.DictWriter(out, fieldnames=fields + extra, extrasaction="ignore")
                writer.writeheader()
            writer.writerow(flat)
    for line, text in prog.messages:
        print(f"{args.program}:{line}: MSG: {text}", file=sys.stderr)
    for w in prog.warnings:
        print(f"warning: {w}", file=sys.stderr)
    if prog.errors:
        for e in prog.errors:
            print(str(e), file=sys.stderr)
        print(f"dexmon moves: {len(prog.errors)} error(s)", file=sys.stderr)
        return 2
    return 0
