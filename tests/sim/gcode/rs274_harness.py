"""Differential harness: dexmon's interpreter against LinuxCNC's stand-alone ``rs274``.

``rs274`` (Debian package ``linuxcnc-uspace``) prints a program's canonical machining calls.
This module runs it (:func:`run_rs274`), reads its output into motion end points
(:func:`parse_canon`), turns dexmon's move table into the same list (:func:`dexmon_motions`)
and compares the two (:func:`compare`). ``bench/rs274_diff.py`` runs it over whole program
collections; ``tests/sim/gcode/test_rs274.py`` over the recorded outputs in ``tests/data/rs274``.

Both sides get the same tool table, parameter file and subroutine directory. rs274 treats
tool tables and parameter files in inches (its machine units), so dexmon is run with
``machine_units="inch"``. Canon positions are *program* coordinates (offsets are separate
calls) in program units; they are converted to mm here and compared with dexmon's
``end - wco``.
"""

from __future__ import annotations

import dataclasses
import gzip
import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

#: DEXMON_RS274=off runs the tests as a machine without LinuxCNC would (recordings only)
RS274 = None if os.environ.get("DEXMON_RS274") == "off" else shutil.which("rs274")
ROOT = Path(__file__).resolve().parents[3]
DATA = ROOT / "tests" / "data" / "rs274"
SHARED = Path(os.environ.get("DEXMON_SHARED", ROOT.parent / "shared"))
#: where Debian's linuxcnc-uspace puts its sample programs
PACKAGE_DIRS = (Path("/usr/share/linuxcnc/ncfiles"), Path("/usr/share/doc/linuxcnc/examples"))
CORPUS_TABLES = {
    "linuxcnc_mmount.ngc": "linuxcnc_mmount.tbl",
    "linuxcnc_gmoccapy_2tools_ccomp.ngc": "linuxcnc_gmoccapy_2tools_ccomp.tbl",
    "linuxcnc_cam_nisley.ngc": "linuxcnc_cam_nisley.tbl",
}
#: rs274 refuses a file with no M2/M30 or closing % after running all of it; dexmon takes it
#: (GRBL senders stream such files), so the harness compares its motions as accepted
NO_END = "File ended with no percent sign or program end"
#: what dexmon refuses on purpose, with a clear message: lathe-only codes, U V W axes
BY_DESIGN = re.compile(r"lathe|U V W|axis words are not supported")
MM_TOL = 1e-3                      # mm: the tolerance
INCH_TOL = 0.5e-4 * 25.4 + 1e-6    # rs274 prints 4 decimals: an inch program is known to that

_CANON = re.compile(r"^\s*\d+ N\S*\s+([A-Z_0-9]+)\((.*)\)\s*$")
_UNITS = {"CANON_UNITS_MM": 1.0, "CANON_UNITS_INCHES": 25.4, "CANON_UNITS_CM": 10.0}
# ARC_FEED(first_end, second_end, first_axis, second_axis, rotation, axis_end, a, b, c):
# which of X Y Z the first, second and axis coordinates are, per plane
_ARC_AXES = {"CANON_PLANE_XY": (0, 1, 2), "CANON_PLANE_XZ": (2, 0, 1), "CANON_PLANE_YZ": (1, 2, 0)}
ERROR = "ERROR: "   # prefix of rs274's stderr lines in the text this module keeps
MOTION_KINDS = ("T", "F", "A", "P", "S")   # traverse, feed, arc, probe, spline


@dataclasses.dataclass
class Motion:
    """One motion end point: ``kind`` in MOTION_KINDS, ``end`` X Y Z A B C in mm/degrees
    (None for an rs274 spline, whose points it does not print), ``center`` of an arc (3,)."""

    kind: str
    end: np.ndarray | None
    center: np.ndarray | None = None
    tol: float = MM_TOL
    where: str = ""       # dexmon: "file:line"; rs274: the canon call's index
    key: tuple = ()       # dexmon: (file index, line) of the row


@dataclasses.dataclass
class Run:
    """What one interpreter made of a program: its motions, and its error if it refused."""

    motions: list[Motion]
    error: str | None = None       # the message
    error_text: str | None = None  # the block it refused (rs274 prints its text, not its number)
    error_line: int | None = None  # dexmon only


@dataclasses.dataclass(frozen=True)
class Case:
    """One program of a set, with the inputs both interpreters get."""

    name: str          # "tests/x.ngc", "corpus/x.nc", "package/ncfiles__x.ngc": the recording's name
    path: Path
    tools: Path
    params: Path

    @property
    def recording(self) -> Path:
        return DATA / "canon" / (self.name + ".canon.gz")


