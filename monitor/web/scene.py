"""The 3-D scene the page shows: the model's top surface coloured by height, the path
(rapids and feeds told apart), the tool at its tip and the findings, in one offscreen
pyvista plotter whose surface is updated in place from stage to stage."""

from __future__ import annotations

import numpy as np

from monitor.render import view3d

#: the surface drawn has at most this many points: a finer model is shown by the lowest
#: point of each k x k block of rays (a cut never disappears), so a picture costs the
#: same on a million rays as on a quarter of them
MAX_SURFACE_POINTS = 256 * 1024

#: colours: feeds, rapids, findings, background
FEED_COLOUR, RAPID_COLOUR, FINDING_COLOUR, BACKGROUND = "#37c8e6", "#f08c28", "red", "#1c1e24"


class Scene:
    """A plotter on a model of ``frame`` (sim Frame) starting from ``heights`` (nv, nu) mm.

    ``moves`` (move table in the model frame) draws the path, ``tool`` (sim Tool) the tool,
    ``findings`` (m, 3) mm the findings' positions. :meth:`show` puts the surface at new
    heights and the tool at a new tip, then renders.
    """

    def __init__(self, frame, heights: np.ndarray, moves=None, tool=None, findings=None,
                 window_size=(900, 640)):
        import pyvista as pv

        view3d.quiet_vtk()
        self.k = block_factor(frame.nu * frame.nv, MAX_SURFACE_POINTS)
        self.frame = frame = block_frame(frame, self.k)
        self.tool = tool
        h = block_lowest(np.asarray(heights, np.float64), self.k)
        #: the colour range (mm): from the program's deepest point to the stock's top
        self.clim = height_range(h, moves)
        self.floor = self.clim[0]
        self._base, self._axis = _point_basis(frame)
        self.surface = surface_mesh(frame, self._base)
        self._set_surface(h)
        self.plotter = pl = pv.Plotter(off_screen=True, window_size=list(window_size))
        pl.set_background(BACKGROUND)
        pl.add_mesh(self.surface, scalars="height", cmap="viridis", clim=self.clim, nan_color="#30323a",
                    show_scalar_bar=True, scalar_bar_args={"title": "height (mm)", "fmt": "%.1f", "color": "white"})
        for lines, colour, width in _path_lines(moves):
            pl.add_mesh(lines, color=colour, line_width=width)
        self._findings = pv.PolyData(np.zeros((1, 3)))
        self._findings_actor = pl.add_mesh(self._findings, color=FINDING_COLOUR, point_size=14,
                                           render_points_as_spheres=True)
        self.set_findings(findings)
        self._tool_actors, self._tool_at = self._add_tool(tool)
        pl.add_axes(color="white")
        pl.view_isometric()
        pl.reset_camera()
        pl.camera.zoom(1.15)

    @property
    def render_window(self):
        return self.plotter.ren_win

    def _add_tool(self, tool):
        if tool is None:
            return [], np.zeros(3)
        at = np.zeros(3)
        actors = [self.plotter.add_mesh(mesh, color=colour, smooth_shading=True)
                  for mesh, colour in view3d.tool_meshes(tool, at)]
        for a in actors:
            a.SetVisibility(False)
        return actors, at

    def set_heights(self, heights: np.ndarray) -> None:
        """Move the surface to ``heights`` (nv, nu) mm of the model's frame (empty rays
        drop to the floor)."""
        h = block_lowest(np.asarray(heights, np.float64), self.k)
        self._set_surface(h)

    def _set_surface(self, h: np.ndarray) -> None:
        z = np.where(np.isfinite(h), h, self.floor).T.reshape(-1, order="F")
        self.surface.points = self._base + z[:, None] * self._axis
        self.surface.point_data["height"] = h.T.reshape(-1, order="F")

    def set_tip(self, tip) -> None:
        """Put the tool at ``tip`` (3,) mm; hide it when the tip is unknown (NaN or None)."""
        ok = tip is not None and bool(np.all(np.isfinite(tip)))
        for a in self._tool_actors:
            a.SetVisibility(ok)
            if ok:
                a.SetPosition(*(np.asarray(tip, np.float64) - self._tool_at))

    def set_findings(self, points) -> None:
        """Mark the findings at ``points`` (m, 3) mm (None or none: no marks)."""
        import pyvista as pv

        pts = np.zeros((0, 3)) if points is None else np.asarray(points, np.float64).reshape(-1, 3)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        self._findings_actor.SetVisibility(bool(len(pts)))
        if len(pts):
            self._findings.copy_from(pv.PolyData(pts))

    def show(self, heights: np.ndarray, tip=None) -> None:
        """Surface at ``heights``, tool at ``tip``; the picture is drawn by the next render."""
        self.set_heights(heights)
        self.set_tip(tip)

    def close(self) -> None:
        self.plotter.close()


