"""Turning a tri-dexel model on: ``[stock] model = "tri-dexel"`` in a job or ``dexmon
simulate --tri-dexel``. On a 5-axis job (a head tilting the tool toward a thin rib) the
holder contact the Z grid cannot see is found and printed as usual; the rotary example's
planted gouge is found on it as on the Z grid; the default stays the Z grid."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from monitor.cli import main
from monitor.job import JobError, load_job, parse_job_text

ROTARY_JOB = Path(__file__).resolve().parents[2] / "monitor" / "examples" / "rotary_job" / "job.toml"

#: the T profile in the XZ plane: a 30 x 5 base plate and a 0.6 mm rib on it, up to Z25
T_PROFILE = [(0, 0), (30, 0), (30, 5), (10.8, 5), (10.8, 25), (10.2, 25), (10.2, 5), (0, 5)]

PROGRAM = """G21 G90 G94 G17
T1 M6
M3 S12000
G0 X1.5 Y-25 Z40 B-30
G0 Z4.5
G1 Y45 F600
G0 Z40
M5
M30
"""
HOLDER_LINE = 6  # the feed past the rib, the tool leaning 30 degrees toward it: its rim
# skims the base plate (to Z3.5), its shank stays 1 mm off the rib, its holder goes through it


def t_prism(path: Path) -> None:
    """The T profile extruded along Y from 0 to 20 mm, a closed STL."""
    n = len(T_PROFILE)
    verts = [(x, y, z) for y in (0.0, 20.0) for x, z in T_PROFILE]
    # caps: the rib's quad and a fan over the base's six corners (convex, two collinear);
    # the profile runs counterclockwise in X Z, so these face -Y at Y0 and, reversed, +Y at Y20
    cap = [(3, 4, 5), (3, 5, 6), (0, 1, 2), (0, 2, 3), (0, 3, 6), (0, 6, 7)]
    faces = list(cap) + [(c + n, b + n, a + n) for a, b, c in cap]
    for k in range(n):  # the walls, facing out of the profile
        a, b = k, (k + 1) % n
        faces += [(a, b + n, b), (a, a + n, b + n)]
    mesh = trimesh.Trimesh(np.array(verts, float), np.array(faces), process=True)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(30 * 5 * 20 + 0.6 * 20 * 20)
    mesh.export(str(path))


def write_job(tmp_path: Path, model_line: str = "") -> Path:
    t_prism(tmp_path / "t.stl")
    (tmp_path / "tilt.nc").write_text(PROGRAM)
    job = tmp_path / "job.toml"
    job.write_text(f"""resolution = 1.0
