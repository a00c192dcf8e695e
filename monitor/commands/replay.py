"""``dexmon replay``: rebuild, picture or export any stage of a recorded run.

    dexmon replay RUN                                  summary: stages, findings, trace sizes
    dexmon replay RUN --stage N --png out.png [--3d]   picture of stage N (N = end: last)
    dexmon replay RUN --line 22 --png out.png          ... after the last cut of line 22
    dexmon replay RUN --time 12.5 --png out.png        ... at 12.5 s of machine time
    dexmon replay RUN --from A --to B --gif out.gif | --mp4 out.mp4
    dexmon replay RUN --findings                       findings with their lines
    dexmon replay RUN --export-stl N out.stl           the model at stage N as an STL mesh
    dexmon replay RUN --view                           interactive 3-D window with a stage slider

Pictures and animations come from the traces stored in the run file; nothing is
re-simulated. They are coloured by meaning: against the design (the run's job's, or
``--design``) a deviation map (within tolerance grey, gouges red, excess blue, with its
colour bar in mm), without one the depth of cut; by move id only with ``--color-by move``.
Stages may be written as integers, ``end`` or fractions like ``1/4``.
"""

from __future__ import annotations

import json
import sys
from fractions import Fraction

from sim.errors import InputError

HELP = "rebuild, picture or export any stage of a recorded run"


def add_arguments(parser) -> None:
    parser.add_argument("run", help="run file (.dexrun / SQLite) written by live or dry-run")
    parser.add_argument("--stage", default=None, help="stage to picture: N, 'end' or a fraction like 1/2")
    parser.add_argument("--line", type=int, default=None, help="picture the stage after the last cut of this line")
    parser.add_argument("--time", type=float, default=None, metavar="SECONDS",
                        help="picture the stage at this machine time (s since the run's start)")
    parser.add_argument("--png", default=None, metavar="OUT.png", help="write a picture of --stage/--line/--time")
    parser.add_argument("--color-by", default="auto", choices=("auto", "deviation", "depth", "move"),
                        help="colour: deviation against the design (auto when there is one), depth of cut, "
                             "or move id")
    parser.add_argument("--design", default=None, metavar="STL",
                        help="design model for the deviation map (default: the run's job's)")
    parser.add_argument("--tool", default=None, metavar="SPEC", help="tool drawn (default: the run's job's)")
    parser.add_argument("--3d", dest="three_d", action="store_true",
                        help="the --png is a pyvista 3-D view (default: Van Hook's shaded top view)")
    parser.add_argument("--from", dest="first", default=None, help="first stage of an animation")
    parser.add_argument("--to", dest="last", default=None, help="last stage of an animation (may be before --from)")
    parser.add_argument("--gif", default=None, metavar="OUT.gif", help="write the animation as a GIF")
    parser.add_argument("--mp4", default=None, metavar="OUT.mp4", help="write the animation as an MP4")
    parser.add_argument("--fps", type=float, default=10.0, help="animation frames per second (default 10)")
    parser.add_argument("--frames", type=int, default=120, help="at most this many animation frames (default 120)")
    parser.add_argument("--size", type=int, default=800,
                        help="pictures this many pixels on the long side at most; small grids are enlarged "
                             "towards it (default 800)")
    parser.add_argument("--findings", action="store_true", help="list the findings with their lines")
    parser.add_argument("--export-stl", nargs=2, default=None, metavar=("N", "OUT.stl"),
                        help="write the model at stage N as an STL mesh")
    parser.add_argument("--view", action="store_true", help="open an interactive 3-D window with a stage slider")
    parser.add_argument("--json", action="store_true", help="print JSON lines instead of text")


def parse_stage(text, last: int, first: int = 0, where: str = "--stage") -> int:
    """``N``, ``end``/``last``, ``start`` or a fraction ``a/b`` of the run -> a stage number."""
    s = str(text).strip().lower()
    if s in ("end", "last"):
        return int(last)
    if s in ("start", "first"):
        return int(first)
    try:
        if "/" in s or "." in s:
            f = Fraction(s)
            if not 0 <= f <= 1:
                raise ValueError
            return int(first + round(f * (last - first)))
        n = int(s)
    except (ValueError, ZeroDivisionError):
        raise InputError(f"expected a stage number, 'end' or a fraction like 1/4, got {text!r}", where) from None
    if n < 0:
        raise InputError(f"stage must be >= 0, got {n}", where)
    return n


def stage_picture(view, stage: int, max_size: int = 800, three_d: bool = False, findings: bool = True,
                  color_by: str = "auto", design=None, tool=None):
    """RGB uint8 picture of ``stage`` of a :class:`monitor.trace_io.RunView`, coloured by
    meaning with its overlay (:class:`monitor.render.runpicture.RunPictures`)."""
    from monitor.render.runpicture import RunPictures

    pics = RunPictures(view, max_size, color_by=color_by, design=design, tool=tool, findings=findings)
    if three_d:
        from monitor.render import view3d

        return view3d.stage_png(pics, stage, window_size=(max_size, max_size))
    return pics.picture(stage)


