"""pyvista 3-D views of a dexel model: error-map or height colouring with a colour bar, the
tool and holder as solids of revolution, the path, Huang's contour display; offscreen PNG
and an interactive window with a stage slider.
"""

from __future__ import annotations

import os

import numpy as np

from sim.errors import InputError


def _pv():
    import pyvista as pv
    return pv


def quiet_vtk() -> None:
    """Keep VTK's own messages off stderr (offscreen it warns about X it does not need):
    its output window and its logger are switched off."""
    try:
        from vtkmodules.vtkCommonCore import vtkLogger, vtkObject, vtkOutputWindow

        vtkObject.GlobalWarningDisplayOff()
        vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_OFF)
        vtkOutputWindow.GetInstance().SetDisplayModeToNever()
    except (ImportError, AttributeError):  # another VTK build: its messages stay
        pass


def solid_surface(grid):
    """The dexel model as a closed ``pv.PolyData`` solid (top, walls and bottom, from
    ``sim.surface.surface_mesh``) with point data ``height`` = Z, mm; None when empty."""
    pv = _pv()
    from sim.surface import surface_arrays

    verts, faces, _ = surface_arrays(grid)
    if len(faces) == 0:
        return None
    faces = np.asarray(faces, np.int64)
    cells = np.hstack([np.full((len(faces), 1), 3, np.int64), faces]).reshape(-1)
    mesh = pv.PolyData(np.asarray(verts, np.float64), cells)
    mesh.point_data["height"] = mesh.points[:, 2].copy()
    return mesh


def heightfield(frame, heights: np.ndarray, floor: float | None = None):
    """A ``pv.StructuredGrid`` of the visible surface (nv, nu) heights, mm, in world coords.

    Empty rays (NaN) drop to ``floor`` (default: the lowest height) so the mesh stays whole.
    Point data ``height`` holds the heights (NaN kept).
    """
    pv = _pv()
    h = np.asarray(heights, np.float64)
    lo = np.nanmin(h) if floor is None and np.isfinite(h).any() else (floor or 0.0)
    z = np.where(np.isfinite(h), h, lo)
    i = np.arange(frame.nu) * frame.spacing
    j = np.arange(frame.nv) * frame.spacing
    local = np.stack(np.broadcast_arrays(i[None, :], j[:, None], z), axis=-1)
    pts = frame.to_world(local)
    # StructuredGrid wants (nu, nv, 1) arrays in Fortran order of points
    sg = pv.StructuredGrid(pts[..., 0].T[..., None], pts[..., 1].T[..., None], pts[..., 2].T[..., None])
    sg.point_data["height"] = h.T.reshape(-1, order="F")
    return sg


def error_cmap(tol=None, n: int = 4001):
    """A matplotlib colormap reproducing ``sim.checks.error_map.error_colors`` over
    [-interest, +interest] mm, and that range."""
    from matplotlib.colors import ListedColormap

    from sim.checks.error_map import error_colors
    from sim.tolerance import DEFAULT

    tol = tol or DEFAULT
    e = np.linspace(-tol.interest, tol.interest, n)
    return ListedColormap(error_colors(e, tol) / 255.0), (-tol.interest, tol.interest)


def revolve(profile: np.ndarray, base: np.ndarray, n_theta: int = 48):
    """Surface of revolution of a (k, 2) (h, r) profile about +Z, placed at ``base`` (3,)."""
    pv = _pv()
    p = np.asarray(profile, np.float64)
    th = np.linspace(0, 2 * np.pi, n_theta)
    x = p[:, 1][:, None] * np.cos(th)[None, :] + base[0]
    y = p[:, 1][:, None] * np.sin(th)[None, :] + base[1]
    z = np.broadcast_to(p[:, 0][:, None] + base[2], x.shape)
    sg = pv.StructuredGrid(x[..., None], y[..., None], np.array(z)[..., None])
    try:
        return sg.extract_surface(algorithm="dataset_surface")
    except TypeError:  # older pyvista without the keyword
        return sg.extract_surface()


def tool_meshes(tool, tip) -> list[tuple[object, str]]:
    """(mesh, colour) of the cutter and any shank/holder of a ``sim.tools.Tool`` at ``tip``."""
    tip = np.asarray(tip, np.float64).reshape(3)
    out = []
    prof = getattr(tool, "profile", None)
    if prof is None:
        r = float(getattr(tool, "radius", 3.0))
        prof = np.array([[0, 0], [0, r], [20, r], [20, 0]])
    out.append((revolve(prof, tip), "gold"))
    bodies = tool.bodies() if hasattr(tool, "bodies") else []
    for b, col in zip(bodies, ("silver", "dimgray")):
        out.append((revolve(b.profile, tip), col))
    return out


