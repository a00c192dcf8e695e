"""The job's workpiece as dexel models: stock, fixtures and design on one frame covering
them all, with the tools the program uses (:func:`build_workpiece`, :class:`Workpiece`).

In the job's work coordinates (:mod:`monitor.work_coords`); a stock model too large for
memory is refused before anything of it is allocated (:func:`check_stock_memory`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from monitor.job import Job, JobError, Solid
from monitor.work_coords import reference_wco
from sim.errors import InputError
from sim.frame import Frame
from sim.gcode.moves import MoveKind
from sim.grid import DexelGrid
from sim.tolerance import Tolerance


def _load_mesh(solid: Solid, what: str):
    from sim.solids import load_mesh

    mesh, _ = load_mesh(solid.stl)
    mesh = mesh.copy()
    mesh.apply_translation(solid.offset)
    return mesh


def solid_bounds(solid: Solid, what: str):
    """``(lo (3,), hi (3,), mesh)`` mm: the solid's box, with its mesh when it took
    loading one for it (an STL), else None."""
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
    lo, hi, stock_mesh = solid_bounds(job.stock, "[stock]")
    fixture_meshes = []
    for f in job.fixtures:
        flo, fhi, fm = solid_bounds(f, "[[fixtures]]")
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

    slo, shi, _ = solid_bounds(job.stock, "[stock]") if stock_mesh is None else (
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
    lo, hi, _ = solid_bounds(solid, "[[fixtures]]") if mesh is None else (mesh.bounds[0], mesh.bounds[1], None)
    m = reach + 2 * spacing
    frame = Frame.top(lo[0] - m, lo[1] - m, hi[0] + m, hi[1] + m, spacing)
    return _solid_grid(frame, solid, mesh, tol)