def cases(which: str = "all") -> list[Case]:
    """The programs of a set: ``tests`` (tests/data/rs274/programs), ``corpus``
    (../shared/corpus/gcode, when present), ``package`` (linuxcnc-uspace's, when installed)."""
    out: list[Case] = []
    if which in ("tests", "all"):
        for p in sorted((DATA / "programs").glob("*.ngc")):
            out.append(Case("tests/" + p.name, p, DATA / "tools.tbl", DATA / "params.var"))
    corpus = SHARED / "corpus" / "gcode"
    if which in ("corpus", "all") and corpus.is_dir():
        tables = corpus / "tooltables"
        for p in sorted(corpus.iterdir()):
            if p.is_file() and p.suffix != ".md":
                out.append(Case("corpus/" + p.name, p, tables / CORPUS_TABLES.get(p.name, "default.tbl"),
                                tables / "rs274_seed.var"))
    if which in ("package", "all"):
        for base in PACKAGE_DIRS:
            for p in sorted(base.rglob("*.ngc")) if base.is_dir() else []:
                rel = str(p.relative_to(base.parent)).replace("/", "__")
                out.append(Case("package/" + rel, p, DATA / "tools.tbl", DATA / "params.var"))
    return out


def run_rs274(program: Path, tool_table: Path, var_file: Path, block_delete: bool = False,
              timeout: float = 120.0) -> str:
    """rs274's canon output (stdout) for ``program``, run in batch mode from the program's folder.

    The parameter file is copied first: rs274 writes it back at the end. HOME is a fresh
    folder: rs274 keeps its tool table in ``$HOME/.tool.mmap``, shared by every rs274 run
    of that user, so parallel runs with other tables would see each other's tools.
    """
    if RS274 is None:
        raise RuntimeError("rs274 is not on the PATH (apt-get install linuxcnc-uspace)")
    with tempfile.TemporaryDirectory() as tmp:
        var = Path(tmp) / "params.var"
        shutil.copyfile(var_file, var)
        cmd = [RS274, "-g", "-t", str(tool_table), "-v", str(var)]
        if block_delete:
            cmd.append("-b")   # the switch toggles: default off, -b on
        cmd.append(str(Path(program).resolve()))
        env = dict(os.environ, LC_ALL="C", HOME=tmp)
        done = subprocess.run(cmd, input=b"5\n", capture_output=True, timeout=timeout,
                              cwd=Path(program).resolve().parent, env=env)
    # rs274 prints its error (message, then the refused block) on stderr
    errors = [ln for ln in done.stderr.decode("utf-8", "replace").splitlines()
              if ln.strip() and ln.strip() != "executing" and not ln.startswith("int Interp::")]
    return done.stdout.decode("utf-8", "replace") + "".join(f"{ERROR}{ln}\n" for ln in errors)


def _numbers(args: str) -> list[float]:
    return [float(x) for x in re.split(r"[,\s]+", args.strip()) if x and x != "..."]


def parse_canon(text: str) -> Run:
    """Motions and error of rs274's output ``text`` (see :func:`run_rs274`)."""
    motions: list[Motion] = []
    scale, plane = 1.0, "CANON_PLANE_XY"
    error_lines: list[str] = []
    for i, raw in enumerate(text.splitlines()):
        m = _CANON.match(raw)
        if m is None:
            if raw.startswith(ERROR):
                error_lines.append(raw[len(ERROR):].rstrip())
            continue
        call, args = m.groups()
        where = f"canon {i}"
        tol = MM_TOL if scale != 25.4 else INCH_TOL
        if call == "USE_LENGTH_UNITS":
            scale = _UNITS[args.strip()]
        elif call == "SELECT_PLANE":
            plane = args.strip()
        elif call in ("STRAIGHT_TRAVERSE", "STRAIGHT_FEED", "STRAIGHT_PROBE"):
            v = _numbers(args)[:6]
            end = np.array(v[:3] + [0.0] * 3) * scale
            end[3:6] = v[3:6]
            motions.append(Motion({"STRAIGHT_TRAVERSE": "T", "STRAIGHT_FEED": "F",
                                   "STRAIGHT_PROBE": "P"}[call], end, tol=tol, where=where))
        elif call == "ARC_FEED":
            v = _numbers(args)
            first, second, axis = _ARC_AXES[plane]
            end = np.zeros(6)
            center = np.full(3, np.nan)
            end[first], end[second], end[axis] = v[0] * scale, v[1] * scale, v[5] * scale
            center[first], center[second] = v[2] * scale, v[3] * scale
            end[3:6] = v[6:9]
            motions.append(Motion("A", end, center, tol=tol, where=where))
        elif call == "NURBS_FEED":
            motions.append(Motion("S", None, tol=tol, where=where))
        elif call == "RIGID_TAP":
            # G33.1: in to the point, then back out to where it started
            back = motions[-1].end.copy() if motions and motions[-1].end is not None else np.zeros(6)
            end = back.copy()
            end[:3] = np.array(_numbers(args)[:3]) * scale
            motions.append(Motion("F", end, tol=tol, where=where))
            motions.append(Motion("F", back, tol=tol, where=where))
    run = Run(motions)
    if error_lines and error_lines[0] != NO_END:
        run.error = error_lines[0]
        run.error_text = error_lines[1] if len(error_lines) > 1 else ""
    return run


