"""Setups that cannot be what the user meant, told at the start of a live run or dry run.

``simulate`` reports them first (:mod:`sim.checks.setup`): a stock the program's path never
reaches (the work offset or the units wrong: a G20 program read against a stock in mm), a
design that does not lie in the stock. A live session says the same at its start, through
the alerter, before any cutting is judged, so such a run never ends "clean". During the
run one more can show: the work offset the job gives (``work_offset = [x, y, z]``) is not
the one the controller reports (WCO) -- the job's model is then somewhere else than the
machine's work -- told once (:class:`WorkOffsetCheck`).

Each is a ``setup`` finding record (``status = "setup"``, no lead time): what looks wrong
and what to check.
"""

from __future__ import annotations

import math

import numpy as np

from sim.checks.findings import Finding

#: the reported WCO may differ from the job's work_offset by this much per axis, mm
#: (controllers report 3 decimals; a job's offset is typed from them)
WORK_OFFSET_TOLERANCE_MM = 0.01


#: tips per turning row the setup check's boxes follow (:func:`_placed_on_part`)
SETUP_SAMPLES = 8


def placed_on_part(moves, kinematics, origin, tool_lengths):
    """``moves`` (a table of tips) with every row a rotary turns replaced by the tips the
    kinematics puts on the part: :data:`SETUP_SAMPLES` straight feeds through tips at
    equal steps of its machine axes (arcs by their ends): the setup check's boxes, lenient
    as they are, then hold what the turned part or tilted tool really meets."""
    from sim.gcode.moves import MoveKind
    from sim.kinematics import ROTARY_COLUMN

    origin = np.zeros(6) if origin is None else np.asarray(origin, np.float64)
    cols = [ROTARY_COLUMN[r] for r in kinematics.rotaries]
    moving = np.isin(moves["kind"], (MoveKind.RAPID, MoveKind.FEED, MoveKind.ARC_CW, MoveKind.ARC_CCW))
    turning = moving & (((moves["start"][:, cols] + origin[cols]) != 0.0).any(axis=1)
                        | ((moves["end"][:, cols] + origin[cols]) != 0.0).any(axis=1))
    if not turning.any():
        return moves
    rows = moves[turning]
    lengths = np.array([(tool_lengths or {}).get(int(t), float(L)) for t, L in zip(rows["tool"], rows["tool_length"])])
    f = np.linspace(0.0, 1.0, SETUP_SAMPLES + 1)
    poses = rows["start"][:, None, :] + f[None, :, None] * (rows["end"] - rows["start"])[:, None, :] + origin
    poses[:, :, 2] += lengths[:, None]  # the gauge point over the tip (the row's own length is 0)
    poses[:, :, 2] -= rows["tool_length"][:, None]
    tips, _ = kinematics.forward(poses.reshape(-1, 6), np.repeat(lengths, SETUP_SAMPLES + 1))
    tips = tips.reshape(len(rows), SETUP_SAMPLES + 1, 3) - origin[:3]
    # in program order: each turning row becomes its pieces where it stood
    count = np.where(turning, SETUP_SAMPLES, 1)
    out = np.repeat(moves, count)
    placed = np.repeat(turning, count)
    out["kind"][placed] = int(MoveKind.FEED)
    out["start"][placed, :3] = tips[:, :-1].reshape(-1, 3)
    out["end"][placed, :3] = tips[:, 1:].reshape(-1, 3)
    out["tool_length"][placed] = 0.0
    return out


def setup_records(wp, moves: np.ndarray, inch: bool, t: float | None = None) -> list[dict]:
    """The ``setup`` finding records of a session's workpiece ``wp``
    (:class:`monitor.workpiece.Workpiece`) and program ``moves`` (the model frame, tips, mm):
    :func:`sim.checks.setup.setup_findings` with the stock's material box, the largest tool
    radius and the design's box. ``inch``: the program is written in inches (G20)."""
    from sim.checks.setup import design_box, material_box, setup_findings

    reach = max([t_.radius for t_ in wp.tools.values()] + [wp.default_tool.radius])
    design = design_box(wp.design) if wp.design is not None else None
    if wp.kinematics is not None:
        moves = placed_on_part(moves, wp.kinematics, wp.origin, wp.tool_lengths)
    found = setup_findings(moves, material_box(wp.stock), reach, design, inch=inch)
    return [setup_record(f, t) for f in found]


def setup_record(f: Finding, t: float | None = None) -> dict:
    """The JSON record of a setup finding: no lead time, ``status = "setup"``."""
    from monitor.predict import finding_record

    rec = finding_record(f, math.nan, t, predicted=False)
    rec["status"] = "setup"
    return rec


class WorkOffsetCheck:
    """Compares the WCO a controller reports with the job's ``work_offset``; tells the first
    difference, once.

    The reported WCO holds more than the work system's zero: G92 and the tool length offset
    (and another work system's offset while the program runs in it). So a WCO is taken as
    the job's when it is ``work_offset`` plus any offset the program itself puts on top of
    its work system (each row's WCO minus the job system's .var offset; 0 before the
    program sets any), within :data:`WORK_OFFSET_TOLERANCE_MM` per axis.

    Parameters
    ----------
    work_offset : (3,) the job's work offset, machine coords, mm.
    moves : MOVE_DTYPE (n,) the interpreter's table (``wco`` column: G5x + G92 + tool length).
    reference : (3,) or (6,) the .var offset of the job's work system, mm.
    """

    def __init__(self, work_offset, moves: np.ndarray, reference):
        self.work_offset = np.asarray(work_offset, np.float64).reshape(3)
        own = np.asarray(moves["wco"][:, :3], np.float64) - np.asarray(reference, np.float64).reshape(-1)[:3]
        self.extras = np.unique(np.concatenate([np.zeros((1, 3)), own[np.all(np.isfinite(own), axis=1)]]), axis=0)
        self.told = False

    def differs(self, wco) -> bool:
        """True when the reported ``wco`` ((3,) or more, mm) is not the job's work offset plus
        an offset of the program's own."""
        d = np.asarray(wco, np.float64).reshape(-1)[:3] - self.work_offset
        if not np.all(np.isfinite(d)):
            return False
        return not bool(np.any(np.all(np.abs(d - self.extras) <= WORK_OFFSET_TOLERANCE_MM, axis=1)))

    def see(self, state, tip) -> list[dict]:
        """The setup record for a fresh ``state`` whose WCO differs (the first time only),
        else []. ``tip`` (3,) mm: the tool tip in the job's frame, where it is told."""
        if self.told or not state.fresh or not self.differs(state.wco):
            return []
        self.told = True
        job = _xyz(self.work_offset)
        got = _xyz(state.wco)
        message = (f"setup: the controller reports work offset (WCO) {got} mm, but the job's work_offset is "
                   f"{job} mm: the job's stock, fixtures and design are not where the machine works. Check the "
                   "work offset set on the controller (its work system, G92, tool length offset) and the job's "
                   'work_offset, or take it from the controller (work_offset = "controller")')
        f = Finding("setup", position=tuple(float(v) for v in tip), message=message,
                    detail={"check": "work_offset_differs", "job_work_offset": [float(v) for v in self.work_offset],
                            "controller_wco": [float(v) for v in np.asarray(state.wco, np.float64)[:3]]})
        return [setup_record(f, state.t)]


def _xyz(v) -> str:
    x, y, z = (float(a) for a in np.asarray(v, np.float64).reshape(-1)[:3])
    return f"X{x:.3f} Y{y:.3f} Z{z:.3f}"
