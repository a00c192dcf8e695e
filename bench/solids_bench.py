"""Solids benchmark: mesh ray casting, Booleans and surface extraction on ~1M-ray grids.

    .venv/bin/python bench/solids_bench.py [--shared ../shared] [--rays 1000000] [--nodes 1000000]

Prints one JSON line per case: ``case``, ``seconds`` (best of ``--repeat`` warm runs;
numba compilation is done by a first untimed call), ``rays``, ``segments`` or ``faces``
where it applies, and ``peak_rss_mb`` of the process so far. Corpus cases are skipped
(with a JSON line saying so) when the corpus is absent.

``tridexel_mesh cut box``: the closed surface of a tri-dexel model of the same cut box on
a lattice of ~``--nodes`` nodes (:mod:`sim.tridexel_surface`), its triangles, and
``ratio_to_z_surface``: its seconds over the column surface of the model's own Z grid
(``surface_mesh``), median of interleaved pairs, with ``load`` (``os.getloadavg()``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import statistics
import time
from pathlib import Path

import trimesh

from sim.boolean import difference, intersection, overlap_length, union
from sim.frame import Frame
from sim.solids import box_grid, cylinder_grid, heightfield_grid, mesh_grid
from sim.surface import heightfield_mesh, surface_mesh
from sim.tridexel import TriDexel
from sim.tridexel_surface import tridexel_mesh


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _best(fn, repeat):
    fn()  # compile / warm caches
    best = math.inf
    out = None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def _emit(case, seconds, rays, **extra):
    print(json.dumps({"case": case, "seconds": round(seconds, 4), "rays": int(rays), **extra,
                      "peak_rss_mb": round(_rss_mb(), 1)}), flush=True)


def _frame_over(bounds, n_rays):
    (x0, y0, _), (x1, y1, _) = bounds
    spacing = math.sqrt((x1 - x0) * (y1 - y0) / n_rays)
    return Frame.top(x0, y0, x1, y1, spacing)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", default=str(Path(__file__).resolve().parents[2] / "shared"))
    ap.add_argument("--rays", type=int, default=1_000_000)
    ap.add_argument("--nodes", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    parts = Path(args.shared) / "corpus" / "parts"

    for name in ("sphere_on_plate.stl", "carpet1.stl"):
        path = parts / name
        if not path.is_file():
            print(json.dumps({"case": f"cast {name}", "skipped": f"{path} not found"}))
            continue
        mesh = trimesh.load(path, force="mesh")
        f = _frame_over(mesh.bounds, args.rays)
        if mesh.is_watertight:
            secs, g = _best(lambda: mesh_grid(f, mesh), args.repeat)
            case = f"mesh_grid {name}"
        else:
            floor = float(mesh.bounds[0, 2])
            secs, g = _best(lambda: heightfield_grid(f, mesh, floor), args.repeat)
            case = f"heightfield_grid {name}"
        _emit(case, secs, f.n_rays, triangles=len(mesh.faces), spacing_mm=round(f.spacing, 4),
              segments=int(g.counts.sum()))

    f = Frame.top(-50, -50, 50, 50, 100 / (math.sqrt(args.rays) - 1))
    stock = box_grid(f, (-45, -45, -10), (45, 45, 0))
    tool = cylinder_grid(f, (0, 0, -4), (0.2, 0.1, 1), 30, 20, face_id=7)
    bar = cylinder_grid(f, (-60, 5, -6), (1, 0, 0), 3, 120, face_id=8)
    for fn in (union, intersection, difference, overlap_length):
        secs, _ = _best(lambda: fn(stock, tool), args.repeat)
        _emit(fn.__name__, secs, f.n_rays)
    cut = difference(difference(stock, tool), bar)
    secs, m = _best(lambda: surface_mesh(cut), 1)
    _emit("surface_mesh cut box", secs, f.n_rays, faces=len(m.faces),
          multi_segment_rays=int((cut.counts > 1).sum()))
    secs, m = _best(lambda: heightfield_mesh(cut), 1)
    _emit("heightfield_mesh cut box", secs, f.n_rays, faces=len(m.faces))
    _tridexel_case(args.nodes, args.repeat)


def _cut_box(f):
    """The cut box above on any frame: a stock less a tilted cylinder and a bar along X."""
    stock = box_grid(f, (-45, -45, -10), (45, 45, 0))
    tool = cylinder_grid(f, (0, 0, -4), (0.2, 0.1, 1), 30, 20, face_id=7)
    bar = cylinder_grid(f, (-60, 5, -6), (1, 0, 0), 3, 120, face_id=8)
    return difference(difference(stock, tool), bar)


def _tridexel_case(nodes: int, repeat: int) -> None:
    lo, hi = (-46, -46, -11), (46, 46, 1)
    spacing = (92 * 92 * 12 / nodes) ** (1 / 3)
    model = TriDexel.build(lo, hi, spacing, _cut_box)
    tridexel_mesh(model)  # compile
    surface_mesh(model.grids["z"])
    pairs = []
    for _ in range(max(repeat, 1)):  # interleaved: both see the same machine load
        t = time.perf_counter()
        m = tridexel_mesh(model)
        tri = time.perf_counter() - t
        t = time.perf_counter()
        surface_mesh(model.grids["z"])
        pairs.append((tri, time.perf_counter() - t))
    _emit("tridexel_mesh cut box", statistics.median(p[0] for p in pairs), model.grids["z"].frame.n_rays,
          nodes=int(math.prod(model.shape)), spacing_mm=round(spacing, 4), faces=len(m.faces),
          watertight=bool(m.is_watertight), ratio_to_z_surface=round(statistics.median(a / b for a, b in pairs), 3),
          load=[round(v, 2) for v in os.getloadavg()])


if __name__ == "__main__":
    main()