def dexmon_run(program: Path, tool_table: Path, var_file: Path, block_delete: bool = False, **kw) -> Run:
    """dexmon's motions for ``program`` with the same inputs as :func:`run_rs274`.

    dexmon reads its position back after a tool change as rs274's stand-alone canon does
    (``after_tool_change="rs274"``), not as a machine does (its default): see
    sim/gcode/tool_length.py.
    """
    kw.setdefault("after_tool_change", "rs274")
    from sim.gcode import GCodeError, load_program

    try:
        prog = load_program(program, tool_table=tool_table, var_file=var_file, machine_units="inch",
                            subroutine_path=[Path(program).parent], block_delete=block_delete, **kw)
    except GCodeError as err:
        # the motions before the refused line are compared too
        prog = load_program(program, tool_table=tool_table, var_file=var_file, machine_units="inch",
                            subroutine_path=[Path(program).parent], block_delete=block_delete,
                            keep_going=True, **kw)
        first = prog.errors[0] if prog.errors else None
        rows = getattr(first, "rows_before", None)
        return Run(dexmon_motions(prog, upto=(err.file, err.line), rows=rows), error=err.message,
                   error_text=err.source_line, error_line=err.line)
    return Run(dexmon_motions(prog))


def dexmon_motions(prog, upto: tuple[str, int] | None = None, rows: int | None = None) -> list[Motion]:
    """The motion rows of ``prog``'s move table as :class:`Motion` (work coordinates, mm).

    The rows of one spline block become one ``"S"`` motion (rs274 prints no spline points).
    ``upto`` (file name, line) stops at the first row of that line or a later one of that file;
    ``rows``, the number of rows made before the error when it is known, stops there instead
    (an error in a subroutine, a move held by cutter compensation that was never made).
    """
    from sim.gcode import MoveKind
    from sim.gcode.moves import work_end

    moves = prog.moves
    ends = work_end(moves)
    centers = moves["center"] - moves["wco"][:, :3]
    out: list[Motion] = []
    kinds = {MoveKind.RAPID: "T", MoveKind.FEED: "F", MoveKind.ARC_CW: "A", MoveKind.ARC_CCW: "A",
             MoveKind.PROBE: "P"}
    for i in range(len(moves) if rows is None else min(rows, len(moves))):
        key = (int(moves["file"][i]), int(moves["line"][i]))
        if rows is None and upto is not None and prog.files[key[0]] == upto[0] and key[1] >= upto[1]:
            break
        kind = kinds.get(int(moves["kind"][i]))
        if kind is None or kind == "P" and moves["feed"][i] == 0.0:
            continue   # a probe's retract (feed 0) is part of rs274's STRAIGHT_PROBE
        where = f"{Path(prog.files[key[0]]).name}:{key[1]}"
        out.append(Motion(kind, ends[i].copy(), centers[i].copy() if kind == "A" else None, where=where, key=key))
    return out


def _dedupe(motions: list[Motion]) -> list[Motion]:
    """Drop zero-length motions: one whose end equals the previous end (either side may skip them)."""
    out: list[Motion] = []
    last = np.zeros(6)
    for m in motions:
        if m.end is not None and m.kind != "P" and np.all(np.abs(m.end - last) <= 1e-7 + 0.5 * m.tol):
            continue
        out.append(m)
        if m.end is not None:
            last = m.end
    return out


def _norm_block(text: str | None) -> str:
    return re.sub(r"\s+", "", (text or "")).lower()


@dataclasses.dataclass
class Comparison:
    """Outcome of :func:`compare`: ``status`` is one of
    ``match`` (both accept, same motions), ``both_refuse`` (same block, same motions before it),
    ``by_design`` (dexmon refuses a lathe code or a U V W axis clearly; the same motions before it),
    ``differ`` (motions differ), ``refuse_differs`` (one refuses, or they refuse other blocks)."""

    status: str
    detail: str = ""
    index: int | None = None   # first differing motion
    count: int = 0             # motions compared (rs274's)

    @property
    def ok(self) -> bool:
        return self.status in ("match", "both_refuse", "by_design")


