"""``dexmon report RUN -o report.html``: a self-contained HTML report of a recorded run.

Summary (stages, removed volume), the times side by side (programmed, recorded, cutting;
per tool), the link (missed, bad and disconnected polls, every gap: when, how long, what
was missed, how the controller came back, where the monitor found the machine again), the
final part in 3-D and from above coloured by meaning (the deviation map against the
design, else depth of cut), removal and feed over machine time, every finding with its
stage and time, a close 3-D view and a section through it and the program listing round
its line, and the removal per move.
Pictures are PNG embedded as base64; the file needs nothing else to open.
"""

from __future__ import annotations

import base64
import html
import io
import json
import sys
from pathlib import Path

import numpy as np

from sim.errors import InputError

HELP = "write an HTML report of a recorded run"


def add_arguments(parser) -> None:
    parser.add_argument("run", help="run file written by live or dry-run")
    parser.add_argument("-o", "--output", required=True, metavar="OUT.html", help="HTML file to write")
    parser.add_argument("--size", type=int, default=480, help="pictures of findings this many pixels a side")
    parser.add_argument("--design", default=None, metavar="STL",
                        help="design model for the deviation map (default: the run's job's)")
    parser.add_argument("--tool", default=None, metavar="SPEC", help="tool drawn (default: the run's job's)")
    parser.add_argument("--max-findings", type=int, default=50, help="pictures for at most this many findings")
    parser.add_argument("--json", action="store_true", help="print one JSON line instead of text")