def moment(view, args, first: int, last: int) -> int:
    """The stage a picture is of: ``--stage``, ``--line`` or ``--time`` (exactly one)."""
    from monitor.render.runpicture import stage_at_line, stage_at_time

    given = [k for k in ("stage", "line", "time") if getattr(args, k) is not None]
    if len(given) != 1:
        raise InputError("--png needs one of --stage N, --line L or --time SECONDS"
                         + (f" (got {', '.join('--' + g for g in given)})" if given else ""), "--png")
    if args.line is not None:
        return stage_at_line(view, args.line)
    if args.time is not None:
        return stage_at_time(view, args.time)
    return parse_stage(args.stage, last, first)


def _fmt_time(s: float) -> str:
    m, sec = divmod(float(s), 60.0)
    return f"{int(m)}:{sec:05.2f}" if m else f"{sec:.2f} s"


def check_numbers(args) -> None:
    """Refuse numbers no picture or animation can use, before the run file is read."""
    from monitor.options import number, picture_size

    picture_size(args.size)
    number(args.fps, "--fps")
    number(args.frames, "--frames", whole=True)


def run(args) -> int:
    from monitor.render.shaded import save_png
    from monitor.trace_io import RunView

    check_numbers(args)
    out = sys.stdout
    status = 0
    with RunView(args.run) as view:
        # only the findings need no trace: a run whose trace is damaged still lists them
        tr = None if args.findings and not (args.png or args.gif or args.mp4 or args.export_stl or args.view) \
            else view.trace
        first, last = (view.first_stage, view.last_stage) if tr is not None else (0, 0)
        did = False
        tool = None
        if args.tool:
            from sim.tools import parse_tool_spec
            tool = parse_tool_spec(args.tool)
        if args.png:
            n = view.check_stage(moment(view, args, first, last))
            img = stage_picture(view, n, args.size, args.three_d, color_by=args.color_by, design=args.design,
                                tool=tool)
            save_png(img, args.png)
            _say(args, out, {"event": "png", "stage": n, "path": args.png, "size": list(img.shape[:2])},
                 f"stage {n}: wrote {args.png} ({img.shape[1]}x{img.shape[0]})")
            did = True
        elif (args.stage is not None or args.line is not None or args.time is not None) and not args.export_stl:
            raise InputError("--stage/--line/--time need --png OUT.png (or use --export-stl N OUT.stl)", "--stage")
        if args.gif or args.mp4:
            if args.first is None or args.last is None:
                raise InputError("animations need --from A and --to B", "--gif/--mp4")
            from monitor.render.animate import write_animation
            from monitor.render.runpicture import RunPictures

            a = view.check_stage(parse_stage(args.first, last, first, "--from"), "--from")
            b = view.check_stage(parse_stage(args.last, last, first, "--to"), "--to")
            pics = RunPictures(view, args.size, color_by=args.color_by, design=args.design, tool=tool)
            for path in (args.gif, args.mp4):
                if path:
                    n = write_animation(pics.frames(a, b, args.frames), path, fps=args.fps)
                    _say(args, out, {"event": "animation", "from": a, "to": b, "frames": n, "path": path},
                         f"stages {a}..{b}: wrote {n} frames to {path}")
            did = True
        if args.export_stl:
            from sim.surface import export_stl

            n = view.check_stage(parse_stage(args.export_stl[0], last, first, "--export-stl"), "--export-stl")
            grid = view.grid_at(n)
            export_stl(grid, args.export_stl[1])
            _say(args, out, {"event": "stl", "stage": n, "path": args.export_stl[1],
                             "volume_mm3": round(grid.volume(), 3)},
                 f"stage {n}: wrote {args.export_stl[1]} (volume {grid.volume():.3f} mm^3)")
            did = True
        if args.findings:
            fs = view.findings
            from monitor.render.runpicture import finding_moments

            when = finding_moments(view, fs)
            for f, (stage, secs) in zip(fs, when):
                said = format_finding(f)
                if stage is not None:
                    said += f" Stage {stage}" + (f", {_fmt_time(secs)} into the run." if secs is not None else ".")
                _say(args, out, {"event": "finding", **f, "at_stage": stage, "at_s": secs}, said)
            if not fs:
                _say(args, out, {"event": "findings", "count": 0}, "no findings")
            status = 1 if fs else 0
            did = True
        if args.view:
            from monitor.render import view3d

            from monitor.render.runpicture import RunPictures

            view3d.interactive(RunPictures(view, args.size, color_by=args.color_by, design=args.design, tool=tool))
            did = True
        if not did:
            summary = {"event": "summary", "run": str(args.run), "first_stage": first, "last_stage": last,
                       "truncated": view.cut_short is not None, "recorded_stage": view.recorded_stage,
                       "findings": len(view.findings),
                       "rays": tr.frame.n_rays, "spacing_mm": tr.frame.spacing,
                       "z_trace_changes": tr.z.n_changes if tr.z else 0,
                       "time_trace_changes": tr.t.n_changes if tr.t else 0}
            _say(args, out, summary,
                 f"{args.run}: stages {first}..{last}{' (cut short)' if view.cut_short else ''}, "
                 f"{len(view.findings)} findings, {tr.frame.nu}x{tr.frame.nv} rays at {tr.frame.spacing} mm")
        say_damage("replay", view, tr is not None)
    return status


