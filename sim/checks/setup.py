"""Setups that cannot be what the user meant, found before any cutting is judged.

A stock the program never reaches, or a design that does not lie in the stock, makes every
later check meaningless: the simulation "finds nothing" because nothing meets. Each is
reported as one ``setup`` finding saying what looks wrong and what to check (the work
offset or work system, the stock's position, the units), so such a run is never "clean".

The tests are on boxes: conservative (a box overlap that is not a real touch passes), so
a setup finding is never raised for a path that does cut the stock.
"""

from __future__ import annotations

import numpy as np

from sim.checks.findings import Finding
from sim.gcode.arcs import arc_rows_geometry
from sim.gcode.linearize import arc_points
from sim.gcode.moves import INCH, MoveKind, tip_positions

_CUTTING = (MoveKind.FEED, MoveKind.ARC_CW, MoveKind.ARC_CCW)


def material_box(grid) -> tuple[np.ndarray, np.ndarray] | None:
    """``(lo (3,), hi (3,))`` mm of the material in dexel grid ``grid`` (a top frame):
    the XY extent of the rays that hold material and the Z of the highest top; None when
    the grid is empty. ``lo[2]`` is ``-inf``: below the top, any depth counts as inside."""
    top = grid.top()
    has = np.isfinite(top)
    if not has.any():
        return None
    f = grid.frame
    jj, ii = np.nonzero(has)
    lo = f.origin + np.array([ii.min() * f.spacing, jj.min() * f.spacing, 0.0])
    hi = f.origin + np.array([ii.max() * f.spacing, jj.max() * f.spacing, 0.0])
    lo[2], hi[2] = -np.inf, float(np.nanmax(top)) + f.origin[2]
    return lo, hi


def path_boxes(moves: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(lo (k, 3), hi (k, 3))`` mm: the box of the tool tip's path on each row of
    ``moves[rows]``: its start and end, and for an arc the points where it reaches furthest
    along its plane's axes (the quarter angles its sweep passes). The tip, not the
    controlled point: G43's length is taken off Z, so a long tool's path is where it cuts."""
    sel = moves[rows]
    a, b = sel["start"][:, :3].copy(), sel["end"][:, :3].copy()
    a[:, 2] -= sel["tool_length"]
    b[:, 2] -= sel["tool_length"]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    arc = np.flatnonzero(np.isin(sel["kind"], (MoveKind.ARC_CW, MoveKind.ARC_CCW)))
    if arc.size:
        _, a0, sweep, _ = arc_rows_geometry(sel[arc])
        # t (in 0..1) at which each arc passes angle 0, 90, 180 and 270 deg: the first time
        # its angle a0 + t * sweep comes round to it
        quarter = np.arange(4) * (np.pi / 2)
        t = np.mod((quarter[None, :] - a0[:, None]) * np.sign(sweep)[:, None], 2 * np.pi) / np.abs(sweep)[:, None]
        src, which = np.nonzero(t <= 1.0)
        if src.size:
            pts = arc_points(sel[arc], t[src, which], src)[:, :3]
            pts[:, 2] -= sel["tool_length"][arc[src]]
            np.minimum.at(lo, arc[src], pts)
            np.maximum.at(hi, arc[src], pts)
    return lo, hi


def cutting_boxes(moves: np.ndarray, reach: float, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Boxes the tool can touch on the program's cutting rows (feeds and arcs).

    Returns ``(rows (k,), lo (k, 3), hi (k, 3))`` mm: each row's tip path
    (:func:`path_boxes`), widened by ``reach`` (the largest tool radius) in X and Y and
    open upwards (the tool stands above its tip). ``scale`` multiplies the program's
    coordinates first (25.4: the program read as inches)."""
    rows = np.flatnonzero(np.isin(moves["kind"], _CUTTING))
    lo, hi = path_boxes(moves, rows)
    lo, hi = lo * scale, hi * scale
    lo[:, :2] -= reach
    hi[:, :2] += reach
    hi[:, 2] = np.inf
    return rows, lo, hi


def _overlaps(lo, hi, box_lo, box_hi) -> np.ndarray:
    return np.all((lo <= box_hi) & (hi >= box_lo), axis=-1)


def _span(lo, hi) -> str:
    return " ".join(f"{a}{l:.6g}..{h:.6g}" for a, l, h in zip("XYZ", lo, hi) if np.isfinite(l) and np.isfinite(h))


def setup_findings(moves: np.ndarray, stock_box, reach: float, design_box=None,
                   inch: bool = False) -> list[Finding]:
    """``setup`` findings of a job (see the module docstring).

    Parameters
    ----------
    moves : MOVE_DTYPE (n,) in the model frame (the job's work coordinates), mm.
    stock_box : (lo (3,), hi (3,)) mm of the stock (:func:`material_box`), or None.
    reach : float, mm, the largest tool radius.
    design_box : (lo (3,), hi (3,)) mm of the design model, or None.
    inch : the program is written in inches (G20): the units are worth a word.
    """
    out: list[Finding] = []
    if stock_box is None:
        return out
    s_lo, s_hi = (np.asarray(v, np.float64) for v in stock_box)
    rows, lo, hi = cutting_boxes(moves, reach)
    if rows.size and not _overlaps(lo, hi, s_lo, s_hi).any():
        p_lo, p_hi = path_boxes(moves, rows)
        p_lo, p_hi = p_lo.min(axis=0), p_hi.max(axis=0)
        hint = "check the work offset / work system the stock is in, the stock's position and its units"
        if inch:
            hint = ("the program is in inches (G20) and dexmon reads it in mm; is the stock given in mm? "
                    + hint)
        elif _overlaps(*cutting_boxes(moves, reach, INCH)[1:], s_lo, s_hi).any():
            hint = "the stock would be cut if the program were in inches (G20 missing?); " + hint
        first = int(moves["line"][rows[0]])
        out.append(Finding("setup", line=first, lines=(first,), position=tuple(tip_positions(moves[rows[:1]])[0]),
                           message=f"setup: the program's cutting moves never reach the stock (they span "
                                   f"{_span(p_lo, p_hi)} mm; the stock {_span(s_lo, s_hi)} mm): {hint}",
                           detail={"check": "path_misses_stock"}))
    if design_box is not None:
        d_lo, d_hi = (np.asarray(v, np.float64) for v in design_box)
        if not _overlaps(d_lo, d_hi, s_lo, s_hi):
            out.append(Finding("setup", position=tuple((d_lo + d_hi) / 2),
                               message=f"setup: the design ({_span(d_lo, d_hi)} mm) does not lie in the stock "
                                       f"({_span(s_lo, s_hi)} mm): check the design's offset, its units and "
                                       "the work system",
                               detail={"check": "design_outside_stock"}))
    return out


def design_box(design) -> tuple[np.ndarray, np.ndarray]:
    """``(lo (3,), hi (3,))`` mm of a :class:`sim.checks.error_map.DesignModel` (its
    triangles, placed)."""
    f = design.frame
    lo = f.to_world(design.tri_lo.min(axis=0))
    hi = f.to_world(design.tri_hi.max(axis=0))
    return np.minimum(lo, hi), np.maximum(lo, hi)