def png_base64(img: np.ndarray) -> str:
    import imageio.v3 as iio

    buf = io.BytesIO()
    iio.imwrite(buf, np.ascontiguousarray(img), extension=".png")
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _img_tag(img: np.ndarray, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{png_base64(img)}">'


def finding_stage(view, f: dict, rebuilt: bool = True) -> int:
    """The live stage where a finding is seen whole: the cut after the last cut of any of
    its lines (the poll that found the machine past them, so the picture shows all of it),
    else the stage it happened at, else the run's end. ``rebuilt``: at most the last stage
    the model is rebuilt at (a run cut short may have recorded it later)."""
    tab = view.stage_table
    lines = set(f.get("lines") or ()) | ({int(f["line"])} if f.get("line") is not None else set())
    stage = view.last_stage
    hit = np.nonzero(np.isin(tab["line"], sorted(lines)))[0] if tab.size and lines else ()
    if len(hit):
        stage = int(tab["stage"][min(hit[-1] + 1, tab.size - 1)])
    elif isinstance(f.get("stage"), int) and view.first_stage <= f["stage"] <= view.recorded_stage:
        stage = int(f["stage"])
    return min(stage, view.last_stage) if rebuilt else stage


def cycle_time(view) -> dict:
    out = {}
    tab = view.stage_table
    if tab.size and np.isfinite(tab["t"]).any():
        t = tab["t"][np.isfinite(tab["t"])]
        out["recorded_s"] = float(t.max() - t.min())
    secs = view.row_seconds
    if secs is not None:
        out["program_s"] = float(np.nansum(secs))
    states = view.reader.state_count() if hasattr(view.reader, "state_count") else 0
    if states:
        st = view.reader.states()
        out["machine_s"] = float(st["t"][-1] - st["t"][0])
    return out


def _fmt_s(s: float) -> str:
    m, sec = divmod(float(s), 60.0)
    h, m = divmod(m, 60.0)
    return f"{int(h)}:{int(m):02d}:{sec:05.2f}" if h else f"{int(m)}:{sec:05.2f}"


#: the final part's 3-D picture is at least this many pixels a side
FINAL_3D_MIN_PX = 720
#: link events listed in the report at most
MAX_LINK_EVENTS = 50


def link_section(reader) -> list[str]:
    """HTML of the run's link trouble: counts of missed, bad and disconnected polls, one
    row per gap (when into the run, how long, polls missed, lines lost, position jump,
    how the controller came back, what the monitor did), and the link events said."""
    e = html.escape
    st = reader.states()
    counts = {k: int(np.count_nonzero(st["state"] == v)) for k, v in
              (("missed", "Missed"), ("bad", "Bad"), ("disconnected", "Disconnected"))}
    events = reader.link_events()
    gaps = [g for g in events if g.get("kind") == "gap"]
    said = [ev for ev in events if ev.get("kind") not in ("gap", "lost")]
    parts = ["<h2>Link</h2>"]
    if not any(counts.values()) and not events:
        parts.append(f"<p>No link trouble: every one of {len(st)} polls answered.</p>")
        return parts
    parts.append("<table>")
    rows = [("polls recorded", len(st))] + [(f"{k} polls", v) for k, v in counts.items()] + [("gaps", len(gaps))]
    parts += [f"<tr><th>{e(a)}</th><td>{b}</td></tr>" for a, b in rows]
    parts.append("</table>")
    if gaps:
        parts.append("<table><tr><th>when</th><th>how long</th><th>polls missed</th><th>lines lost</th>"
                     "<th>position jump</th><th>came back</th><th>what happened</th></tr>")
        for g in gaps:
            when = _fmt_s(g["run_s"]) if g.get("run_s") is not None else "?"
            long = f"{g['seconds']:.1f} s" if g.get("seconds") is not None else "not back"
            jump = f"{g['jump_mm']:.2f} mm" if g.get("jump_mm") is not None else ""
            cells = [when, long, g.get("polls_missed", 0), g.get("lines_lost", 0), jump, g.get("came_back", ""),
                     g.get("message", "")]
            parts.append("<tr class='gap'>" + "".join(f"<td>{e(str(c))}</td>" for c in cells) + "</tr>")
        parts.append("</table>")
    if said:
        parts.append("<ul>")
        parts += [f"<li>{e(str(ev.get('kind')))}: {e(str(ev.get('message', '')))}</li>"
                  for ev in said[:MAX_LINK_EVENTS]]
        if len(said) > MAX_LINK_EVENTS:
            parts.append(f"<li>... and {len(said) - MAX_LINK_EVENTS} more</li>")
        parts.append("</ul>")
    return parts


def cycle_per_tool(view) -> list[dict]:
    """Programmed time per tool: ``{"tool", "feed_s", "rapid_s", "other_s", "total_s"}``
    from the rows' programmed seconds (feeds and arcs, rapids, dwells and the rest)."""
    from sim.gcode.moves import MoveKind

    moves, secs = view.moves, view.row_seconds
    if moves is None or secs is None or len(secs) != len(moves):
        return []
    secs = np.nan_to_num(np.asarray(secs, np.float64))
    feed = np.isin(moves["kind"], (MoveKind.FEED, MoveKind.ARC_CW, MoveKind.ARC_CCW))
    rapid = moves["kind"] == MoveKind.RAPID
    out = []
    for tool in np.unique(moves["tool"]):
        mine = moves["tool"] == tool
        f, r = float(secs[mine & feed].sum()), float(secs[mine & rapid].sum())
        total = float(secs[mine].sum())
        out.append({"tool": int(tool), "feed_s": f, "rapid_s": r, "other_s": max(total - f - r, 0.0), "total_s": total})
    return out


def times_section(view) -> list[str]:
    """HTML: the run's times side by side, each said for what it measures, and whether the
    recorded time agrees with the programmed one; then the programmed time per tool."""
    e = html.escape
    ct = cycle_time(view)
    rows = []
    if "program_s" in ct:
        rows.append(("programmed cycle time", _fmt_s(ct["program_s"]), "the program at its feeds and the "
                     "machine's accelerations, start to end"))
    if "machine_s" in ct:
        rows.append(("machine time recorded", _fmt_s(ct["machine_s"]), "first to last state polled from "
                     "the controller"))
    if "recorded_s" in ct:
        rows.append(("cutting time recorded", _fmt_s(ct["recorded_s"]), "first to last cut followed "
                     "(the machine moving through the program)"))
    parts = ["<h2>Times</h2><table><tr><th>time</th><th>h:m:s</th><th>what it measures</th></tr>"]
    parts += [f"<tr><th>{e(a)}</th><td>{e(b)}</td><td style='text-align:left'>{e(c)}</td></tr>"
              for a, b, c in rows]
    parts.append("</table>")
    if "program_s" in ct and "recorded_s" in ct and ct["program_s"] > 0:
        ratio = ct["recorded_s"] / ct["program_s"]
        verdict = "agree" if abs(ratio - 1) <= 0.1 else ("the machine ran slower than programmed" if ratio > 1
                                                        else "the run covered part of the program")
        parts.append(f"<p>Cutting recorded / programmed: {ratio:.2f} ({e(verdict)}).</p>")
    per_tool = cycle_per_tool(view)
    if per_tool:
        parts.append("<h3>Programmed time per tool</h3><table><tr><th>tool</th><th>feeds</th><th>rapids</th>"
                     "<th>other</th><th>total</th></tr>")
        for r in per_tool:
            parts.append(f"<tr><td>T{r['tool']}</td><td>{_fmt_s(r['feed_s'])}</td><td>{_fmt_s(r['rapid_s'])}</td>"
                         f"<td>{_fmt_s(r['other_s'])}</td><td>{_fmt_s(r['total_s'])}</td></tr>")
        parts.append("</table>")
    return parts


def listing_around(view, lines, context: int = 4) -> str:
    """HTML of the program's lines around ``lines`` (the first one ``context`` either
    side, every one of ``lines`` shown marked), or '' without the program text."""
    text = view.meta.get("program")
    lines = [int(x) for x in lines if x]
    if not text or not lines:
        return ""
    src = text.splitlines()
    first = lines[0]
    show = sorted({n for n in range(first - context, first + context + 1) if 1 <= n <= len(src)}
                  | {n for n in lines[:12] if 1 <= n <= len(src)})
    out, prev = [], None
    for n in show:
        if prev is not None and n != prev + 1:
            out.append("<span class='gap'>   ...</span>")
        mark = n in lines
        row = f"{n:5d}  {html.escape(src[n - 1])}"
        out.append(f"<span class='hit'>{row}</span>" if mark else row)
        prev = n
    return "<pre class='listing'>" + "\n".join(out) + "</pre>"


def finding_section(pics, f: dict, stage: int, size: int, cut_short: bool = False) -> list[str]:
    """HTML pictures of one finding at ``stage``: a close 3-D view of the model with its
    deviation map round the finding and a section through it (model, design, stock).
    ``cut_short``: the run's model ends before the finding's lines were cut (``stage`` is
    its last), and the caption says so."""
    parts = []
    when = ("the last stage the model rebuilds: the run was cut short before its lines were"
            if cut_short else "its lines cut")
    pos = np.asarray(f["position"][:3], np.float64)
    from monitor.render.live import finding_label

    try:
        from monitor.render import view3d

        # without the tool: at the moment after its lines it stands over what it did
        img = view3d.stage_png(pics, stage, window_size=(size, size), focus=pos, half_mm=10.0, show_tool=False)
        parts.append(f"<figure>{_img_tag(img, 'close 3-D view of ' + f.get('kind', 'finding'))}"
                     f"<figcaption>3-D view round the finding at stage {stage} ({when})</figcaption></figure>")
    except ImportError:  # pyvista missing: the section and the listing still say it
        pass
    across = section_axis(pics.view, f)
    sec = section_image(pics, stage, pos, finding_label(f), across)
    if sec is not None:
        img, where = sec
        other = "Y" if across == "X" else "X"
        parts.append(f"<figure>{_img_tag(img, 'section through ' + f.get('kind', 'finding'))}"
                     f"<figcaption>section along {across} at {other}{where:.3f}"
                     f"{' (the deepest gouge near it)' if pics.design is not None else ''}</figcaption></figure>")
    return parts


#: a finding's section goes through the deepest gouge within this distance of it, mm
SECTION_SEARCH_MM = 5.0


def section_image(pics, stage: int, pos: np.ndarray, title: str, across: str = "X", half_mm: float = 15.0):
    """(image, axis, where mm) of a vertical section near ``pos`` (plots.section_plot):
    along ``across`` ("X" or "Y"), through the deepest gouge within SECTION_SEARCH_MM of
    ``pos`` when there is a design and a gouge; None when off the model."""
    from monitor.render.plots import section_plot

    frame = pics.frame
    loc = frame.to_local(pos[None])[0] / frame.spacing
    h, _ = pics.view.state_at(stage)
    h = np.asarray(pics.crop(h), np.float64)
    stock = np.asarray(pics.stock_top, np.float64)
    design = pics.design.top() if pics.design is not None else None
    if across == "Y":   # work on the transposed arrays: a row is then a column of rays
        h, stock = h.T, stock.T
        design = None if design is None else design.T
        loc = loc[[1, 0]]
    n_rows, n_along = h.shape
    j = int(round(loc[1]))
    if not 0 <= j < n_rows:
        return None
    i0 = max(int(loc[0] - half_mm / frame.spacing), 0)
    i1 = min(int(loc[0] + half_mm / frame.spacing) + 1, n_along)
    if i1 - i0 < 2:
        return None
    if design is not None:
        # the section through the deepest gouge within a few mm of the finding
        reach = int(np.ceil(SECTION_SEARCH_MM / frame.spacing))
        j0, j1 = max(j - reach, 0), min(j + reach + 1, n_rows)
        c0, c1 = max(int(loc[0]) - reach, 0), min(int(loc[0]) + reach + 1, n_along)
        with np.errstate(invalid="ignore"):
            dev = np.nan_to_num(design[j0:j1, c0:c1] - h[j0:j1, c0:c1], nan=0.0)
        if dev.size and dev.max() > 0:
            j = j0 + int(np.unravel_index(np.argmax(dev), dev.shape)[0])
    a, b = (0, 1) if across == "X" else (1, 0)
    x = frame.origin[a] + np.arange(i0, i1) * frame.spacing
    where = float(frame.origin[b] + j * frame.spacing)
    img = section_plot(x, h[j, i0:i1], None if design is None else design[j, i0:i1], stock[j, i0:i1],
                       float(pos[a]), title, axis=across)
    return img, where


def section_axis(view, f: dict) -> str:
    """The axis a finding's section runs along: across the travel of its first line (a
    groove cut along X is seen in a section along Y), X when unknown."""
    moves = view.moves
    line = f.get("line")
    if moves is None or not isinstance(line, int):
        return "X"
    rows = np.nonzero(moves["line"] == line)[0]
    if rows.size == 0:
        return "X"
    d = np.abs(np.nansum(moves["end"][rows, :2] - moves["start"][rows, :2], axis=0))
    return "Y" if d[0] > d[1] else "X"


def timeline_section(view, pics) -> list[str]:
    """HTML: removal rate and programmed feed over machine time, the findings marked."""
    from monitor.render.runpicture import finding_moments
    from monitor.render.live import finding_label
    from monitor.render.plots import timeline_plot
    from sim.gcode.moves import MoveKind

    tab = view.stage_table
    if not tab.size or not np.isfinite(tab["t"]).any():
        return []
    t_cut = tab["t"] - pics.t0
    stages, vol = view.removal_per_stage()
    k = np.clip(np.searchsorted(tab["stage"], stages, side="left"), 0, tab.size - 1)
    t_rem = t_cut[k]
    span = float(np.nanmax(t_cut) - np.nanmin(t_cut)) if t_cut.size else 0.0
    width = max(span / 200.0, 1e-3)
    edges = np.arange(np.nanmin(t_cut), np.nanmax(t_cut) + 2 * width, width)
    rate = np.histogram(t_rem, bins=edges, weights=vol)[0] / width if len(vol) else np.zeros(len(edges) - 1)
    feed = np.full(tab.size, np.nan)
    moves = view.moves
    if moves is not None:
        row = np.clip(tab["move_id"] - 1, 0, len(moves) - 1)
        feed = np.where(moves["kind"][row] == MoveKind.RAPID, 0.0, moves["feed"][row])
    marks = [(s, finding_label(f)) for f, (_, s) in zip(view.findings, finding_moments(view, view.findings))
             if s is not None]
    img = timeline_plot(edges[:-1], rate, t_cut, feed, marks)
    return ["<h2>Removal and feed over time</h2>",
            f"<figure>{_img_tag(img, 'removal and feed over time')}<figcaption>removal rate (mm³/s) and "
            "programmed feed (mm/min, rapids at 0) against machine time; findings marked</figcaption></figure>"]


def build_report(view, size: int = 480, max_findings: int = 50, design=None, tool=None) -> str:
    """The report of a :class:`monitor.trace_io.RunView` as one HTML string."""
    from monitor.commands.replay import format_finding
    from monitor.render.runpicture import finding_moments
    from monitor.render.runpicture import RunPictures

    tr = view.trace
    first, last = view.first_stage, view.last_stage
    frame = tr.frame
    findings = view.findings
    pics = RunPictures(view, size=max(size, 480), design=design, tool=tool)

    removal = view.removal_per_move()
    removed_total = float(sum(removal.values()))
    e = html.escape
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>dexmon report: {e(view.path.name)}</title>",
        "<style>body{font-family:sans-serif;margin:2em;background:#fafafa;color:#222}"
        "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}"
        "th{background:#eee}.f{display:flex;flex-wrap:wrap;gap:1em;align-items:flex-start;margin:1em 0}"
        ".bad{color:#b00}img{border:1px solid #999;max-width:100%}"
        "pre.listing{background:#f0f0f0;padding:.5em;font-size:90%}pre .hit{background:#ffd0d0;font-weight:bold}"
        "</style></head><body>",
        f"<h1>dexmon run report: {e(view.path.name)}</h1>",
        "<!-- damage -->",  # what was damaged, filled in at the end (when everything has been read)
        "<h2>Summary</h2><table>",
    ]
    rows = [("program", view.meta.get("program_path", "")),
            ("stages", f"{first} .. {last}" + (f" (run {view.cut_short})" if view.cut_short else "")),
            ("dexel grid", f"{frame.nu} x {frame.nv} rays at {frame.spacing:g} mm"),
            ("removed volume", f"{removed_total:.3f} mm³"),
            ("findings", str(len(findings))),
            ("pictures coloured by", {"deviation": "deviation from the design", "depth": "depth of cut",
                                      "move": "move id"}[pics.color_by])]
    ct = cycle_time(view)
    if "program_s" in ct:
        rows.append(("programmed cycle time", _fmt_s(ct["program_s"])))
    parts += [f"<tr><th>{e(a)}</th><td>{e(str(b))}</td></tr>" for a, b in rows]
    parts.append("</table>")
    parts += times_section(view)
    parts += link_section(view.reader)
    parts.append("<h2>The part</h2><div class='f'>")
    try:
        from monitor.render import view3d

        side = max(size, FINAL_3D_MIN_PX)
        img3 = view3d.stage_png(pics, last, window_size=(side, side))
        parts.append(f"<figure>{_img_tag(img3, 'final part in 3-D')}<figcaption>stage {last} in 3-D"
                     f"{' with the deviation map' if pics.color_by == 'deviation' else ''}</figcaption></figure>")
    except ImportError:  # pyvista missing: the top views still show the part
        pass
    parts.append(f"<figure>{_img_tag(pics.picture(last), 'end')}<figcaption>stage {last} from above "
                 f"(findings ringed)</figcaption></figure>")
    start = RunPictures(view, size=max(size, 480), design=design, tool=tool, findings=False)
    parts.append(f"<figure>{_img_tag(start.picture(first), 'start')}<figcaption>stage {first}: the stock"
                 f"</figcaption></figure></div>")
    parts += timeline_section(view, pics)
    parts.append(f"<h2>Findings ({len(findings)})</h2>")
    if not findings:
        parts.append("<p>No findings.</p>")
    moments = finding_moments(view, findings)
    for n, (f, (at_stage, secs)) in enumerate(zip(findings, moments)):
        when = (f" Stage {at_stage}" + (f", {_fmt_s(secs)} into the run" if secs is not None else "") + "."
                if at_stage is not None else "")
        lines = f.get("lines") or []
        # the sentence names the line range; list the lines only when a range hides gaps
        gaps = len(lines) > 2 and lines[-1] - lines[0] + 1 != len(lines)
        listed = (f"<p>lines: {e(', '.join(map(str, lines[:40])))}{' …' if len(lines) > 40 else ''}</p>"
                  if gaps else "")
        parts.append(f"<div class='finding'><p class='bad'>{e(format_finding(f))}{e(when)}</p>{listed}")
        parts.append("<div class='f'>")
        if n < max_findings and isinstance(f.get("position"), list) and len(f["position"]) >= 3:
            stage = finding_stage(view, f)
            parts += finding_section(pics, f, stage, size, cut_short=finding_stage(view, f, rebuilt=False) > stage)
        parts.append(listing_around(view, lines or [f.get("line")]))
        parts.append("</div></div>")
    parts.append("<h2>Removal per move</h2><table><tr><th>move</th><th>line</th><th>removed (mm³)</th></tr>")
    moves = view.moves
    for m, v in sorted(removal.items()):
        line = int(moves["line"][m - 1]) if moves is not None and 1 <= m <= len(moves) else ""
        parts.append(f"<tr><td>{m}</td><td>{line}</td><td>{v:.3f}</td></tr>")
    parts.append("</table></body></html>")
    said = [x for x in (view.damage_line, view.cut_short and f"The run was {view.cut_short}.") if x]
    if said:
        parts[parts.index("<!-- damage -->")] = "".join(f"<p class='bad'>{e(x)}</p>" for x in said)
    return "\n".join(parts)


def run(args) -> int:
    from monitor.commands.replay import say_damage
    from monitor.options import number, picture_size
    from monitor.trace_io import RunView

    picture_size(args.size)
    number(args.max_findings, "--max-findings", whole=True, zero=True)  # 0: no pictures of findings

    out = Path(args.output)
    if out.suffix.lower() not in (".html", ".htm"):
        raise InputError(f"the report is HTML; give a .html file, got {out.name!r}", "-o")
    with RunView(args.run) as view:
        tool = None
        if args.tool:
            from sim.tools import parse_tool_spec
            tool = parse_tool_spec(args.tool)
        text = build_report(view, args.size, args.max_findings, design=args.design, tool=tool)
        n = len(view.findings)
        say_damage("report", view)
    out.write_text(text, encoding="utf-8")
    if getattr(args, "json", False):
        print(json.dumps({"event": "report", "path": str(out), "findings": n}), file=sys.stdout)
    else:
        print(f"wrote {out} ({n} finding{'s' if n != 1 else ''})", file=sys.stdout)
    return 0