def say_damage(command: str, view, traced: bool = True) -> None:
    """One line on stderr when the run file was damaged (what was skipped), cut short
    (``view.cut_short``: recorded up to where, rebuilt up to where), or written without
    checksums. ``traced``: the command read the trace (else whether the run was cut short
    is not known, and not said)."""
    damage = view.damage_line
    short = view.cut_short if traced else None
    if damage:
        print(f"dexmon {command}: warning: {damage}" + (f"; {short}" if short else ""), file=sys.stderr)
    elif short:
        print(f"dexmon {command}: note: {view.path} was {short}", file=sys.stderr)
    elif not view.reader.checked:
        print(f"dexmon {command}: note: {view.path} has no checksums (written by an older dexmon): "
              "damage in it would go unnoticed", file=sys.stderr)


def format_finding(f: dict) -> str:
    """One sentence for a person: what, where (lines, X Y Z), how big, and whether it was
    predicted and happened. E.g. ``Gouge at lines 22-23, X30.000 Y19.000 Z-5.500: 0.500 mm
    deep, 73.562 mm² of the design, 26.414 mm³; predicted 4.9 s ahead, then happened.``"""
    if f.get("kind") == "setup":  # its message says what looks wrong and what to check
        return "Setup: " + str(f.get("message", "")).removeprefix("setup: ") + "."
    kind = str(f.get("kind", "finding")).replace("_", " ")
    lines = [int(x) for x in (f.get("lines") or ()) if x]
    line = f.get("line")
    span = f.get("line_range")   # the first and last line even when ``lines`` was cut short
    if isinstance(span, (list, tuple)) and len(span) == 2 and span[0] != span[1]:
        lines = [int(span[0]), int(span[1])] if not lines else lines
        first, last = int(span[0]), int(span[1])
    elif len(lines) > 1:
        first, last = lines[0], lines[-1]
    else:
        first = last = None
    if first is not None:
        total = f.get("lines_total", len(lines))
        where = f"lines {first}-{last}" + (f" ({total} lines)" if total != last - first + 1 else "")
        worst = f.get("worst_line")
        if isinstance(worst, int) and worst not in (0, first):
            where += f" (worst at line {worst})"
    else:
        where = f"line {line}" if line not in (None, 0, -1) else "an unknown line"
    pos = f.get("position")
    if isinstance(pos, (list, tuple)) and len(pos) >= 3 and all(v is not None for v in pos[:3]):
        where += f", X{pos[0]:.3f} Y{pos[1]:.3f} Z{pos[2]:.3f}"
        prog = f.get("programmed")
        if isinstance(prog, (list, tuple)) and len(prog) >= 3 and all(isinstance(v, (int, float)) for v in prog[:3]) \
                and max(abs(a - b) for a, b in zip(prog[:3], pos[:3])) >= 5e-4:
            # the contact point above; where the tip was programmed to be for it
            where += f" (programmed tip X{prog[0]:.3f} Y{prog[1]:.3f} Z{prog[2]:.3f})"
    sizes = []
    if f.get("depth") is not None:
        sizes.append(f"{f['depth']:.3f} mm deep")
    if f.get("area") is not None:
        sizes.append(f"{f['area']:.3f} mm² of the design")
    if f.get("volume") is not None:
        sizes.append(f"{f['volume']:.3f} mm³")
    text = f"{kind[:1].upper()}{kind[1:]} at {where}" + (": " + ", ".join(sizes) if sizes else "")
    lead = f.get("lead_time_s")
    if f.get("predicted"):
        ahead = f" {lead:.1f} s ahead" if isinstance(lead, (int, float)) and lead > 0 else ""
        then = ", then happened" if f.get("status") == "happened" else ", not reached in this run"
        text += f"; predicted{ahead}{then}"
    elif f.get("status") == "happened":
        text += "; seen on the real motion"
    return text + "."


def _say(args, out, obj: dict, text: str) -> None:
    print(json.dumps(obj, default=float) if args.json else text, file=out)
