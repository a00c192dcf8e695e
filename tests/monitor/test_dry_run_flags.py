"""A dry run of a job given wholly by flags (``--program --stock --tool --design``, no job
file) judges that job, not the bundled example with the flags laid over it.

Before: the example was the base of every dry run without a job file, so its tool table
(T1 = a 6 mm *flat* end mill) took tool 1 over ``--tool ball:6`` (a tool table wins over
the default tool), and its clamp fixture and tolerances came along. The corpus dome's
ball path, cut and looked ahead with a flat end mill, was one 1.24 mm gouge over the whole
dome, while ``dexmon simulate`` with the same flags was clean."""

from __future__ import annotations

import json
import math

import numpy as np

from monitor.cli import main

#: the analytic part: a sphere of this radius (mm) centred on the stock's bottom face
R, CX, CY = 10.0, 20.0, 20.0
BALL_R = 3.0
#: lines of the corpus dome's path run: past its first flank (line 4519)
CORPUS_LINES = 5200


def dry_run_events(capsys, tmp_path, *flags) -> tuple[int, list[dict]]:
    run = tmp_path / f"r{len(list(tmp_path.glob('r*.sqlite')))}.sqlite"
    rc = main(["dry-run", *flags, "--clock", "sim", "--speed", "20", "--json", "--run", str(run)])
    return rc, [json.loads(x) for x in capsys.readouterr().out.splitlines()]


def dome_tip_z(x: float, y: float) -> float:
    """The ball's tip on the dome's offset surface (the sphere of radius R + 3 about the
    centre, less 3), 2 um above it (no rounding dips), at least on the stock's bottom."""
    d2 = (x - CX) ** 2 + (y - CY) ** 2
    z = math.sqrt((R + BALL_R) ** 2 - d2) - BALL_R if d2 < (R + BALL_R) ** 2 else -BALL_R
    return max(z, 0.0) + 0.002


def dome_program(path, ys=(CY,)) -> None:
    """Passes along X over the dome at each of ``ys`` (a zig-zag), the tip on the ball's
    offset surface: a 6 mm ball touches the sphere and never enters it; a 6 mm flat end
    mill on the same tips cuts into its flanks, and so would a straight chord between two
    points of the path (the dome is convex)."""
    xs = np.arange(CX - 16, CX + 16.01, 0.25)
    lines = ["G21 G90 G17 G94 G54", "T1 M6", "S12000 M3", "G0 Z20", f"G0 X{xs[0]:.4f} Y{ys[0]:.4f}",
             "G1 Z0.002 F300", "F1500"]
    for k, y in enumerate(ys):
        for x in (xs if k % 2 == 0 else xs[::-1]):
            lines.append(f"G1 X{x:.4f} Y{y:.4f} Z{dome_tip_z(x, y):.4f}")
    path.write_text("\n".join(lines + ["G0 Z20", "M5", "M30"]) + "\n")


def dome_design(path) -> None:
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=4, radius=R)  # its faces lie inside the sphere
    mesh.apply_translation([CX, CY, 0.0])
    mesh.export(path)


def test_flag_job_uses_the_tool_it_names_not_the_examples_table(tmp_path, capsys):
    prog, design = tmp_path / "dome.ngc", tmp_path / "dome.stl"
    dome_program(prog)
    dome_design(design)
    flags = ["--program", str(prog), "--stock", f"box:0,0,0,{2 * CX},{2 * CY},{R + 1}", "--design", str(design),
             "--resolution", "0.5"]
    rc, events = dry_run_events(capsys, tmp_path, *flags, "--tool", "ball:6")
    found = [e for e in events if e["event"] == "finding"]
    assert [f for f in found if f["kind"] == "gouge"] == [] and events[-1]["event"] == "summary", found
    # the same path with the flat end mill the example's table names does gouge: the test
    # tells the two tools apart
    rc, events = dry_run_events(capsys, tmp_path, *flags, "--tool", "flat:6")
    assert rc == 1 and {e["kind"] for e in events if e["event"] == "finding"} >= {"gouge"}


def test_flag_job_without_a_stock_says_so(tmp_path, capsys):
    """Nothing of the example fills in what the flags leave out."""
    prog = tmp_path / "dome.ngc"
    dome_program(prog)
    assert main(["dry-run", "--program", str(prog), "--tool", "ball:6", "--quiet"]) == 2
    assert "no stock" in capsys.readouterr().err


def test_corpus_dome_dry_run_by_flags_is_clean_like_simulate(tmp_path, capsys, shared):
    """The start of the sphere_on_plate path (../shared/corpus/parts/README.md), through
    the dome's first flank where the false gouge began (line 4519), with the part's
    settings given as flags: no gouge, as ``dexmon simulate`` says."""
    parts = shared / "corpus" / "parts"
    meta = json.loads((parts / "sphere_on_plate_ball6_finish.json").read_text())
    text = (parts / "sphere_on_plate_ball6_finish.ngc").read_text().splitlines()[:CORPUS_LINES]
    prog = tmp_path / "sphere.ngc"
    prog.write_text("\n".join(text + [f"G0 Z{meta['safe_z']:.4f}", "M5", "M30"]) + "\n")
    stock = "box:" + ",".join(f"{v:g}" for v in meta["bbox"])
    rc, events = dry_run_events(capsys, tmp_path, "--program", str(prog), "--stock", stock, "--tool", "ball:6",
                                "--design", str(parts / "sphere_on_plate.stl"), "--resolution", "0.5")
    gouges = [e for e in events if e["event"] == "finding" and e["kind"] == "gouge"]
    assert gouges == [] and events[-1]["event"] == "summary", gouges[:1]
