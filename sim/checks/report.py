"""The checks as command-line options (``dexmon simulate ... --design part.stl``)."""

from __future__ import annotations

import numpy as np

from sim.errors import InputError
from sim.tolerance import DEFAULT, Tolerance


def add_check_arguments(parser) -> None:
    """The options block of the checks."""
    g = parser.add_argument_group("checks")
    g.add_argument("--design", default=None, metavar="PART.stl",
                   help="design part (STL/OBJ, same coordinates as the stock): report gouge and undercut")
    g.add_argument("--tolerance", type=float, default=None, metavar="MM",
                   help=f"gouge tolerance t_l in mm (default {DEFAULT.gouge:g})")
    g.add_argument("--undercut-tolerance", type=float, default=None, metavar="MM",
                   help=f"undercut tolerance t_h in mm (default: {DEFAULT.undercut:g}, or the scallop a "
                        f"ball-end finishing raster leaves at its stepover on the part's slope where that "
                        f"is higher; not tied to --tolerance); material left more than the range "
                        f"of interest ({DEFAULT.interest:g} mm) from the part is not an undercut")
    g.add_argument("--fixture", action="append", default=[], metavar="box:X0,Y0,Z0,X1,Y1,Z1",
                   help="a fixture the tool must never enter (repeatable)")
    g.add_argument("--limits", default=None, metavar="X0:300,Y0:200,Z-100:0",
                   help="machine travel limits of the controlled point (machine coords)")
    g.add_argument("--max-depth-of-cut", type=float, default=None, metavar="MM",
                   help="report moves cutting deeper than this along the tool axis")


def _positive(value, name):
    if value is None:
        return None
    if not (np.isfinite(value) and value > 0):
        raise InputError(f"must be a positive length in mm, got {value}", where=name)
    return float(value)


def checker_from_args(args, grid, tool, tools=None):
    """A :class:`~sim.checks.Checker` for the options in ``args``."""
    from sim.checks.checker import Checker
    from sim.checks.collisions import Fixture
    from sim.checks.travel import parse_limits
    from sim.checks.tri import z_part

    t_l = _positive(getattr(args, "tolerance", None), "--tolerance")
    t_h = _positive(getattr(args, "undercut_tolerance", None), "--undercut-tolerance")
    tol = Tolerance(gouge=t_l or DEFAULT.gouge, undercut=t_h or DEFAULT.undercut)
    fixtures = []
    for k, spec in enumerate(getattr(args, "fixture", []) or []):
        text = spec.strip()
        try:
            assert text.lower().startswith("box:")
            vals = [float(v) for v in text[4:].split(",")]
            assert len(vals) == 6
        except (AssertionError, ValueError):
            raise InputError(f"bad fixture {spec!r}: expected box:X0,Y0,Z0,X1,Y1,Z1 (mm)",
                             where="--fixture") from None
        fixtures.append(Fixture.box(vals[:3], vals[3:], z_part(grid).frame.spacing, name=f"#{k + 1}"))
    limits = parse_limits(args.limits) if getattr(args, "limits", None) else None
    return Checker(grid, tool, design=getattr(args, "design", None), fixtures=fixtures, limits=limits,
                   tol=tol, tools=tools or None, undercut_from_path=t_h is None,
                   max_depth_of_cut=_positive(getattr(args, "max_depth_of_cut", None), "--max-depth-of-cut"))


def final_findings(checker) -> list:
    """Everything found while cutting plus the whole-model assessment, merged (cutting-time
    gouges are replaced by the whole-model gouge regions when there is a design)."""
    from sim.checks.findings import KINDS

    from sim.checks.findings import group_passes

    # hits of one kind repeating on consecutive passes over one place are one finding
    reach = 2.0 * max([checker.tool.diameter] + [t.diameter for t in checker.tools.values()])
    during = group_passes(checker.all_findings(), reach)
    if checker.design is None:
        return during
    model = checker.assess_model()
    # the model's regions come from one 8-connected labelling: separate regions stay
    # separate even when the same passes made them
    out = [f for f in during if f.kind not in ("gouge", "undercut")] + model
    out.sort(key=lambda f: (f.stages[0] if f.stages else f.stage, KINDS.index(f.kind)))
    return out