[program]
path = "tilt.nc"
[machine]
kinematics = "xyzbc-head"
[stock]
stl = "t.stl"
{model_line}
[tools.1]
spec = "flat:4:L=8"
shank = [4, 4]
holder = [30, 20]
""")
    return job


def simulate_json(capsys, *argv):
    code = main(["simulate", *map(str, argv), "--json"])
    return code, json.loads(capsys.readouterr().out)


def test_the_job_key_and_its_errors(tmp_path):
    job = load_job(write_job(tmp_path, 'model = "tri-dexel"'))
    assert job.stock_model == "tri-dexel"
    assert load_job(write_job(tmp_path)).stock_model == "z"
    with pytest.raises(JobError, match=r'\[stock\] model: expected "z" .* or "tri-dexel" .*, got "tri"'):
        parse_job_text('[stock]\nbox = [0, 0, 0, 1, 1, 1]\nmodel = "tri"\n')


def test_tilted_holder_through_the_rib_on_a_tri_dexel_job(tmp_path, capsys):
    job = write_job(tmp_path, 'model = "tri-dexel"')
    code, doc = simulate_json(capsys, job)
    assert code == 1 and doc["model"] == "tri-dexel"
    assert [(f["kind"], f["line"]) for f in doc["findings"]] == [("holder_contact", HOLDER_LINE)]
    assert doc["removed_mm3"] > 0
    # the same job on one Z grid (the default): its rays step over the rib, nothing is found
    plain = write_job(tmp_path)
    code, doc = simulate_json(capsys, plain)
    assert code == 0 and doc["model"] == "z" and doc["findings"] == []
    # --tri-dexel turns it on from the command line; the text report names the finding
    code = main(["simulate", str(plain), "--tri-dexel"])
    out = capsys.readouterr().out
    assert code == 1 and "tri-dexel model" in out
    assert "holder_contact" in out and "the tool holder touches material" in out


def test_the_rotary_example_on_a_tri_dexel_model(capsys):
    code, doc = simulate_json(capsys, ROTARY_JOB, "--resolution", "0.5", "--tri-dexel")
    assert code == 1 and doc["model"] == "tri-dexel"
    assert [(f["kind"], f["line"]) for f in doc["findings"]] == [("gouge", 35)]
    assert doc["findings"][0]["depth"] == pytest.approx(1.0, abs=0.02)


def test_a_program_with_stock_on_the_command_line(tmp_path, capsys):
    """No job: ``--stock box:...`` and ``--tri-dexel`` (3-axis): the same findings as the Z
    grid. The slot (5 mm deep, 6 mm wide, 20 mm between its ends' centres) is measured on
    the tri-dexel lattice's Z rays, half a spacing inside the box (TriDexel.box): within
    1 % of its true volume; the Z grid's rays lie on the slot's walls (Y7, Y13) and count
    them whole (791 mm^3)."""
    prog = tmp_path / "p.nc"
    prog.write_text("G21 G90\nM3 S10000\nG0 X10 Y10 Z30\nG0 Z15\nG1 X30 F500\nG0 Z30\nM30\n")
    args = [prog, "--stock", "box:0,0,0,40,20,20", "--tool", "flat:6:L=20", "--resolution", "0.5"]
    code_z, on_z = simulate_json(capsys, *args)
    code_t, on_t = simulate_json(capsys, *args, "--tri-dexel")
    assert code_z == code_t == 1
    assert [(f["kind"], f["line"]) for f in on_t["findings"]] == [(f["kind"], f["line"]) for f in on_z["findings"]] \
        == [("rapid_into_stock", 4)]
    slot = (20 * 6 + np.pi * 3**2) * 5
    assert on_t["removed_mm3"] == pytest.approx(slot, rel=0.01)
    assert on_z["removed_mm3"] == pytest.approx(slot, rel=0.1)
    assert on_t["lattice"][2] > 1


def test_stl_of_a_tri_dexel_model_is_its_closed_surface(tmp_path, capsys):
    """``--stl`` writes the tri-dexel model's own surface (sim.tridexel_surface, built on
    another branch of issue 16: this runs once both are merged)."""
    pytest.importorskip("sim.tridexel_surface")
    job = write_job(tmp_path, 'model = "tri-dexel"')
    out = tmp_path / "cut.stl"
    code, doc = simulate_json(capsys, job, "--stl", out)
    assert code == 1 and doc["stl"] == str(out)
    mesh = trimesh.load(str(out), force="mesh")
    assert mesh.is_watertight
    # the base plate (the 0.6 mm rib is thinner than the 1 mm lattice: no node holds it)
    assert mesh.bounds[0] == pytest.approx([0.0, 0.0, 0.0], abs=1.0)
    assert mesh.bounds[1][:2] == pytest.approx([30.0, 20.0], abs=1.0)


@pytest.mark.parametrize("model", ["z", "tri-dexel"])
def test_png_pictures_the_cut_stock_coloured_by_move(tmp_path, capsys, model):
    """``--png`` draws the cut stock offscreen, faces coloured by move: the slot's move
    colour is in the picture (a Z grid's column surface, a tri-dexel model's own)."""
    pytest.importorskip("pyvista")
    from monitor.render.shaded import id_palette
    from tests.monitor.render.imagecheck import hue_shares
    from tests.monitor.render.test_view3d import _hue_bin

    prog = tmp_path / "p.nc"
    prog.write_text("G21 G90\nM3 S10000\nG0 X-5 Y10 Z30\nG0 Z15\nG1 X45 F500\nG0 Z30\nM30\n")
    out = tmp_path / "cut.png"
    args = [prog, "--stock", "box:0,0,0,40,20,20", "--tool", "flat:6:L=20", "--resolution", "0.5",
            "--png", out] + (["--tri-dexel"] if model == "tri-dexel" else [])
    code, doc = simulate_json(capsys, *args)
    assert code == 0 and doc["png"] == str(out)
    import imageio.v3 as iio

    img = iio.imread(out)[..., :3]
    assert img.std() > 10
    shares = hue_shares(img)
    b = _hue_bin(id_palette()[3])     # the slot: move 3 (to the first point, down, the feed)
    assert shares[[(b - 1) % 36, b, (b + 1) % 36]].sum() > 0.05


BOX = (0.0, 0.0, 0.0, 20.0, 10.0, 5.0)


def box_job(tmp_path: Path, program: str) -> Path:
    (tmp_path / "p.nc").write_text(program)
    job = tmp_path / "job.toml"
    job.write_text(f'resolution = 0.5\n[program]\npath = "p.nc"\n[stock]\nbox = {list(BOX)}\nmodel = "tri-dexel"\n'
                   '[tools]\n1 = "flat:6:L=20"\n')
    return job


@pytest.mark.parametrize("given", ["job", "command line"])
def test_a_rapid_along_the_top_face_of_a_box_stock_removes_nothing(tmp_path, capsys, given):
    """A rapid at the stock's top (Z5, touching it) cuts nothing, on the Z grid as on the
    X and Y grids: no ray of the lattice lies in a face of the box (TriDexel.box's nodes,
    half a spacing inside it). With nodes on the faces the X and Y rays in the top face
    were cut by the tool's end: a rapid into stock of 61.5 mm^3."""
    program = "G21 G90\nT1 M6\nM3 S10000\nG0 X-10 Y5 Z30\nG0 Z5\nG0 X30\nG0 Z30\nM30\n"
    job = box_job(tmp_path, program)
    if given == "job":
        code, doc = simulate_json(capsys, job)
    else:
        code, doc = simulate_json(capsys, tmp_path / "p.nc", "--stock", "box:" + ",".join(f"{v:g}" for v in BOX),
                                  "--tool", "flat:6:L=20", "--resolution", "0.5", "--tri-dexel")
    assert code == 0 and doc["model"] == "tri-dexel"
    assert doc["findings"] == [] and doc["removed_by_rapids_mm3"] == 0.0 and doc["removed_mm3"] == 0.0