def block_factor(n_rays: int, max_points: int) -> int:
    """The k of the k x k blocks of rays one surface point stands for (1: every ray)."""
    return max(1, int(np.ceil(np.sqrt(n_rays / max_points))))


def block_frame(frame, k: int):
    """The frame whose rays are the centres of ``frame``'s k x k blocks (whole blocks)."""
    if k == 1:
        return frame
    from sim.frame import Frame

    centre = frame.origin + (k - 1) / 2 * frame.spacing * (frame.u + frame.v)
    return Frame(centre, frame.direction, frame.u, frame.spacing * k, frame.nu // k, frame.nv // k)


def block_lowest(heights: np.ndarray, k: int) -> np.ndarray:
    """The lowest finite height of each k x k block of ``heights`` (nv, nu) (NaN where the
    whole block is empty); rays past the last whole block are left out."""
    if k == 1:
        return heights
    nv, nu = heights.shape[0] // k, heights.shape[1] // k
    blocks = heights[:nv * k, :nu * k].reshape(nv, k, nu, k)
    return np.fmin.reduce(np.fmin.reduce(blocks, axis=3), axis=1)


def height_range(heights: np.ndarray, moves=None) -> tuple[float, float]:
    """(low, high) mm: the lowest of the heights and the program's deepest tip, the highest
    height (at least 1 mm apart)."""
    fin = heights[np.isfinite(heights)]
    if not fin.size:
        return 0.0, 1.0
    low, high = float(fin.min()), float(fin.max())
    if moves is not None and len(moves):
        ends = np.asarray(moves["end"][:, 2], np.float64)
        ends = ends[np.isfinite(ends)]
        if ends.size:
            low = min(low, float(ends.min()))
    return low, max(high, low + 1.0)


def surface_mesh(frame, base: np.ndarray):
    """The top surface as a ``pv.PolyData`` of quads between neighbouring rays, its points
    ``base`` (the heightfield's point order: u fastest). Polygons, not a structured grid:
    a structured grid is turned into polygons again at every render, which costs more
    than the render itself on a million rays."""
    import pyvista as pv

    nu, nv = frame.nu, frame.nv
    idx = np.arange(nu * nv, dtype=np.int64).reshape(nv, nu)
    a, b = idx[:-1, :-1].reshape(-1), idx[:-1, 1:].reshape(-1)
    c, d = idx[1:, 1:].reshape(-1), idx[1:, :-1].reshape(-1)
    quads = np.column_stack([np.full(a.size, 4, np.int64), a, b, c, d]).reshape(-1)
    return pv.PolyData(base.copy(), faces=quads)


def _point_basis(frame) -> tuple[np.ndarray, np.ndarray]:
    """World points of the surface at height 0 (in the heightfield's point order) and the
    world step per mm of height: points = base + height * axis."""
    i = np.arange(frame.nu) * frame.spacing
    j = np.arange(frame.nv) * frame.spacing
    local = np.stack(np.broadcast_arrays(i[None, :], j[:, None], np.zeros((frame.nv, frame.nu))), axis=-1)
    pts = frame.to_world(local)
    base = np.stack([pts[..., k].T.reshape(-1, order="F") for k in range(3)], axis=1)
    axis = frame.to_world(np.array([0.0, 0.0, 1.0])) - frame.to_world(np.zeros(3))
    return base, axis


def _path_lines(moves):
    """``(pv.PolyData lines, colour, width)`` for the feeds and for the rapids of a move table."""
    if moves is None or not len(moves):
        return []
    import pyvista as pv

    from sim.checks.motion import path_polyline
    from sim.gcode.moves import MoveKind

    p0, p1, rows = path_polyline(moves, chord=0.1)
    rapid = np.asarray(moves["kind"])[rows] == MoveKind.RAPID
    out = []
    for which, colour, width in ((~rapid, FEED_COLOUR, 2), (rapid, RAPID_COLOUR, 1)):
        if not which.any():
            continue
        a, b = p0[which], p1[which]
        pts = np.empty((2 * len(a), 3))
        pts[0::2], pts[1::2] = a, b
        n = len(a)
        cells = np.column_stack([np.full(n, 2), 2 * np.arange(n), 2 * np.arange(n) + 1]).reshape(-1)
        out.append((pv.PolyData(pts, lines=cells), colour, width))
    return out