def build_plotter(grid=None, heights=None, frame=None, errors=None, tol=None, tool=None, tip=None,
                  path=None, findings=None, contours: int = 0, off_screen: bool = True,
                  window_size=(800, 800), color_by: str = "auto"):
    """A ``pv.Plotter`` showing the model and its context.

    Give ``grid`` (a DexelGrid: the surface comes from its tops) or ``heights`` + ``frame``.
    ``errors`` (nv, nu) signed mm colour the surface with the error map and a colour bar;
    otherwise it is coloured by height. ``contours`` > 0 adds Huang's contour display
    (that many iso-height lines). ``path`` (k, 3) and ``findings`` (m, 3) world points.
    """
    pv = _pv()
    if grid is not None:
        frame = grid.frame
        heights = grid.top()
    if heights is None or frame is None:
        raise InputError("build_plotter needs a grid or heights and a frame")
    if off_screen:
        quiet_vtk()
    surf = heightfield(frame, heights)
    solid = solid_surface(grid) if grid is not None and errors is None else None
    pl = pv.Plotter(off_screen=off_screen, window_size=list(window_size))
    pl.set_background("#1c1e24")
    if solid is not None:
        # the stock as a solid with its sides, coloured by the real height range
        z = solid.point_data["height"]
        clim = (float(z.min()), float(z.max()) if z.max() > z.min() else float(z.min()) + 1.0)
        pl.add_mesh(solid, scalars="height", cmap="viridis", clim=clim, show_scalar_bar=True,
                    scalar_bar_args={"title": "height (mm)", "fmt": "%.1f"})
    elif errors is not None and (color_by in ("auto", "error")):
        cmap, clim = error_cmap(tol)
        surf.point_data["error (mm)"] = np.asarray(errors, np.float64).T.reshape(-1, order="F")
        pl.add_mesh(surf, scalars="error (mm)", cmap=cmap, clim=clim, nan_color="#ebc828", n_colors=cmap.N,
                    show_scalar_bar=True, scalar_bar_args={"title": "error (mm)"}, smooth_shading=True)
    else:
        h = np.asarray(heights, np.float64)
        fin = h[np.isfinite(h)]
        clim = (float(fin.min()), float(max(fin.max(), fin.min() + 1.0))) if fin.size else (0.0, 1.0)
        pl.add_mesh(surf, scalars="height", cmap="viridis", nan_color="#30323a", clim=clim,
                    show_scalar_bar=True, scalar_bar_args={"title": "height (mm)", "fmt": "%.1f"},
                    smooth_shading=True)
    if contours:
        lines = surf.contour(isosurfaces=int(contours), scalars="height")
        if lines.n_points:
            pl.add_mesh(lines, color="white", line_width=1.5)
    if path is not None and len(path) > 1:
        pl.add_mesh(pv.MultipleLines(points=np.asarray(path, np.float64)), color="cyan", line_width=2)
    if tool is not None and tip is not None and np.all(np.isfinite(tip)):
        for mesh, col in tool_meshes(tool, tip):
            pl.add_mesh(mesh, color=col, smooth_shading=True)
    if findings is not None and len(findings):
        pts = pv.PolyData(np.asarray(findings, np.float64).reshape(-1, 3))
        pl.add_mesh(pts, color="red", point_size=14, render_points_as_spheres=True)
    pl.view_isometric()
    pl.camera.zoom(1.2)
    return pl


def render_png(grid=None, path_out=None, window_size=(800, 800), **kw) -> np.ndarray:
    """Render offscreen; return the RGB uint8 image and write it to ``path_out`` if given."""
    kw.setdefault("path", None)
    pl = build_plotter(grid=grid, off_screen=True, window_size=window_size, **kw)
    try:
        img = pl.screenshot(path_out if path_out else None, return_img=True)
    finally:
        pl.close()
    return np.asarray(img)[..., :3].astype(np.uint8)


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or os.name == "nt"


def interactive(trace, tool=None, path=None, findings=None, contours: int = 0):
    """A window on the run with a slider over its stages (needs a display)."""
    if not has_display():
        raise InputError("no display for an interactive window ($DISPLAY is not set); "
                         "use --png / --gif instead", "--view")
    pv = _pv()
    first = (trace.z or trace.t).first_stage
    last = trace.last_stage
    pl = build_plotter(heights=trace.heights_at(last), frame=trace.frame, tool=None, path=path,
                       findings=findings, contours=contours, off_screen=False)
    surf = pl.meshes[0] if hasattr(pl, "meshes") else None

    n = trace.frame.n_rays
    buf = (np.empty(n, np.float32), np.empty(n, np.int32))  # one pair reused while sliding

    def show(value):
        h = trace.heights_at(int(round(value)), out=buf).reshape(trace.frame.shape)
        fresh = heightfield(trace.frame, h)
        if surf is not None:
            surf.points = fresh.points
            surf.point_data["height"] = fresh.point_data["height"]
        pl.render()

    pl.add_slider_widget(show, [first, last], value=last, title="stage", fmt="%.0f")
    pl.show()
    del pv
