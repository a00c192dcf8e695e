"""pyvista 3-D views of a recorded run: the part coloured by the deviation map (else depth
of cut) with its colour bar in mm, the tool and holder as solids of revolution, the path
near the stage, findings labelled with their lines, an axis triad and mm axes; offscreen
PNG and an interactive window with a stage slider. And the closed surface of a part (a
tri-dexel model's, :mod:`sim.tridexel_surface`) coloured by the move that made each face.
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


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or os.name == "nt"


def interactive(pics):
    """A window on the run (``pics``: a :class:`monitor.render.runpicture.RunPictures`)
    with a slider over its stages, each drawn as :func:`stage_plotter` draws it (needs a
    display)."""
    if not has_display():
        raise InputError("no display for an interactive window ($DISPLAY is not set); "
                         "use --png / --gif instead", "--view")
    pv = _pv()
    first, last = pics.view.first_stage, pics.view.last_stage
    pl = pv.Plotter(off_screen=False)
    pl.set_background("#1c1e24")
    add_stage(pl, pics, last)
    pl.add_axes(line_width=3, labels_off=False)
    frame_camera(pl, pics)

    def show(value):
        camera = pl.camera_position
        pl.clear_actors()
        add_stage(pl, pics, int(round(value)))
        pl.camera_position = camera   # the user's view stays while sliding
        pl.render()

    pl.add_slider_widget(show, [first, last], value=last, title="stage", fmt="%.0f")
    pl.show()


def deviation_cmap(tol, n: int = 4001):
    """A matplotlib colormap of the deviation map (:mod:`.meaning`) over [-interest,
    +interest] mm, and that range."""
    from matplotlib.colors import ListedColormap

    from monitor.render.meaning import deviation_colors

    e = np.linspace(-tol.interest, tol.interest, n)
    return ListedColormap(deviation_colors(e, tol) / 255.0), (-tol.interest, tol.interest)


def bar_args(title: str, width_px: int) -> dict:
    """The colour bar: vertical on the right, its title on a line of its own above the
    numbers (never over them), fonts and place scaled to the window's ``width_px`` so the
    title stays inside it and the numbers clear of the part."""
    title_pt = int(np.clip(width_px / 50, 9, 16))
    # the title is centred over the bar: keep half its width (about 0.6 em a letter) inside
    half_title = 0.3 * title_pt * len(title) / width_px
    x = min(0.9, 1.0 - half_title - 0.03)
    return {"vertical": True, "position_x": x, "position_y": 0.3, "height": 0.5, "width": 0.035,
            "title_font_size": title_pt, "label_font_size": int(np.clip(width_px / 62, 8, 13)), "n_labels": 5,
            "fmt": "%.2f", "color": "white", "title": title + "\n"}


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
    pl = pv.Plotter(off_screen=off_screen, window_size=list(window_size))
    pl.set_background("#1c1e24")
    add_stage(pl, pics, stage, show_tool=show_tool)
    pl.add_axes(line_width=3, labels_off=False)
    frame_camera(pl, pics, focus, half_mm)
    return pl


def frame_camera(pl, pics, focus=None, half_mm: float | None = None) -> None:
    """Look from the front left and above (X to the right, Y away, the work origin in
    front) at the whole part, or at the ``half_mm`` round world point ``focus``."""
    pl.camera_position = [(-0.45, -1.0, 0.95), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)]
    if focus is not None and half_mm:
        c = np.asarray(focus, np.float64).reshape(3)
        pl.reset_camera(bounds=[c[0] - half_mm, c[0] + half_mm, c[1] - half_mm, c[1] + half_mm,
                                c[2] - half_mm / 2, c[2] + half_mm / 2])
    else:
        # the stock's footprint (not the crop's margin round it) and its top
        f = pics.frame
        has = np.isfinite(pics.stock_top)
        j, i = np.nonzero(has) if has.any() else (np.array([0, f.nv - 1]), np.array([0, f.nu - 1]))
        z = pics.stock_top[has]
        z1 = float(z.max()) if z.size else 0.0
        x0, y0 = f.origin[0] + i.min() * f.spacing, f.origin[1] + j.min() * f.spacing
        x1, y1 = f.origin[0] + i.max() * f.spacing, f.origin[1] + j.max() * f.spacing
        pl.reset_camera(bounds=[x0, x1, y0, y1, z1 - 0.1 * max(x1 - x0, y1 - y0), z1])
    pl.camera.zoom(0.92)
    # the part left of the colour bar (the projection's centre moved right of the view's)
    pl.camera.SetWindowCenter(0.08, 0.0)


def add_stage(pl, pics, stage: int, show_tool: bool = True) -> None:
    """Add ``stage`` of the run to plotter ``pl`` (see :func:`stage_plotter`)."""
    pv = _pv()
    heights, _ = pics.view.state_at(stage)
    h = np.ascontiguousarray(pics.crop(heights), np.float64)
    frame = pics.frame
    floor = float(np.nanmin(pics.stock_top)) if np.isfinite(pics.stock_top).any() else 0.0
    surf = heightfield(frame, h, floor=floor)
    errors = pics.errors(h.astype(np.float32))
    finite = np.isfinite(h)
    if errors is not None:
        cmap, clim = deviation_cmap(pics.tol)
        e = np.clip(np.nan_to_num(errors, nan=0.0, posinf=pics.tol.interest), -pics.tol.interest,
                    pics.tol.interest)
        surf.point_data["deviation (mm)"] = e.T.reshape(-1, order="F")
        part = _part(surf, finite)
        pl.add_mesh(part, scalars="deviation (mm)", cmap=cmap, clim=clim, n_colors=cmap.N, smooth_shading=True,
                    show_scalar_bar=True, scalar_bar_args=bar_args("deviation (mm)", pl.window_size[0]))
    else:
        with np.errstate(invalid="ignore"):
            depth = np.clip(np.nan_to_num(pics.stock_top - h, nan=0.0), 0, None)
        top = float(max(depth.max(), 1e-3))
        surf.point_data["depth of cut (mm)"] = depth.T.reshape(-1, order="F")
        part = _part(surf, finite)
        pl.add_mesh(part, scalars="depth of cut (mm)", cmap="viridis_r", clim=(0.0, top), smooth_shading=True,
                    show_scalar_bar=True, scalar_bar_args=bar_args("depth of cut (mm)", pl.window_size[0]))
    status, tip, row = pics.status(stage)
    from monitor.render.runpicture import path_near

    path = path_near(pics.moves, row)
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
    # the work origin: X red, Y green, Z blue
    for d, col in (((1.0, 0, 0), "red"), ((0, 1.0, 0), "lime"), ((0, 0, 1.0), "dodgerblue")):
        pl.add_mesh(pv.Arrow(start=(0, 0, 0), direction=d, scale=arm, tip_length=0.2, shaft_radius=0.03),
                    color=col)
    b = part.bounds
    # X and Y rulers in mm (Z's would stand by the colour bar; the depth is in its numbers)
    pl.show_bounds(bounds=b, xtitle="X mm", ytitle="Y mm", ztitle="", n_xlabels=4, n_ylabels=4, show_zaxis=False,
                   show_zlabels=False, fmt="%.0f", color="white", font_size=10, location="outer")
    words = [f"stage {stage}"]
    if status.get("line"):
        words.append(f"line {status['line']}")
    if status.get("time") is not None:
        words.append(f"{status['time']:.1f} s")
    if status.get("tool"):
        words.append(status["tool"].lower())
    pl.add_text("   ".join(words), position="upper_left", font_size=11, color="white", name="status")


def stage_png(pics, stage: int, window_size=(800, 800), path_out=None, **kw) -> np.ndarray:
    """Render :func:`stage_plotter` offscreen; the RGB uint8 image (written to ``path_out``)."""
    pl = stage_plotter(pics, stage, window_size=window_size, off_screen=True, **kw)
    try:
        img = pl.screenshot(path_out if path_out else None, return_img=True)
    finally:
        pl.close()
    return np.asarray(img)[..., :3].astype(np.uint8)


def part_polydata(mesh):
    """A ``pv.PolyData`` of a closed part surface (a ``trimesh.Trimesh`` in world mm, as
    :func:`sim.tridexel_surface.tridexel_mesh` gives), its ``move_id`` face attribute
    kept as cell data and as ``rgb`` colours: the stock grey, each move its colour of
    :func:`monitor.render.shaded.id_palette` (``id % size``, as the top view colours)."""
    from monitor.render.shaded import id_palette

    pv = _pv()
    faces = np.asarray(mesh.faces, np.int64)
    cells = np.column_stack([np.full(len(faces), 3, np.int64), faces]).ravel()
    poly = pv.PolyData(np.asarray(mesh.vertices, np.float64), cells)
    ids = np.asarray(mesh.face_attributes.get("move_id", np.zeros(len(faces))), np.int64)
    pal = id_palette()
    poly.cell_data["move_id"] = ids
    poly.cell_data["rgb"] = pal[ids % len(pal)]
    return poly


def part_plotter(mesh_or_model, window_size=(800, 800), off_screen: bool = True, title: str = ""):
    """A pyvista plotter of a part's closed surface seen from the front left and above,
    faces coloured by the move that made them (:func:`part_polydata`), with an axis
    triad and X Y Z rulers in mm. ``mesh_or_model``: a ``trimesh.Trimesh`` or a
    :class:`sim.tridexel.TriDexel` (its surface is extracted here). Nothing depends on
    a view direction: every face the model holds is drawn, side walls and undercuts too."""
    mesh = mesh_or_model
    if hasattr(mesh_or_model, "grids"):
        from sim.tridexel_surface import tridexel_mesh

        mesh = tridexel_mesh(mesh_or_model)
    if len(mesh.faces) == 0:
        raise InputError("the model holds no material; nothing to draw")
    pv = _pv()
    if off_screen:
        quiet_vtk()
    pl = pv.Plotter(off_screen=off_screen, window_size=list(window_size))
    pl.set_background("#1c1e24")
    poly = part_polydata(mesh)
    pl.add_mesh(poly, scalars="rgb", rgb=True, smooth_shading=False)
    pl.add_axes(line_width=3, labels_off=False)
    pl.show_bounds(bounds=poly.bounds, xtitle="X mm", ytitle="Y mm", ztitle="Z mm", n_xlabels=4, n_ylabels=4,
                   n_zlabels=3, fmt="%.0f", color="white", font_size=10, location="outer")
    if title:
        pl.add_text(title, position="upper_left", font_size=11, color="white", name="title")
    pl.camera_position = [(-0.45, -1.0, 0.95), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)]
    pl.reset_camera(bounds=poly.bounds)
    pl.camera.zoom(0.9)
    return pl


def part_png(mesh_or_model, window_size=(800, 800), path_out=None, title: str = "") -> np.ndarray:
    """Render :func:`part_plotter` offscreen; the RGB uint8 image (written to ``path_out``)."""
    pl = part_plotter(mesh_or_model, window_size=window_size, off_screen=True, title=title)
    try:
        img = pl.screenshot(path_out if path_out else None, return_img=True)
    finally:
        pl.close()
    return np.asarray(img)[..., :3].astype(np.uint8)
