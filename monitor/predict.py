"""Checks for the session, all through :class:`sim.checks.Checker` (one piece of check logic).

Everything here is in the job's *work coordinates*: those of the job's work system
(G54 unless ``[program] work_system`` says otherwise), in which stock, fixtures and design
are written. The move table is turned into a table of tool tips in that frame,
``tip_machine - reference_wco`` (:func:`work_moves`, :func:`reference_wco`), so the
stations of a multi-fixture program (G55, G56 ... from a .var file) land where their
offsets put them relative to the job's system; the dexel frame covers stock and fixtures. Travel limits are machine coordinates of the controlled point; they are
shifted into work coordinates by the work offset in force (:func:`limits_in_work`) and the
findings shifted back (:func:`finding_to_machine`).

Two thin adapters around ``Checker``:

* :class:`Lookahead` keeps a *scratch* model, a copy of the live stock taken when the
  session anchors, and a ``Checker`` on it; program rows ahead of the spindle are cut and
  checked onto it *once each* (``Checker.cut_and_check``) as the horizon reaches them,
  a bounded amount of work per state (:attr:`Lookahead.budget_rays`) so a horizon that
  crosses many rows at once does not stall one poll. The live model is never touched.
* :class:`LiveChecks` keeps a ``Checker`` on the *live* model: the path the tool really
  travelled is turned into move rows (:func:`travel_rows`) and cut and checked with it,
  so gouges, rapids into stock, shank/holder contact, fixtures, a stopped spindle and
  limits are found on the real motion too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from monitor.job import Job, JobError, Solid, work_system_index
from monitor.sync import ProgramPath
from sim.checks.arrays import distinct
from sim.checks.findings import Finding
from sim.errors import InputError
from sim.frame import Frame
from sim.gcode.moves import MOVE_DTYPE, MoveKind, Plane, as_move_table, work_end, work_start
from sim.grid import DexelGrid
from sim.tolerance import Tolerance

#: removed / touched volume below this is numerical noise, mm^3
MIN_VOLUME = 1e-3
#: look-ahead work allowed per state, in swept rays (about 2-3 ms on one core)
BUDGET_RAYS = 60_000
#: row shifts below this are rounding of summed offsets, mm
SHIFT_EPS = 1e-9
#: fixed cost of one look-ahead row, in swept-ray equivalents
ROW_OVERHEAD_RAYS = 400


def work_moves(moves: np.ndarray, reference_wco=None) -> np.ndarray:
    """A copy of a move table with ``start/end`` replaced by tip positions in one work frame.

    ``reference_wco`` (6,) mm: the offset (machine - work) of the job's work system
    (:func:`reference_wco`); each row's tip is placed at ``tip_machine - reference_wco``, so
    a G55 row lands at its G55 offset relative to G54 and G92 shifts stay where they put
    the tool. None: each row in its *own* work system (``end - wco``, every fixture of a
    multi-fixture program at work zero) -- what the controller reports as work position.
    ``tool_length`` becomes 0 (the table is the tip's), arc centres move with their row and
    ``wco`` becomes 0. Tables written before the ``wco`` column (old run files) are
    converted first.
    """
    moves = as_move_table(moves)
    out = moves.copy()
    shift = -np.asarray(moves["wco"][:, :3], np.float64)
    shift[:, 2] += moves["tool_length"]  # machine Z of the controlled point = tip + length
    out["start"] = work_start(moves)
    out["end"] = work_end(moves)
    out["center"] = moves["center"] + shift
    if reference_wco is not None:
        rs = row_shifts(moves, reference_wco)
        moved = np.any(rs != 0.0, axis=1)
        if moved.any():  # a single-system program stays bit for bit what it was
            out["start"][moved, :3] += rs[moved]
            out["end"][moved, :3] += rs[moved]
            out["center"][moved] += rs[moved]
    out["tool_length"] = 0.0
    out["wco"] = 0.0
    return out


def reference_wco(job: Job) -> np.ndarray:
    """The interpreter's offset (machine - work, (6,) mm) of the job's work system at the
    program start: its G5x entry from the job's .var file (in the job's machine units);
    zeros without a var file (the interpreter's offsets all start at 0)."""
    from sim.gcode import Interpreter
    from sim.gcode.varfile import read_var_file

    out = np.zeros(6)
    if job.var_file is None:
        return out
    try:
        params = read_var_file(job.var_file)
        it = Interpreter(dialect=job.dialect, machine_units=job.machine_units, var_params=params,
                         filename=str(job.var_file))
    except InputError as exc:
        raise JobError(f"[program] var: {exc}", str(job.source or "command line")) from None
    out[:] = it.g5x[work_system_index(job.work_system)]
    return out


def row_shifts(moves: np.ndarray, reference) -> np.ndarray:
    """Per row, what moves a tip from the row's *own* work coordinates (what a controller
    reports as work position) into the job's frame, float64 (n, 3) mm:
    ``wco - tool length - reference_wco`` (0 for a row in the job's work system, no G92)."""
    moves = as_move_table(moves)
    out = np.asarray(moves["wco"][:, :3], np.float64) - np.asarray(reference, np.float64).reshape(-1)[:3]
    out[:, 2] -= moves["tool_length"]
    # offsets summed in another order differ in the last bit: that is no shift
    out[np.abs(out) < SHIFT_EPS] = 0.0
    return out


def machine_moves(moves_work: np.ndarray, wco) -> np.ndarray:
    """Controlled-point machine coordinates for travel limits: work tip + ``wco`` (6,) mm.

    ``wco`` is the controller's work coordinate offset (G5x + G92 + tool length offset).
    """
    out = moves_work.copy()
    w = np.asarray(wco, np.float64).reshape(-1)[:6]
    w6 = np.zeros(6)
    w6[:w.size] = w
    out["start"] = moves_work["start"] + w6
    out["end"] = moves_work["end"] + w6
    out["center"] = moves_work["center"] + w6[:3]
    return out


# --- the workpiece ------------------------------------------------------------------------

def _load_mesh(solid: Solid, what: str):
    from sim.solids import load_mesh

    mesh, _ = load_mesh(solid.stl)
    mesh = mesh.copy()
    mesh.apply_translation(solid.offset)
    return mesh


def _bounds(solid: Solid, what: str):
    b = solid.bounds()
    if b is not None:
        return np.array(b[0], float), np.array(b[1], float), None
    mesh = _load_mesh(solid, what)
    return np.asarray(mesh.bounds[0], float), np.asarray(mesh.bounds[1], float), mesh


def _solid_grid(frame: Frame, solid: Solid, mesh, tol: Tolerance) -> DexelGrid:
    from sim import solids

    if solid.kind == "box":
        lo, hi = solid.bounds()
        return solids.box_grid(frame, lo, hi, tol=tol)
    if solid.kind == "cylinder":
        base, direction, r, h = solid.cylinder_placement()
        return solids.cylinder_grid(frame, base, direction, r, h, tol=tol)
    return solids.mesh_grid(frame, mesh, tol=tol)


def build_tools(job: Job, tool_numbers) -> tuple[dict[int, object], object]:
    """``({tool number: sim.tools.Tool}, default Tool)`` for the numbers the program uses.

    Inline ``[tools]`` entries win over the tool table; numbers in neither take the
    job's default tool. Raises :class:`JobError` naming the tool that is missing.
    """
    from sim.tools import Body, parse_tool_spec, with_bodies
    from sim.tooltable import read_tool_table, tool_from_entry

    table = read_tool_table(job.tool_table, job.machine_units) if job.tool_table else {}
    where = str(job.source or "command line")

    def make(td):
        try:
            tool = parse_tool_spec(td.spec, job.tolerance)
        except InputError as exc:
            raise JobError(f"tool {td.number}: {exc}", where) from None
        if td.shank or td.holder:
            shank = Body.cylinder("shank", td.shank[0], tool.flute_length, td.shank[1]) if td.shank else tool.shank
            base = shank.top if shank is not None else tool.flute_length
            holder = Body.cylinder("holder", td.holder[0], base, td.holder[1]) if td.holder else tool.holder
            tool = with_bodies(tool, shank, holder)
        return tool

    tools = {}
    for n in sorted({int(x) for x in tool_numbers}):
        td = job.tools.get(n)
        if td is not None:
            tools[n] = make(td)
        elif n in table:
            tools[n] = tool_from_entry(table[n])
        elif job.default_tool is not None:
            tools[n] = make(job.default_tool)
    default = make(job.default_tool) if job.default_tool is not None else (
        next(iter(tools.values()), None))
    if default is None:
        raise JobError("no tool for this program: give [tools] (or a tool table) or --tool", where)
    missing = sorted(set(int(x) for x in tool_numbers) - set(tools) - {0})
    if missing:
        raise JobError(f"tool T{missing[0]} is used by the program but not in [tools] or the tool table",
                       where)
    return tools, default


@dataclass
class Workpiece:
    """Live stock model, fixtures and design on one top frame, in work coordinates (mm)."""

    frame: Frame
    stock: DexelGrid  # or a sim.tridexel.TriDexel (build_workpiece's model="tri-dexel"); frame is its Z grid's
    fixtures: list  # [sim.checks.collisions.Fixture], each on its own frame
    design: object | None  # sim.checks.error_map.DesignModel
    tools: dict
    default_tool: object
    tol: Tolerance
    fixture_names: list[str] = field(default_factory=list)
    #: the machine's kinematics (None: 3-axis) and the machine pose (6,) of the work frame's
    #: origin (the job's reference work offset): rows with rotation are cut on the turned part
    kinematics: object | None = None
    origin: np.ndarray | None = None
    #: {tool number: mm} the G43 length a turning head places each tool by (None: no
    #: head turns a tool): the work tables hold tips, their tool_length column is 0
    tool_lengths: dict | None = None

    def tool(self, number: int):
        return self.tools.get(int(number), self.default_tool)


#: the stock model a job may need at most (MB) unless the command says otherwise
#: (``simulate --memory-limit``): past it numpy would fail mid-allocation, or the OS kill
#: the process, long after the job was read
MEMORY_LIMIT_MB = 4096.0


def check_stock_memory(job: Job, frame: Frame, model: str = "z", stock_mesh=None,
                       limit_mb: float = MEMORY_LIMIT_MB,
                       hint: str = "use a coarser resolution or a smaller stock") -> None:
    """Refuse (JobError) a stock model on ``frame`` (``model`` "tri-dexel": its three
    grids on :func:`tri_lattice`) needing more than ``limit_mb``, before anything of it
    is allocated: every command that builds a job's workpiece says the same."""
    from sim.tridexel import lattice_shape

    rays = frame.n_rays
    if model == "tri-dexel":
        nx, ny, nz = lattice_shape(*tri_lattice(frame, job, stock_mesh), frame.spacing)
        rays = nx * ny + ny * nz + nz * nx
    need = DexelGrid.estimate_bytes(rays)
    if need > limit_mb * 2**20:
        raise JobError(f"the job's dexel grid needs about {need / 2**20:.0f} MB, over the {limit_mb:.0f} MB "
                       f"limit ({frame.nu} x {frame.nv} rays {frame.spacing:g} mm apart); {hint}",
                       str(job.source or "command line"))


def build_workpiece(job: Job, moves: np.ndarray, model: str = "z", memory_limit_mb: float = MEMORY_LIMIT_MB,
                    memory_hint: str | None = None) -> Workpiece:
    """Stock, fixtures and design of ``job`` as dexel models on a frame covering them all.

    ``moves``: the program's move table in machine coordinates (the interpreter's): on a
    machine whose head turns the tool its ``tool_length`` column gives each tool's G43
    length (:func:`head_tool_lengths`). ``model``: the stock as one Z grid (``"z"``, what
    the live session follows) or as a tri-dexel model (``"tri-dexel"``,
    :class:`sim.tridexel.TriDexel`, ``simulate`` with ``[stock] model``): its lattice
    (:func:`tri_lattice`, nodes half a spacing inside the stock) covers the frame, and
    its Z grid's rays are then the frame the design and the checks use. A model needing
    more than ``memory_limit_mb`` is refused (:func:`check_stock_memory`, ``memory_hint``
    saying what to change)."""
    from sim.checks.collisions import Fixture
    from sim.checks.error_map import DesignModel
    from sim.kinematics import head_only

    if job.stock is None:
        raise JobError("no stock: give [stock] in the job file or --stock", str(job.source or "command line"))
    tools, default = build_tools(job, np.unique(moves["tool"]) if len(moves) else [])
    reach = max([t.radius for t in tools.values()] + [default.radius])
    for t in list(tools.values()) + [default]:
        for b in (t.shank, t.holder):
            if b is not None:
                reach = max(reach, b.max_radius)
    lo, hi, stock_mesh = _bounds(job.stock, "[stock]")
    fixture_meshes = []
    for f in job.fixtures:
        flo, fhi, fm = _bounds(f, "[[fixtures]]")
        lo, hi = np.minimum(lo, flo), np.maximum(hi, fhi)
        fixture_meshes.append(fm)
    margin = reach + 2 * job.resolution
    frame = Frame.top(lo[0] - margin, lo[1] - margin, hi[0] + margin, hi[1] + margin, job.resolution)
    check_stock_memory(job, frame, model, stock_mesh, memory_limit_mb,
                       **({"hint": memory_hint} if memory_hint else {}))
    if model == "tri-dexel":
        stock = _tri_stock(frame, job, stock_mesh)
        frame = stock.grids["z"].frame  # the design's and the checks' rays are the model's
    else:
        stock = _solid_grid(frame, job.stock, stock_mesh, job.tolerance)
    names = [f.name or f"fixture {k + 1}" for k, f in enumerate(job.fixtures)]
    rotary = job.kinematics if job.kinematics.rotaries else None
    origin = work_origin(job) if rotary is not None else None
    lengths = head_tool_lengths(rotary, moves, str(job.source or "command line")) \
        if rotary is not None and rotary.head else None
    fixed = head_only(rotary) if rotary is not None else None  # what a fixture bolted to the machine sees
    fixtures = [Fixture(name, _fixture_grid(f, fm, job.resolution, reach, job.tolerance),
                        kinematics=rotary if job.fixture_on_table(f) else fixed, origin=origin,
                        tool_lengths=lengths)
                for f, fm, name in zip(job.fixtures, fixture_meshes, names)]
    design = None
    if job.design is not None:
        if job.design.kind == "stl":
            design = DesignModel(frame, job.design.stl, offset=job.design.offset, name=str(job.design.stl))
        else:
            import trimesh

            blo, bhi = job.design.bounds()
            mesh = trimesh.creation.box(bounds=[blo, bhi])
            design = DesignModel(frame, mesh, name="design box")
    return Workpiece(frame, stock, fixtures, design, tools, default, job.tolerance, names,
                     kinematics=rotary, origin=origin, tool_lengths=lengths)


def head_tool_lengths(kinematics, moves: np.ndarray, where: str) -> dict[int, float]:
    """{tool number: mm} the G43 length in force on each tool's motion rows that a head
    axis tilts (its machine angle not 0 at an end): the
    pivot-to-tip distance of a turning head holds it, and the work tables that are cut
    hold tips (tool_length 0). ``moves``: the machine table. One tool tilted with two
    lengths (a G43 changed while tilted) raises JobError naming its lines."""
    from sim.kinematics import ROTARY_COLUMN

    cols = [ROTARY_COLUMN[ax.letter] for ax in kinematics.head]
    moving = np.isin(moves["kind"], (MoveKind.RAPID, MoveKind.FEED, MoveKind.ARC_CW, MoveKind.ARC_CCW))
    tilted = moving & ((moves["start"][:, cols] != 0.0).any(axis=1) | (moves["end"][:, cols] != 0.0).any(axis=1))
    out: dict[int, float] = {}
    for tool in np.unique(moves["tool"][tilted]):
        rows = np.nonzero(tilted & (moves["tool"] == tool))[0]
        lengths = np.unique(moves["tool_length"][rows])
        if lengths.size > 1:
            lines = [int(moves["line"][rows[np.nonzero(moves["tool_length"][rows] == v)[0][0]]]) for v in lengths[:2]]
            raise JobError(f"T{int(tool)} is tilted by the head with two tool lengths, {lengths[0]:g} mm "
                           f"(line {lines[0]}) and {lengths[1]:g} mm (line {lines[1]}); dexmon places a tilted "
                           "tool by one G43 length per tool", where)
        out[int(tool)] = float(lengths[0])
    return out


def tri_lattice(frame: Frame, job: Job, stock_mesh=None) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` (3,) mm: the first and last node of the tri-dexel lattice of ``job``'s
    stock, :func:`sim.tridexel.stock_lattice`'s (as ``TriDexel.box`` and ``.mesh`` lay
    it: nodes half a spacing inside the stock's lowest corner, no ray on a face of a box),
    covering ``frame``'s rectangle and the stock's height grown by two spacings."""
    from sim.tridexel import stock_lattice

    slo, shi, _ = _bounds(job.stock, "[stock]") if stock_mesh is None else (
        stock_mesh.bounds[0], stock_mesh.bounds[1], None)
    slo, shi = np.asarray(slo, np.float64), np.asarray(shi, np.float64)
    f = frame
    corner = f.origin + np.array([(f.nu - 1) * f.spacing, (f.nv - 1) * f.spacing, 0.0])
    cover = (np.array([f.origin[0], f.origin[1], slo[2]]), np.array([corner[0], corner[1], shi[2]]))
    return stock_lattice(slo, shi, f.spacing, 2 * f.spacing, cover)


def _tri_stock(frame: Frame, job: Job, stock_mesh):
    """The job's stock as a tri-dexel model on :func:`tri_lattice` (its Z grid covers
    ``frame``'s rectangle, half a spacing off it: the model's Z frame replaces it)."""
    from sim.tridexel import TriDexel

    lo, hi = tri_lattice(frame, job, stock_mesh)
    return TriDexel.build(lo, hi, frame.spacing, lambda f: _solid_grid(f, job.stock, stock_mesh, job.tolerance))


def work_origin(job: Job) -> np.ndarray:
    """Machine X Y Z (mm) A B C (deg) of the job's work zero, (6,): the job's
    ``work_offset`` when it gives one, else its .var file's (zeros without one). The
    kinematics' points (``rot_point``) are machine coordinates; this places the model."""
    out = reference_wco(job)
    if job.work_offset is not None:
        out[:3] = job.work_offset
    return out


def _fixture_grid(solid: Solid, mesh, spacing: float, reach: float, tol: Tolerance) -> DexelGrid:
    """A fixture on its own top frame (its XY box grown by ``reach``): small, so probing a
    move against it costs little wherever the stock frame is."""
    lo, hi, _ = _bounds(solid, "[[fixtures]]") if mesh is None else (mesh.bounds[0], mesh.bounds[1], None)
    m = reach + 2 * spacing
    frame = Frame.top(lo[0] - m, lo[1] - m, hi[0] + m, hi[1] + m, spacing)
    return _solid_grid(frame, solid, mesh, tol)


# --- machine <-> work coordinates for travel limits --------------------------------------

_AXES = "XYZABC"


def limits_in_work(limits: dict | None, wco) -> dict | None:
    """Travel limits of the controlled point (machine coords) as limits of the work tip.

    ``limits``: {axis: (lo, hi)} mm/deg; ``wco`` (6,) the offset in force (G5x + G92 +
    tool length): machine = work + wco, so each bound moves by ``-wco`` of its axis.
    """
    if not limits:
        return None
    w = np.zeros(6)
    v = np.asarray(wco, np.float64).reshape(-1)[:6]
    w[:v.size] = v
    out = {}
    for axis, (lo, hi) in limits.items():
        k = _AXES.index(axis.upper())
        out[axis.upper()] = (float(lo) - w[k], float(hi) - w[k])
    return out


def finding_to_machine(f: Finding, wco) -> Finding:
    """A ``travel_limit`` finding from work-coordinate checks, told in machine coordinates
    (position, limit and message); other kinds are returned unchanged."""
    if f.kind != "travel_limit":
        return f
    from dataclasses import replace

    w = np.zeros(6)
    v = np.asarray(wco, np.float64).reshape(-1)[:6]
    w[:v.size] = v
    axis = str(f.detail.get("axis", "X")).upper()
    k = _AXES.index(axis)
    lim = float(f.detail.get("limit", math.nan)) + w[k]
    group = str(f.detail.get("group", axis + "+"))
    side = "min" if group.endswith("-") else "max"
    pos = tuple(float(p + w[i]) for i, p in enumerate(f.position))
    detail = dict(f.detail, limit=lim)
    msg = f"travel limit: {axis}{side} {lim:g} exceeded by {f.depth:.3f} at line {f.line}"
    return replace(f, position=pos, detail=detail, message=msg)


def make_checker(wp: Workpiece, stock: DexelGrid, limits: dict | None, wco):
    """A :class:`sim.checks.Checker` on ``stock`` with the workpiece's design, fixtures,
    tools and tolerance, and the machine ``limits`` moved into work coordinates."""
    from sim.checks.checker import Checker

    return Checker(stock, wp.default_tool, design=wp.design, fixtures=wp.fixtures,
                   limits=limits_in_work(limits, wco), tol=wp.tol, tools=wp.tools, min_volume=MIN_VOLUME,
                   kinematics=wp.kinematics, origin=wp.origin, tool_lengths=wp.tool_lengths)


def _checked(checker, rows: np.ndarray, ids: np.ndarray, wco):
    """``checker.cut_and_check`` with limit findings in machine coordinates; the checker's
    own history is not kept (the session keeps what it alerted)."""
    res, found = checker.cut_and_check(rows, move_ids=ids)
    checker.findings.clear()
    return res, [finding_to_machine(f, wco) for f in found]


# --- the look-ahead -----------------------------------------------------------------------------

def row_costs(moves: np.ndarray, reach: float, spacing: float) -> np.ndarray:
    """Estimated work of cutting and checking each row, float64 (n,) in swept rays: the
    row's XY box grown by ``reach`` mm over the ray area, plus a fixed cost."""
    s = np.asarray(moves["start"][:, :2], np.float64)
    e = np.asarray(moves["end"][:, :2], np.float64)
    arc = np.isin(moves["kind"], (MoveKind.ARC_CW, MoveKind.ARC_CCW))
    c = np.asarray(moves["center"][:, :2], np.float64)
    # an arc's box: its centre +- radius (an upper bound)
    r = np.where(arc, np.linalg.norm(s - c, axis=1), 0.0)
    lo = np.where(arc[:, None], c - r[:, None], np.minimum(s, e)) - reach
    hi = np.where(arc[:, None], c + r[:, None], np.maximum(s, e)) + reach
    area = np.prod(np.maximum(hi - lo, 0.0), axis=1) / spacing**2
    moving = np.isin(moves["kind"], (MoveKind.RAPID, MoveKind.FEED, MoveKind.ARC_CW, MoveKind.ARC_CCW,
                                     MoveKind.PROBE))
    return np.where(moving, area, 0.0) + ROW_OVERHEAD_RAYS


def rotary_row_costs(wp: Workpiece, moves: np.ndarray, reach: float) -> np.ndarray:
    """Extra work of rows a rotary turns, float64 (n,) swept rays: their instances of
    motion (:meth:`sim.kinematics.Kinematics.instance_counts` of the machine poses, the
    tallest tool) times the rays under one tool (0 for rows that do not turn)."""
    out = np.zeros(len(moves))
    turning = np.any(moves["start"][:, 3:] != moves["end"][:, 3:], axis=1) | \
        np.any(moves["start"][:, 3:] != 0.0, axis=1)
    if not turning.any():
        return out
    height = max(float(t.profile[-1, 0]) for t in [*wp.tools.values(), wp.default_tool])
    origin = np.zeros(6) if wp.origin is None else np.asarray(wp.origin, np.float64)
    step = wp.tol.instance_fraction * wp.frame.spacing
    lengths = np.zeros(len(moves))
    for tool, length in (wp.tool_lengths or {}).items():
        lengths[moves["tool"] == tool] = length
    count = wp.kinematics.instance_counts(moves["start"][turning] + origin, moves["end"][turning] + origin,
                                          lengths[turning], height, reach, step)
    out[turning] = (count + 1) * (2.0 * reach / wp.frame.spacing + 2.0) ** 2
    return out


class Lookahead:
    """Cut and check the program ahead of the spindle on a scratch copy of the live stock.

    Parameters
    ----------
    wp : Workpiece
    moves : MOVE_DTYPE (n,) in work coordinates (:func:`work_moves`)
    path : ProgramPath of the same table (program time per row)
    horizon_s, horizon_mm : how far ahead to look (program seconds; and/or mm of path)
    limits : {axis: (lo, hi)} machine travel limits (optional), checked with ``wco``
    budget_rays : work allowed per :meth:`advance` (swept rays, :func:`row_costs`); at
        least one row is always done, so the scratch model keeps moving
    """

    def __init__(self, wp: Workpiece, moves: np.ndarray, path: ProgramPath, horizon_s: float = 5.0,
                 horizon_mm: float | None = None, limits: dict | None = None, budget_rays: float = BUDGET_RAYS):
        self.wp = wp
        self.moves = moves
        self.path = path
        self.horizon_s = float(horizon_s)
        self.horizon_mm = horizon_mm
        self.limits = {k.upper(): v for k, v in (limits or {}).items()}
        self.budget_rays = float(budget_rays)
        reach = max([t.radius for t in wp.tools.values()] + [wp.default_tool.radius])
        costs = row_costs(moves, reach, wp.frame.spacing)
        if wp.kinematics is not None:
            costs = costs + rotary_row_costs(wp, moves, reach)
        self.cost_cum = np.concatenate([[0.0], np.cumsum(costs)])
        self.checker = None
        self.next_row = 0
        self.wco = np.zeros(6)
        self.rows_checked = 0
        #: program s the rows waiting to be predicted reach back from the horizon end
        #: after the last :meth:`advance` (0: caught up)
        self.backlog_s = 0.0
        # the furthest horizon end of the advances since the anchor, before / after the
        # last advance: a row that starts before ``_end_before`` was inside the horizon
        # earlier and waited (program s)
        self._end_seen = -math.inf
        self._end_before = -math.inf

    @property
    def model(self) -> DexelGrid | None:
        """The scratch model (the live stock at the anchor, cut by the rows predicted since)."""
        return None if self.checker is None else self.checker.grid

    def anchor(self, live: DexelGrid, row: int, wco=None, behind: bool = False) -> None:
        """Restart the scratch model from the live one, predicting from ``row`` on.

        ``behind``: the spindle overtook the look-ahead; the rows ahead were inside the
        horizon already, so findings on them count as predicted late (:meth:`late_s`)."""
        if not behind:
            self._end_seen = -math.inf
        if wco is not None:
            self.wco = np.asarray(wco, np.float64)
        c = self.checker
        if c is None or c.engagement is not None:  # engagement keeps its own top snapshot
            self.checker = make_checker(self.wp, live.copy(), self.limits, self.wco)
        else:
            # re-anchoring after a jump: refill the scratch model in place and keep the
            # checker (its design casts, error map and bounds stay valid: the live model
            # only loses material, and findings only read the rays each batch updates)
            _copy_into(c.grid, live)
            c.forget_contacts()
            c.limits = limits_in_work(self.limits, self.wco)
        self.next_row = int(row)

    def set_wco(self, wco) -> None:
        """The work offset changed: later rows are checked against limits moved with it."""
        self.wco = np.asarray(wco, np.float64)
        if self.checker is not None:
            self.checker.limits = limits_in_work(self.limits, self.wco)

    def horizon_end(self, progress: float) -> float:
        """Program time up to which rows are predicted."""
        end = progress + self.horizon_s
        if self.horizon_mm is not None:
            end = min(end, self.path.progress_at_length(self.path.length_at(progress) + self.horizon_mm))
        return end

    def target_row(self, progress: float) -> int:
        """One past the last row that starts before the horizon end."""
        hi = int(np.searchsorted(self.path.row_t0, self.horizon_end(progress), side="left"))
        return min(hi, len(self.moves))

    def behind(self, progress: float) -> int:
        """Rows inside the horizon not predicted yet (0 when caught up)."""
        return max(self.target_row(progress) - self.next_row, 0)

    def advance(self, progress: float, budget_rays: float | None = None) -> list[Finding]:
        """Predict the next rows that start before the horizon end, as many as the budget
        allows (at least one); return their findings."""
        if self.checker is None:
            raise RuntimeError("Lookahead.anchor() first")
        end = self.horizon_end(progress)
        self._end_before, self._end_seen = self._end_seen, max(self._end_seen, end)
        target = self.target_row(progress)
        lo = self.next_row
        if target <= lo:
            self.backlog_s = 0.0
            return []
        budget = self.budget_rays if budget_rays is None else float(budget_rays)
        cap = int(np.searchsorted(self.cost_cum, self.cost_cum[lo] + budget, side="right")) - 1
        hi = min(target, max(cap, lo + 1))
        self.next_row = hi
        self.backlog_s = max(end - float(self.path.row_t0[hi]), 0.0) if hi < target else 0.0
        return self.check_rows(lo, hi)

    def late_s(self, finding: Finding, progress: float) -> float:
        """Program s of lead the finding lost waiting in the backlog: its row was inside
        the horizon at an earlier :meth:`advance` (or before the spindle overtook the
        look-ahead) but predicted only now; 0 when it was predicted at its first chance."""
        row = int(min(finding.stages or (finding.stage,))) - 1
        if row < 0 or row >= self.path.row_t0.size:
            return 0.0
        t0 = float(self.path.row_t0[row])
        if t0 >= self._end_before:
            return 0.0
        return max(self.horizon_end(progress) - t0, 0.0)

    def check_rows(self, lo: int, hi: int) -> list[Finding]:
        """Cut and check rows ``lo..hi-1`` on the scratch model (``Checker.cut_and_check``)."""
        self.rows_checked += hi - lo
        ids = np.arange(lo + 1, hi + 1, dtype=np.int64)
        _, found = _checked(self.checker, self.moves[lo:hi], ids, self.wco)
        return found


def _copy_into(dst: DexelGrid, src: DexelGrid) -> None:
    """Make ``dst`` hold ``src``'s material (same frame), reusing ``dst``'s arrays where
    they have the size (no page faults for a million rays)."""
    for k, v in src.store.items():
        d = dst.store.get(k)
        if isinstance(v, np.ndarray) and isinstance(d, np.ndarray) and d.shape == v.shape and d.dtype == v.dtype:
            np.copyto(d, v)
        else:
            dst.store[k] = v.copy() if isinstance(v, np.ndarray) else v


# --- the live checks ---------------------------------------------------------------------------

class LiveChecks:
    """Cut the path the tool really travelled into the live model and check it.

    Parameters
    ----------
    wp : Workpiece (its ``stock`` is the live model, cut in place)
    moves : MOVE_DTYPE (n,) the program in work coordinates (gives each travelled piece
        its row's kind, line, tool and feed)
    limits : machine travel limits {axis: (lo, hi)} (optional)
    max_pieces : capacity of the reusable row buffer (more pieces are cut in batches)
    """

    def __init__(self, wp: Workpiece, moves: np.ndarray, limits: dict | None = None, wco=None,
                 max_pieces: int = 64):
        self.wp = wp
        self.moves = moves
        self.limits = {k.upper(): v for k, v in (limits or {}).items()}
        self.wco = np.zeros(6) if wco is None else np.asarray(wco, np.float64)
        self.checker = make_checker(wp, wp.stock, self.limits, self.wco)
        # per program row, what a travelled piece takes from it (small arrays: indexing
        # them per state is cheaper than copying whole MOVE_DTYPE rows)
        self._line = np.ascontiguousarray(moves["line"])
        self._kind = np.where(moves["kind"] == MoveKind.RAPID, MoveKind.RAPID, MoveKind.FEED).astype(
            moves.dtype["kind"])
        self._feed = np.ascontiguousarray(moves["feed"])
        self._tool = np.ascontiguousarray(moves["tool"])
        self._spindle = np.ascontiguousarray(moves["spindle"])
        self._sdir = np.ascontiguousarray(moves["spindle_dir"])
        # per row, how often the program switched the spindle (running <-> stopped) up to
        # it: the same count at two rows means the program leaves the spindle as it is
        # between them (as sim.checks.spindle reads a row: stopped when its direction or
        # speed is 0)
        stopped = (self._sdir == 0) | (self._spindle <= 0)
        self._switches = np.concatenate([[0], np.cumsum(stopped[1:] != stopped[:-1])])
        self._rot0 = np.ascontiguousarray(moves["start"][:, 3:])
        self._rot1 = np.ascontiguousarray(moves["end"][:, 3:])
        self._buf = np.zeros(max_pieces, MOVE_DTYPE)
        self._buf["plane"] = Plane.XY
        self._ids = np.zeros(max_pieces, np.int64)

    def set_wco(self, wco) -> None:
        w = np.asarray(wco, np.float64)
        if not np.array_equal(w, self.wco):
            self.wco = w
            self.checker.limits = limits_in_work(self.limits, w)

    def cut(self, points: np.ndarray, rows: np.ndarray, spindle_rpm: float | None = None,
            arrived_row: int | None = None, polled_rows=()):
        """Cut the polyline ``points`` (k+1, 3) mm (work tip), piece ``q`` belonging to
        program row ``rows[q]`` (int, (k,)); return ``(removed mm^3, changed rays int64
        sorted and distinct, findings)``. ``points`` (k+1, 6) adds the work A B C (deg) at
        each point (a rotary job: the pieces turn as the machine did); with 3 columns each
        piece takes its row's programmed angles.

        ``spindle_rpm``: the speed the controller reports (None: take the program's);
        it holds for the path only where the program leaves the spindle as it is from
        the rows of the polls at its ends (``polled_rows``, the program rows the
        controller was at) over every row in between.
        ``arrived_row``: the row of the piece that ended at ``points[0]`` (the last one
        cut before), if known.

        Where the row changes (between two pieces, or from ``arrived_row`` to the first),
        the tool's pose at that point is cut first as the arriving row's own
        (:func:`arrival_poses`): that row brought the tool there, so whatever its pose
        touches is that row's doing, not the next one's.
        """
        if spindle_rpm is not None and self._program_switches_spindle(rows, arrived_row, *polled_rows):
            # the controller's speed is what the polls at the two ends of the path saw; the
            # program switched the spindle between them (a coarse poll over its M3 and M5,
            # say), so how it ran there is not what either end saw: each row takes the
            # program's (else a path from before M3 to after M5 was all "spindle stopped")
            spindle_rpm = None
        points, rows = arrival_poses(points, rows, arrived_row)
        removed = 0.0
        changed = []
        found: list[Finding] = []
        k = len(points) - 1
        step = self._buf.size
        for a in range(0, k, step):
            b = min(a + step, k)
            m = self._fill(points[a:b + 1], rows[a:b], spindle_rpm)
            res, f = _checked(self.checker, m, self._ids[:b - a], self.wco)
            removed += float(res.removed.sum())
            if res.changed_rays.size:
                changed.append(res.changed_rays)
            found += f
        # sorted: the trace record takes them as they are (np.unique would hash them first)
        rays = distinct(np.concatenate(changed)).astype(np.int64, copy=False) if changed else np.zeros(0, np.int64)
        return removed, rays, found

    def _program_switches_spindle(self, rows: np.ndarray, *more) -> bool:
        """Whether the program starts or stops the spindle anywhere from the first to the
        last of ``rows`` and the rows in ``more`` (None: unknown, left out)."""
        rows = np.asarray(rows)
        lo, hi = int(rows.min()), int(rows.max())
        for r in more:
            if r is not None and 0 <= r < self._switches.size:
                lo, hi = min(lo, int(r)), max(hi, int(r))
        return bool(self._switches[hi] != self._switches[lo])

    def _fill(self, pts: np.ndarray, rows: np.ndarray, spindle_rpm) -> np.ndarray:
        """The travelled pieces as move rows in the reusable buffer (a view, k rows)."""
        k = len(rows)
        m = self._buf[:k]
        m["line"] = self._line[rows]
        m["kind"] = self._kind[rows]
        start, end = m["start"], m["end"]
        if pts.shape[1] == 6:
            start[:] = pts[:-1]
            end[:] = pts[1:]
        else:
            start[:, :3] = pts[:-1]
            end[:, :3] = pts[1:]
            start[:, 3:] = self._rot0[rows]
            end[:, 3:] = self._rot1[rows]
        m["feed"] = self._feed[rows]
        m["tool"] = self._tool[rows]
        if spindle_rpm is None:
            m["spindle"] = self._spindle[rows]
            m["spindle_dir"] = self._sdir[rows]
        else:
            m["spindle"] = abs(float(spindle_rpm))
            if spindle_rpm == 0:
                m["spindle_dir"] = 0
            else:
                d = self._sdir[rows]
                m["spindle_dir"] = np.where(d != 0, d, 1 if spindle_rpm > 0 else -1)
        self._ids[:k] = rows + 1
        return m


def arrival_poses(points: np.ndarray, rows: np.ndarray, arrived_row: int | None = None):
    """The travelled polyline with a zero-length piece at every change of program row,
    owned by the row that arrived there: ``(points (k'+1, 3), rows (k',) int64)``.

    ``points`` (k+1, 3) mm, piece ``q`` = ``points[q] -> points[q+1]`` of row ``rows[q]``
    (k,); ``arrived_row``: the row whose piece ended at ``points[0]`` (None: unknown).

    Why: the swept volume of a move includes the tool at its end, but the kernel decides
    a ray at exactly the tool radius from that end with arithmetic relative to the move's
    *start*, while the next move (a straight retract from that point) decides it relative
    to the point itself. The two can disagree in the last bit. Rays at exactly the radius
    are common (round program coordinates on a 0.5 mm grid: the rays at a slot's end and
    walls), and each is a whole column of material handed to the next row: a retract
    after a feed then reads as a rapid into stock. Cutting the arrival pose with the next
    piece's own arithmetic (a zero-length move from the same point) makes the two agree.
    """
    points = np.asarray(points, np.float64)
    rows = np.asarray(rows, np.int64)
    if rows.size == 0:
        return points, rows
    before = np.empty_like(rows)
    before[0] = rows[0] if arrived_row is None else int(arrived_row)
    before[1:] = rows[:-1]
    turn = np.nonzero(before != rows)[0]
    if turn.size == 0:
        return points, rows
    return np.insert(points, turn, points[turn], axis=0), np.insert(rows, turn, before[turn])


# --- findings as JSON records ---------------------------------------------------------------

def lead_time(finding: Finding, path: ProgramPath, progress: float, feed_override: float = 100.0) -> float:
    """Predicted seconds until the spindle reaches the finding's move (0 if already there).

    Program time from the current progress to the start of the first offending row, scaled
    by the feed override (a 200 % override halves it).
    """
    stages = finding.stages or (finding.stage,)
    row = int(min(stages)) - 1
    if row < 0 or row >= path.row_t0.size:
        return 0.0
    scale = 100.0 / feed_override if feed_override and feed_override > 0 else 1.0
    return max(float(path.row_t0[row]) - float(progress), 0.0) * scale


def finding_record(f: Finding, lead: float, t: float | None = None, predicted: bool = True,
                   stage: int | None = None, path: ProgramPath | None = None, moves=None) -> dict:
    """The JSON object of one finding: ``Finding.to_json()`` + ``lead_time_s``, ``predicted``
    and ``status`` (``"predicted"`` ahead of the spindle, ``"happened"`` on the real motion)
    (+ ``t``).

    With ``path`` its ``time_s`` is the program time at which its worst move starts
    (the move table's timing); with ``moves`` (the program in work coordinates) its
    ``programmed`` point is where that move was programmed to take the tip (the live
    checks cut the travelled path, whose pieces end elsewhere).

    The checker's ``stage`` is a move id (row + 1): it is told as ``move``, so that
    ``stage`` means one thing in a run, the live stage (the model after the n-th recorded
    cut, 0 = the stock), given only where the finding happened (``stage``)."""
    d = f.to_json()
    d["move"] = int(d.pop("stage", 0) or 0)
    row = d["move"] - 1
    if path is not None and 0 <= row < path.row_t0.size:
        d["time_s"] = round(float(path.row_t0[row]), 3)
    if moves is not None and 0 <= row < len(moves):
        tip = np.array(moves["end"][row, :3], np.float64)
        tip[2] -= float(moves["tool_length"][row])
        d["programmed"] = [round(float(v), 4) for v in tip]
    if stage is not None:
        d["stage"] = int(stage)
    d["lead_time_s"] = round(float(lead), 3) if math.isfinite(lead) else None
    d["predicted"] = bool(predicted)
    d["status"] = "predicted" if predicted else "happened"
    if t is not None:
        d["t"] = float(t)
    return d
