"""The 3-D scene the page shows: the model's top surface coloured by height, the path
(rapids and feeds told apart), the tool at its tip and the findings, in one offscreen
pyvista plotter whose surface is updated in place from stage to stage."""

from __future__ import annotations

import numpy as np

from monitor.render import view3d

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
        self.frame = frame
        self.tool = tool
        h = np.asarray(heights, np.float64)
        #: the colour range (mm): from the program's deepest point to the stock's top
        self.clim = height_range(h, moves)
        self.floor = self.clim[0]
        self.surface = view3d.heightfield(frame, h, floor=self.floor)
        self._base, self._axis = _point_basis(frame)
        self.plotter = pl = pv.Plotter(off_screen=True, window_size=list(window_size))
        pl.set_background(BACKGROUND)
        pl.add_mesh(self.surface, scalars="height", cmap="viridis", clim=self.clim, nan_color="#30323a",
                    show_scalar_bar=True, smooth_shading=True,
                    scalar_bar_args={"title": "height (mm)", "fmt": "%.1f", "color": "white"})
        for lines, colour, width in _path_lines(moves):
            pl.add_mesh(lines, color=colour, line_width=width)
        if findings is not None and len(findings):
            pl.add_mesh(pv.PolyData(np.asarray(findings, np.float64).reshape(-1, 3)), color=FINDING_COLOUR,
                        point_size=14, render_points_as_spheres=True)
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
        """Move the surface to ``heights`` (nv, nu) mm (empty rays drop to the floor)."""
        h = np.asarray(heights, np.float64)
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

    def show(self, heights: np.ndarray, tip=None) -> None:
        """Surface at ``heights``, tool at ``tip``; the picture is drawn by the next render."""
        self.set_heights(heights)
        self.set_tip(tip)

    def render(self) -> None:
        self.plotter.render()

    def close(self) -> None:
        self.plotter.close()


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
