"""The 3-D scene the page shows: the model's top surface coloured by height, the path
near the stage (rapids and feeds told apart; the moves the pictures draw,
:func:`monitor.render.runpicture.path_near`), the tool at its tip and the findings
labelled with their line (drawn over the surface, so one under the stock's top still
shows), in one offscreen pyvista plotter updated in place from stage to stage."""

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

    ``moves`` (move table in the model frame) gives the path, ``tool`` (sim Tool) the tool,
    ``findings`` (m, 3) mm the findings' positions and ``finding_labels`` their labels.
    :meth:`show` puts the surface at new heights, the tool at a new tip and the path
    round a new program row; the next render draws them.
    """

    def __init__(self, frame, heights: np.ndarray, moves=None, tool=None, findings=None,
                 finding_labels=None, window_size=(900, 640)):
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
        self.moves = moves if moves is not None and len(moves) else None
        #: feeds and rapids: (mesh, actor) each, their points replaced by :meth:`set_path`
        self._path = {}
        for rapid, colour, width in ((False, FEED_COLOUR, 2), (True, RAPID_COLOUR, 1)):
            mesh = pv.PolyData(np.zeros((2, 3)), lines=np.array([2, 0, 1]))
            self._path[rapid] = (mesh, pl.add_mesh(mesh, color=colour, line_width=width))
        self.set_path(None)
        self.set_findings(findings, finding_labels)
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

    def set_path(self, row: int | None) -> None:
        """Draw the path round program ``row`` of the move table (None: its start)."""
        from monitor.render.runpicture import path_near

        path = path_near(self.moves, row)
        for rapid, (mesh, actor) in self._path.items():
            sel = np.zeros(0, bool) if path is None else path["rapid"] == rapid
            actor.SetVisibility(bool(sel.any()))
            if sel.any():
                mesh.copy_from(segments(path["start"][sel], path["end"][sel]))

    def set_findings(self, points, labels=None) -> None:
        """Mark the findings at ``points`` (m, 3) mm with ``labels`` (m,) (default
        ``finding``); None or none: no marks. The labels are drawn over the model (a
        finding under the surface is not hidden by it), each with a red dot."""
        pts = np.zeros((0, 3)) if points is None else np.asarray(points, np.float64).reshape(-1, 3)
        labels = list(labels) if labels is not None else ["finding"] * len(pts)
        keep = np.all(np.isfinite(pts), axis=1)
        pts, labels = pts[keep], [t for t, k in zip(labels, keep) if k]
        for part in ("findings-labels", "findings-points"):   # the two actors add_point_labels names
            self.plotter.remove_actor(part, render=False)
        if len(pts):
            self.plotter.add_point_labels(pts, labels, name="findings", point_color=FINDING_COLOUR, point_size=14,
                                          render_points_as_spheres=True, text_color=FINDING_COLOUR, font_size=14,
                                          shape_color="#101014", shape_opacity=0.7, always_visible=True,
                                          render=False)

    def show(self, heights: np.ndarray, tip=None, row: int | None = None) -> None:
        """Surface at ``heights``, tool at ``tip``, the path round program ``row``; the
        picture is drawn by the next render."""
        self.set_heights(heights)
        self.set_tip(tip)
        self.set_path(row)

    def path_meshes(self) -> list:
        """The path's meshes now shown (feeds, rapids)."""
        return [mesh for mesh, actor in self._path.values() if actor.GetVisibility()]

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


def segments(start: np.ndarray, end: np.ndarray):
    """A ``pv.PolyData`` of the line pieces from ``start`` (k, 3) to ``end`` (k, 3) mm."""
    import pyvista as pv

    n = len(start)
    pts = np.empty((2 * n, 3))
    pts[0::2], pts[1::2] = start, end
    cells = np.column_stack([np.full(n, 2), 2 * np.arange(n), 2 * np.arange(n) + 1]).reshape(-1)
    return pv.PolyData(pts, lines=cells)