def compare(ref: Run, got: Run) -> Comparison:
    """Compare rs274's run ``ref`` with dexmon's run ``got`` motion by motion.

    An rs274 spline (``NURBS_FEED``, no points printed) stands for all of dexmon's chords of
    one block; the motion after it checks where the spline ended.
    """
    a, b = _dedupe(ref.motions), _dedupe(got.motions)
    i = j = 0
    while i < len(a) and j < len(b):
        if a[i].kind == "S" and b[j].kind == "F":
            while j + 1 < len(b) and b[j + 1].key == b[j].key and b[j + 1].kind == "F":
                j += 1
            i, j = i + 1, j + 1
            continue
        bad = _motion_differs(a[i], b[j])
        if bad:
            return Comparison("differ", f"motion {i}: {bad} (rs274 {a[i].where}, dexmon {b[j].where})", i, len(a))
        i, j = i + 1, j + 1
    if got.error is not None and BY_DESIGN.search(got.error) and j == len(b):
        return Comparison("by_design", f"dexmon refuses line {got.error_line}: {got.error}", count=len(a))
    if (ref.error is None) != (got.error is None):
        who = "rs274" if ref.error else "dexmon"
        msg = ref.error if ref.error else f"line {got.error_line}: {got.error}"
        return Comparison("refuse_differs", f"only {who} refuses: {msg} [{ref.error_text or got.error_text}]",
                          count=len(a))
    if i < len(a) or j < len(b):
        extra, who = (a[i], "rs274") if i < len(a) else (b[j], "dexmon")
        return Comparison("differ", f"motion {i}: only {who} has it ({extra.kind} {_fmt(extra.end)} "
                          f"{extra.where}); rs274 {len(a)} motions, dexmon {len(b)} rows", i, len(a))
    if ref.error is not None:
        eof = re.search(r"seeking o-word: .* from line: (\d+)", ref.error)
        if eof and got.error_line == int(eof.group(1)):
            return Comparison("both_refuse", ref.error, count=len(a))
        if _norm_block(ref.error_text) != _norm_block(got.error_text):
            return Comparison("refuse_differs", f"rs274 refuses [{ref.error_text}] ({ref.error}); dexmon refuses "
                              f"line {got.error_line} [{got.error_text}] ({got.error})", count=len(a))
        return Comparison("both_refuse", ref.error, count=len(a))
    return Comparison("match", count=len(a))


def _fmt(v) -> str:
    return "None" if v is None else "(" + ", ".join(f"{x:.4f}" for x in np.asarray(v)[:3]) + ")"


def _motion_differs(r: Motion, d: Motion) -> str:
    if r.kind != d.kind and not (r.kind == "S" or d.kind == "S"):
        return f"kind {r.kind} vs {d.kind} at {_fmt(r.end)} / {_fmt(d.end)}"
    if r.kind == "S" and d.kind != "S":
        return f"rs274 spline vs dexmon {d.kind} {_fmt(d.end)}"
    if r.end is not None and d.end is not None:
        err = float(np.max(np.abs(r.end - d.end)))
        if not err <= r.tol:
            return f"end {_fmt(r.end)} vs {_fmt(d.end)} (off {err:.4f} mm)"
    if r.kind == "A" and d.kind == "A" and r.center is not None and d.center is not None:
        mask = np.isfinite(r.center)
        err = float(np.max(np.abs(r.center[mask] - d.center[mask])))
        if not err <= r.tol:
            return f"arc centre {_fmt(r.center)} vs {_fmt(d.center)} (off {err:.4f} mm)"
    return ""


# --- recorded outputs ------------------------------------------------------------------------

def keep_canon(text: str) -> str:
    """The lines of rs274's output the comparison reads (units, plane, motions, the error)."""
    keep = []
    for raw in text.splitlines():
        m = _CANON.match(raw)
        if m is None:
            if raw.startswith(ERROR):
                keep.append(raw.rstrip())
        elif m.group(1) in ("USE_LENGTH_UNITS", "SELECT_PLANE", "STRAIGHT_TRAVERSE", "STRAIGHT_FEED",
                            "STRAIGHT_PROBE", "ARC_FEED", "NURBS_FEED", "RIGID_TAP"):
            keep.append(raw.rstrip())
    return "\n".join(keep) + "\n"


def write_recording(path: Path, text: str) -> None:
    """Write the kept canon lines of ``text`` gzip-compressed (mtime 0: same bytes every time)."""
    data = keep_canon(text).encode()
    with open(path, "wb") as fh, gzip.GzipFile(fileobj=fh, mode="wb", mtime=0, filename="") as gz:
        gz.write(data)


def read_recording(path: Path) -> str:
    return gzip.decompress(Path(path).read_bytes()).decode()
