import argparse
import json

import pytest
import trimesh

from sim.checks.report import add_check_arguments, checker_from_args, final_findings
from sim.errors import InputError
from sim.frame import Frame
from sim.gcode.moves import MoveKind
from sim.solids import box_grid
from sim.tools import parse_tool_spec
from tests.sim.checks.helpers import table

F, R = MoveKind.FEED, MoveKind.RAPID


def parse(argv):
    p = argparse.ArgumentParser()
    add_check_arguments(p)
    return p.parse_args(argv)


def grid():
    return box_grid(Frame.top(0, 0, 60, 40, 0.5), (0, 0, 0), (60, 40, 20))


def test_options_build_a_checker_whose_findings_are_json(tmp_path):
    design = tmp_path / "part.stl"
    trimesh.creation.box(bounds=[(0, 0, 0), (60, 40, 15)]).export(design)
    args = parse(["--design", str(design), "--tolerance", "0.01", "--fixture", "box:62,0,0,70,40,35",
                  "--limits", "X-20:100,Y-20:80,Z-10:60", "--max-depth-of-cut", "10"])
    ch = checker_from_args(args, grid(), parse_tool_spec("flat:6"))
    # t_h is not tied to t_l: scallop-sized by default
    assert ch.tol.gouge == 0.01 and ch.tol.undercut == 0.05
    assert checker_from_args(parse(["--undercut-tolerance", "0.2"]), grid(),
                             parse_tool_spec("flat:6")).tol.undercut == 0.2
    # a flat pass at 14.9: 0.1 mm into the 15 mm design top
    m = table([(R, (10, 20, 30), (10, 20, 25)), (F, (10, 20, 25), (10, 20, 14.9)),
               (F, (10, 20, 14.9), (50, 20, 14.9)), (R, (50, 20, 14.9), (50, 20, 30))])
    ch.cut_and_check(m)
    found = json.loads(json.dumps([f.to_json() for f in final_findings(ch)]))
    gouge = [f for f in found if f["kind"] == "gouge"]
    assert len(gouge) == 1 and gouge[0]["depth"] == pytest.approx(0.1, abs=1e-5)
    assert set(gouge[0]["lines"]) <= {20, 30} and gouge[0]["position"][2] == pytest.approx(14.9, abs=1e-4)
    # the uncut stock above the design is not assessed (only faces a move made are);
    # the pass leaves its sides 5 mm above the design: undercut on the cut faces
    assert all(f["kind"] in ("gouge", "undercut") for f in found)


@pytest.mark.parametrize("argv, where", [(["--fixture", "box:1,2,3"], "--fixture"),
                                         (["--limits", "X9:1"], "--limits"),
                                         (["--tolerance", "-1"], "--tolerance")])
def test_bad_options_name_themselves(argv, where):
    with pytest.raises(InputError, match=where):
        checker_from_args(parse(argv), grid(), parse_tool_spec("flat:6"))
