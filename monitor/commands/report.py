"""``dexmon report RUN -o report.html``: a self-contained HTML report of a recorded run.

Summary (stages, cycle time, removed volume), the link (missed, bad and disconnected polls,
every gap: when, how long, what was missed, how the controller came back, where the
monitor found the machine again), every finding with its lines and a picture of the model
where it happened, the removal per move, and pictures of the start and end.
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
    parser.add_argument("--size", type=int, default=480, help="pictures at most this many pixels a side")
    parser.add_argument("--max-findings", type=int, default=50, help="pictures for at most this many findings")
    parser.add_argument("--json", action="store_true", help="print one JSON line instead of text")


def png_base64(img: np.ndarray) -> str:
    import imageio.v3 as iio

    buf = io.BytesIO()
    iio.imwrite(buf, np.ascontiguousarray(img), extension=".png")
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _img_tag(img: np.ndarray, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{png_base64(img)}">'


def finding_stage(view, f: dict) -> int:
    """The live stage where a finding is seen: the last cut of any of its lines (so the
    picture shows all of it), else the stage it happened at, else the run's end."""
    tab = view.stage_table
    lines = set(f.get("lines") or ()) | ({int(f["line"])} if f.get("line") is not None else set())
    if tab.size and lines:
        hit = np.nonzero(np.isin(tab["line"], sorted(lines)))[0]
        if hit.size:
            return min(int(tab["stage"][hit[-1]]), view.last_stage)
    if isinstance(f.get("stage"), int) and view.first_stage <= f["stage"] <= view.last_stage:
        return int(f["stage"])
    return view.last_stage


def crop_around(img: np.ndarray, frame, k: int, pos, half_mm: float = 12.0) -> np.ndarray:
    """The part of a (possibly reduced by ``k``) picture within ``half_mm`` of ``pos``."""
    from monitor.render.shaded import to_pixels

    c = to_pixels(frame, np.asarray(pos, np.float64).reshape(1, 3))[0] / k
    r = max(8, int(half_mm / (frame.spacing * k)))
    h, w = img.shape[:2]
    x0, x1 = int(max(c[0] - r, 0)), int(min(c[0] + r, w))
    y0, y1 = int(max(c[1] - r, 0)), int(min(c[1] + r, h))
    if x1 - x0 < 4 or y1 - y0 < 4:
        return img
    crop = img[y0:y1, x0:x1]
    rep = max(1, 160 // max(crop.shape[:2]))
    return np.repeat(np.repeat(crop, rep, axis=0), rep, axis=1)


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


def build_report(view, size: int = 480, max_findings: int = 50) -> str:
    """The report of a :class:`monitor.trace_io.RunView` as one HTML string."""
    from monitor.commands.replay import finding_positions, format_finding
    from monitor.render.animate import frame_picture, reduce_factor

    tr = view.trace
    first, last = view.first_stage, view.last_stage
    frame = tr.frame
    k = reduce_factor(frame.shape, size)
    findings = view.findings
    marks = finding_positions(findings)
    tool = view.tool()

    def pic(stage, with_marks=True):
        h, ids = view.state_at(stage)
        info = view.stage_info(stage)
        tip = info.get("tip")
        tip = tip if tip is not None and np.all(np.isfinite(tip)) else None
        return frame_picture(h, ids, frame, k, tool=tool, tip=tip,
                             findings=marks if with_marks else None)

    removal = view.removal_per_move()
    removed_total = float(sum(removal.values()))
    ct = cycle_time(view)
    e = html.escape
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>dexmon report: {e(view.path.name)}</title>",
        "<style>body{font-family:sans-serif;margin:2em;background:#fafafa;color:#222}"
        "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}"
        "th{background:#eee}.f{display:flex;gap:1em;align-items:flex-start;margin:1em 0}"
        ".bad{color:#b00}img{image-rendering:pixelated;border:1px solid #999}</style></head><body>",
        f"<h1>dexmon run report: {e(view.path.name)}</h1>",
        "<!-- damage -->",  # what was damaged, filled in at the end (when everything has been read)
        "<h2>Summary</h2><table>",
    ]
    rows = [("program", view.meta.get("program_path", "")),
            ("stages", f"{first} .. {last}" + (" (run cut short)" if tr.truncated else "")),
            ("dexel grid", f"{frame.nu} x {frame.nv} rays at {frame.spacing:g} mm"),
            ("removed volume", f"{removed_total:.3f} mm³"),
            ("findings", str(len(findings)))]
    for key, label in (("program_s", "programmed cycle time"), ("machine_s", "machine time recorded"),
                       ("recorded_s", "cutting time recorded")):
        if key in ct:
            rows.append((label, _fmt_s(ct[key])))
    parts += [f"<tr><th>{e(a)}</th><td>{e(str(b))}</td></tr>" for a, b in rows]
    parts.append("</table>")
    parts += link_section(view.reader)
    parts.append("<h2>Start and end</h2><div class='f'>")
    parts.append(f"<figure>{_img_tag(pic(first, False), 'start')}<figcaption>stage {first}</figcaption></figure>")
    parts.append(f"<figure>{_img_tag(pic(last), 'end')}<figcaption>stage {last} (findings ringed)"
                 f"</figcaption></figure></div>")
    parts.append(f"<h2>Findings ({len(findings)})</h2>")
    if not findings:
        parts.append("<p>No findings.</p>")
    for n, f in enumerate(findings):
        parts.append("<div class='f'>")
        if n < max_findings and isinstance(f.get("position"), list) and len(f["position"]) >= 3:
            stage = finding_stage(view, f)
            img = crop_around(pic(stage), frame, k, f["position"])
            parts.append(f"<figure>{_img_tag(img, f.get('kind', 'finding'))}"
                         f"<figcaption>stage {stage}</figcaption></figure>")
        lines = f.get("lines") or []
        # the sentence names the line range; list the lines only when a range hides gaps
        gaps = len(lines) > 2 and lines[-1] - lines[0] + 1 != len(lines)
        listed = (f"<p>lines: {e(', '.join(map(str, lines[:40])))}{' …' if len(lines) > 40 else ''}</p>"
                  if gaps else "")
        parts.append(f"<div><p class='bad'>{e(format_finding(f))}</p>{listed}</div></div>")
    parts.append("<h2>Removal per move</h2><table><tr><th>move</th><th>line</th><th>removed (mm³)</th></tr>")
    moves = view.moves
    for m, v in sorted(removal.items()):
        line = int(moves["line"][m - 1]) if moves is not None and 1 <= m <= len(moves) else ""
        parts.append(f"<tr><td>{m}</td><td>{line}</td><td>{v:.3f}</td></tr>")
    parts.append("</table></body></html>")
    if view.damage_line:
        parts[parts.index("<!-- damage -->")] = f"<p class='bad'>{e(view.damage_line)}</p>"
    return "\n".join(parts)


def run(args) -> int:
    from monitor.commands.replay import say_damage
    from monitor.trace_io import RunView

    out = Path(args.output)
    if out.suffix.lower() not in (".html", ".htm"):
        raise InputError(f"the report is HTML; give a .html file, got {out.name!r}", "-o")
    with RunView(args.run) as view:
        text = build_report(view, args.size, args.max_findings)
        n = len(view.findings)
        say_damage("report", view, "the report shows it up to its last intact stage"
                   if view.trace.truncated else None)
    out.write_text(text, encoding="utf-8")
    if getattr(args, "json", False):
        print(json.dumps({"event": "report", "path": str(out), "findings": n}), file=sys.stdout)
    else:
        print(f"wrote {out} ({n} finding{'s' if n != 1 else ''})", file=sys.stdout)
    return 0
