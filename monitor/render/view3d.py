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


def deviation_cmap(tol, n: int = 4001):
    """A matplotlib colormap of the deviation map (:mod:`.meaning`) over [-interest,
    +interest] mm, and that range."""
    from matplotlib.colors import ListedColormap

    from monitor.render.meaning import deviation_colors

    e = np.linspace(-tol.interest, tol.interest, n)
    return ListedColormap(deviation_colors(e, tol) / 255.0), (-tol.interest, tol.interest)


#: the colour bar: vertical on the right, its title above the numbers (never over them)
BAR_ARGS = {"vertical": True, "position_x": 0.88, "position_y": 0.25, "height": 0.55, "width": 0.05,
            "title_font_size": 16, "label_font_size": 13, "n_labels": 5, "fmt": "%.2f", "color": "white"}


def _part(surf, finite: np.ndarray):
    """``surf`` without the cells touching rays that have no material (``finite`` (nv, nu)
    False): the part's surface only, no floor drawn round it."""
    if finite.all() or not finite.any():
        return surf
    inner = surf.extract_points(finite.T.reshape(-1, order="F"), adjacent_cells=False)
    try:
        return inner.extract_surface(algorithm="dataset_surface")
    except TypeError:  # older pyvista without the keyword
        return inner.extract_surface()


def stage_plotter(pics, stage: int, window_size=(800, 800), off_screen: bool = True, focus=None,
                  half_mm: float | None = None, show_tool: bool = True):
    """A pyvista plotter of ``stage`` of a run (``pics``: a
    :class:`monitor.render.runpicture.RunPictures`): the part (the cropped model as a
    surface) coloured by the deviation map with a colour bar in mm (else by depth of
    cut), the path near the stage (feeds cyan, rapids magenta), tool and holder at their
    pose, findings labelled with their line, an axis triad at the work origin, mm axes
    along the part's bounds, and the stage, line and time written in a corner. The
    camera frames the whole part, or the ``half_mm`` around world point ``focus``."""
    pv = _pv()
    if off_screen:
        quiet_vtk()
    heights, _ = pics.view.state_at(stage)
    h = np.ascontiguousarray(pics.crop(heights), np.float64)
    frame = pics.frame
    floor = float(np.nanmin(pics.stock_top)) if np.isfinite(pics.stock_top).any() else 0.0
    surf = heightfield(frame, h, floor=floor)
    pl = pv.Plotter(off_screen=off_screen, window_size=list(window_size))
    pl.set_background("#1c1e24")
    errors = pics.errors(h.astype(np.float32))
    finite = np.isfinite(h)
    if errors is not None:
        cmap, clim = deviation_cmap(pics.tol)
        e = np.clip(np.nan_to_num(errors, nan=0.0, posinf=pics.tol.interest), -pics.tol.interest,
                    pics.tol.interest)
        surf.point_data["deviation (mm)"] = e.T.reshape(-1, order="F")
        part = _part(surf, finite)
        pl.add_mesh(part, scalars="deviation (mm)", cmap=cmap, clim=clim, n_colors=cmap.N, smooth_shading=True,
                    show_scalar_bar=True, scalar_bar_args={**BAR_ARGS, "title": "deviation (mm)\n"})
    else:
        with np.errstate(invalid="ignore"):
            depth = np.clip(np.nan_to_num(pics.stock_top - h, nan=0.0), 0, None)
        top = float(max(depth.max(), 1e-3))
        surf.point_data["depth of cut (mm)"] = depth.T.reshape(-1, order="F")
        part = _part(surf, finite)
        pl.add_mesh(part, scalars="depth of cut (mm)", cmap="viridis_r", clim=(0.0, top), smooth_shading=True,
                    show_scalar_bar=True, scalar_bar_args={**BAR_ARGS, "title": "depth of cut (mm)\n"})
    status, tip, row = pics.status(stage)
    path = pics.path_near(row)
    if path is not None and len(path["start"]):
        for rapid, color, width in ((False, "cyan", 2), (True, "magenta", 1)):
            sel = path["rapid"] == rapid
            if sel.any():
                seg = np.stack([path["start"][sel], path["end"][sel]], axis=1).reshape(-1, 3)
                pl.add_mesh(pv.line_segments_from_points(seg), color=color, line_width=width)
    if show_tool and pics.live.tool is not None and tip is not None:
        for mesh, col in tool_meshes(pics.live.tool, tip):
            pl.add_mesh(mesh, color=col, smooth_shading=True, opacity=0.9)
    if pics.marks:
        from monitor.render.live import finding_label

        pts = np.array([m["position"] for m in pics.marks], np.float64).reshape(-1, 3)
        pl.add_point_labels(pts, [finding_label(m) for m in pics.marks], point_color="red", point_size=14,
                            render_points_as_spheres=True, text_color="red", font_size=14, shape_color="#101014",
                            shape_opacity=0.7, always_visible=True)
    size = max(frame.nu, frame.nv) * frame.spacing
    arm = 0.12 * size
    for d, col in ((np.array([1.0, 0, 0]), "red"), (np.array([0, 1.0, 0]), "lime"), (np.array([0, 0, 1.0]), "dodgerblue")):
        pl.add_mesh(pv.Arrow(start=(0, 0, 0), direction=d, scale=arm, tip_length=0.2, shaft_radius=0.03),
                    color=col)
    pl.add_axes(line_width=3, labels_off=False)
    b = part.bounds
    pl.show_bounds(bounds=b, xtitle="X mm", ytitle="Y mm", ztitle="Z mm", n_xlabels=4, n_ylabels=4, n_zlabels=3,
                   fmt="%.0f", color="white", font_size=10, location="outer")
    words = [f"stage {stage}"]
    if status.get("line"):
        words.append(f"line {status['line']}")
    if status.get("time") is not None:
        words.append(f"{status['time']:.1f} s")
    if status.get("tool"):
        words.append(status["tool"].lower())
    pl.add_text("   ".join(words), position="upper_left", font_size=11, color="white")
    # from the front left and above: X runs to the right, Y away, the work origin in front
    pl.camera_position = [(-0.45, -1.0, 0.95), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)]
    if focus is not None and half_mm:
        c = np.asarray(focus, np.float64).reshape(3)
        pl.reset_camera(bounds=[c[0] - half_mm, c[0] + half_mm, c[1] - half_mm, c[1] + half_mm,
                                c[2] - half_mm / 2, c[2] + half_mm / 2])
    else:
        pl.reset_camera(bounds=b)
    pl.camera.zoom(0.95)   # room for the axes labels round the part
    return pl


def stage_png(pics, stage: int, window_size=(800, 800), path_out=None, **kw) -> np.ndarray:
    """Render :func:`stage_plotter` offscreen; the RGB uint8 image (written to ``path_out``)."""
    pl = stage_plotter(pics, stage, window_size=window_size, off_screen=True, **kw)
    try:
        img = pl.screenshot(path_out if path_out else None, return_img=True)
    finally:
        pl.close()
    return np.asarray(img)[..., :3].astype(np.uint8)
