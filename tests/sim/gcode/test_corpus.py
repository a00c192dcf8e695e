"""Every real program of ../shared/corpus/gcode interprets, or fails where SOURCES.md says."""

from __future__ import annotations

import numpy as np
import pytest

from sim.gcode import GCodeError, MoveKind, load_program, work_end

TABLES = {
    "linuxcnc_mmount.ngc": "linuxcnc_mmount.tbl",
    "linuxcnc_gmoccapy_2tools_ccomp.ngc": "linuxcnc_gmoccapy_2tools_ccomp.tbl",
    "linuxcnc_cam_nisley.ngc": "linuxcnc_cam_nisley.tbl",
}
DEFECTS = {  # file -> (line, N word, words in the message)
    "cncjs_circle_diamond_square.gcode": (624, "N624", "radius to end of arc differs"),
    "cncjs_full_circle_without_xyz.gcode": (11, "N55", "arc needs R or the I/J"),
}
NAMES = [
    "camotics_bear.nc", "camotics_botomata_bottom.nc", "camotics_flower_mold.nc", "camotics_genes_encoder.ngc",
    "camotics_heart.ngc", "camotics_heart_cutout.ngc", "camotics_slant_test.nc",
    "cncjs_circle_diamond_square.gcode", "cncjs_full_circle_without_xyz.gcode", "cncjs_helical_thread_milling.gcode",
    "cncjs_jsdc_jscut.gcode", "freecad_linuxcnc_imperial_ref.ngc", "linuxcnc_3D_Chips.ngc", "linuxcnc_3dtest.ngc",
    "linuxcnc_arcspiral.ngc", "linuxcnc_cam_nisley.ngc", "linuxcnc_cds.ngc", "linuxcnc_gmoccapy_2tools_ccomp.ngc",
    "linuxcnc_mmount.ngc", "linuxcnc_polar.ngc", "linuxcnc_skeleton.ngc", "linuxcnc_systems.ngc", "linuxcnc_tort.ngc",
    "ugs_arc_rword_test.gcode", "ugs_g17_g18_g19.gcode", "ugs_ordbot_handle_cambam.nc", "ugs_ruler.gcode",
    "ugs_shapeoko_calibration_pycam.ngc",
]


def _load(shared, name, **kw):
    c = shared / "corpus" / "gcode"
    return load_program(c / name, tool_table=c / "tooltables" / TABLES.get(name, "default.tbl"),
                        var_file=c / "tooltables" / "rs274_seed.var", machine_units="inch", **kw)


def test_corpus_listing_is_complete(shared):
    found = sorted(p.name for p in (shared / "corpus" / "gcode").iterdir() if p.is_file() and p.suffix != ".md")
    assert found == sorted(NAMES)


@pytest.mark.parametrize("name", NAMES)
def test_corpus_program(shared, name):
    if name in DEFECTS:
        line, nword, msg = DEFECTS[name]
        with pytest.raises(GCodeError) as info:
            _load(shared, name)
        err = info.value
        assert err.line == line and msg in err.message and nword in err.source_line
        return
    prog = _load(shared, name)
    m = prog.moves
    assert len(m) > 0
    assert np.isfinite(m["end"]).all() and np.isfinite(m["start"]).all()
    # rows chain: every move starts where the previous one ended
    np.testing.assert_allclose(m["start"][1:], m["end"][:-1], atol=1e-9)
    arcs = m[(m["kind"] == MoveKind.ARC_CW) | (m["kind"] == MoveKind.ARC_CCW)]
    if len(arcs):
        from sim.gcode.arcs import arc_rows_geometry

        r, _a, _s, axes = arc_rows_geometry(arcs)
        rows = np.arange(len(arcs))
        e1 = arcs["end"][rows, axes[:, 0]] - arcs["center"][rows, axes[:, 0]]
        e2 = arcs["end"][rows, axes[:, 1]] - arcs["center"][rows, axes[:, 1]]
        np.testing.assert_allclose(np.hypot(e1, e2), r, atol=0.0005 * 25.4 + 1e-9)


def test_defects_keep_going_list_all_and_keep_moves(shared):
    prog = _load(shared, "cncjs_full_circle_without_xyz.gcode", keep_going=True)
    assert [e.line for e in prog.errors][:1] == [11]
    assert len(prog.moves) > 0


def test_corpus_units_and_offsets(shared):
    # mmount touches off in G55 = (2, 1, 0) in from the seed .var file
    prog = _load(shared, "linuxcnc_mmount.ngc")
    assert prog.state_at(60).units == 200
    m = prog.moves
    wco_x = m["wco"][:, 0]
    assert np.isclose(wco_x, 2 * 25.4).any()        # G55 X
    assert np.isclose(wco_x, -1 * 25.4).any()       # G56 X
    # cds.ngc is inch: 4 in stock, cutter never below 0.94 in from the top at Z=2 in
    cds = _load(shared, "linuxcnc_cds.ngc").moves
    assert work_end(cds)[:, 2].min() >= (2 - 0.94) * 25.4 - 1e-6
    # G43 H1 adds T1 Z0.511 in: machine Z = work Z + 12.9794 mm
    np.testing.assert_allclose(cds["wco"][-1, 2], 0.511 * 25.4)


def test_comp_corpus_tool_radius_is_applied(shared):
    # gmoccapy: G41 with T3 (5 mm? table gives inches) on a full circle "G3 I-20" around (50, 50)
    prog = _load(shared, "linuxcnc_gmoccapy_2tools_ccomp.ngc")
    m = prog.moves
    circle = m[(m["line"] == 42)]
    assert len(circle) >= 1
    c = circle[0]
    r = np.hypot(*(c["start"][:2] - c["center"][:2]))
    from sim.tooltable import read_tool_table

    tbl = read_tool_table(shared / "corpus" / "gcode" / "tooltables" / "linuxcnc_gmoccapy_2tools_ccomp.tbl",
                          units="inch")
    # G41 on a CCW circle: tool left = inside, radius 20 - tool radius
    assert r == pytest.approx(20 - tbl[3].diameter / 2, abs=1e-6)