def test_a_jobs_box_stock_is_the_box_on_all_three_grids(tmp_path):
    """The job's tri-dexel box stock is what TriDexel.box gives for it, on a lattice
    covering the job's frame: each grid holds the box's volume (20 x 10 x 5 mm, whole
    spacings) and its segments, face ids included, on the rays both lattices share."""
    from monitor.workpiece import build_workpiece
    from sim.gcode.program import interpret
    from sim.tridexel import TriDexel

    stock = build_workpiece(load_job(box_job(tmp_path, "")), interpret("T1 M6\nG0 Z30\n").moves, "tri-dexel").stock
    assert stock.volumes() == pytest.approx({"x": 1000.0, "y": 1000.0, "z": 1000.0}, abs=1e-9)
    box = TriDexel.box(BOX[:3], BOX[3:], 0.5)
    shift = (box.lo - stock.lo) / 0.5
    assert np.allclose(shift, np.rint(shift)) and (shift >= 0).all()
    assert (np.array(stock.shape) >= np.rint(shift) + box.shape).all()
    # every ray of the job's lattice holds what the box's ray there holds (none outside it)
    i, j, k = (int(v) for v in np.rint(shift))
    offsets = {"z": (i, j), "x": (j, k), "y": (k, i)}  # (u, v) of each grid's frame
    for a, (du, dv) in offsets.items():
        mine, ref = stock.grids[a], box.grids[a]
        for v in range(mine.frame.nv):
            for u in range(mine.frame.nu):
                inside = 0 <= u - du < ref.frame.nu and 0 <= v - dv < ref.frame.nv
                got = (mine.segments(u, v), mine.face_ids(u, v))
                want = (ref.segments(u - du, v - dv), ref.face_ids(u - du, v - dv)) if inside else None
                if want is None:
                    assert got[0].size == 0, (a, u, v)
                else:
                    assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1]), (a, u, v)
