"""The tri-dexel cut (:class:`sim.tridexel.TriCutter`: the X, Y and Z grids of one model)
beside the single-direction cut (the Z grid alone, :class:`sim.cut.Cutter`) of the same
program, in the same process.

Rows (one JSON line each, with ``os.getloadavg()``):

* ``3axis``: a prefix of ``<shared>/bench/wavy_finish.nc`` (6 mm ball on the 100 x 100 x
  20 box; skipped with a message when the shared folder is absent) at a coarser spacing
  than ``sim_bench`` so that the row takes well under a minute. ``ratio``: tri-dexel
  seconds / Z-grid seconds, median of interleaved pairs (the Z grid has the exact sweep,
  the X and Y grids instances of motion); ``moves_per_s`` of each; ``threads_gain``:
  the tri-dexel cut on one thread / on ``--threads`` (each grid on bands of rows, the
  default), and ``grids_at_once_gain`` the same with the three grids cut at the same
  time instead, medians of interleaved triples; ``seconds_by_grid``: each grid cut
  alone on one thread.
* ``4axis`` / ``5axis``: the programs of ``bench/rotary_bench.py`` (a wrapped finishing pass
  on an A axis; a head-head raster tilting B) on tri-dexel stock: ``instances`` (poses
  per grid), ``instances_per_s`` (poses cut into all three grids per second), and the
  ratio to the same rotary cut of the Z grid alone.

    python bench/tridexel_bench.py [--shared ../shared] [--spacing 0.5] [--moves 4000]
                                   [--pairs 3] [--threads N]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path


sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.rotary_bench import five_axis, four_axis, instance_count  # noqa: E402
from sim import bands  # noqa: E402
from sim.cut import Cutter  # noqa: E402
from sim.gcode import load_program  # noqa: E402
from sim.tools import parse_tool_spec  # noqa: E402
from sim.tridexel import AXES, TriCutter, TriDexel  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
WAVY = ("bench/wavy_finish.nc", "ball:6:L=20")
WAVY_STOCK = ((0.0, 0.0, 0.0), (100.0, 100.0, 20.0))
ROTARY_SPACING = 0.25


def _loadavg() -> list[float]:
    return [round(v, 2) for v in os.getloadavg()]


def _timed(call) -> float:
    t0 = time.perf_counter()
    call()
    return time.perf_counter() - t0


def _runs(calls, rounds: int) -> list[list[float]]:
    """Seconds of each of ``calls`` run in turn, ``rounds`` times (interleaved)."""
    out = [[] for _ in calls]
    for _ in range(rounds):
        for got, call in zip(out, calls):
            got.append(_timed(call))
    return out


def _pairs(first, second, pairs: int) -> tuple[list[float], list[float]]:
    """Seconds of ``first()`` and ``second()`` run alternately ``pairs`` times."""
    a, b = _runs((first, second), pairs)
    return a, b


def _ratio(a: list[float], b: list[float]) -> float:
    return round(statistics.median(x / y for x, y in zip(a, b)), 2)


def three_axis(shared: Path, spacing: float, n_moves: int, pairs: int, threads: int) -> dict:
    moves = load_program(shared / WAVY[0]).moves[:n_moves]
    tool = parse_tool_spec(WAVY[1])
    stock = TriDexel.box(*WAVY_STOCK, spacing)
    for t in (1, threads):  # compile (or load) every kernel the timed runs use
        TriCutter(stock.copy(), tool, threads=t, grids_at_once=True).cut_moves(moves[:50])
        TriCutter(stock.copy(), tool, threads=t).cut_moves(moves[:50])
    Cutter(stock.grids["z"].copy(), tool, threads=threads).cut_moves(moves[:50], record_changes=False)

    def tri(t, at_once=False):
        return lambda: TriCutter(stock.copy(), tool, threads=t, grids_at_once=at_once).cut_moves(moves)

    def z_alone():
        Cutter(stock.grids["z"].copy(), tool, threads=threads).cut_moves(moves, record_changes=False)

    tri_s, z_s = _pairs(tri(threads), z_alone, pairs)
    one_s, many_s, at_once_s = _runs((tri(1), tri(threads), tri(threads, True)), pairs)
    by_grid = {}
    for a in AXES:
        c = Cutter(stock.grids[a].copy(), tool, threads=1)
        by_grid[a] = round(_timed(lambda: c.cut_moves(moves, record_changes=False)), 3)
    tri_med, z_med = statistics.median(tri_s), statistics.median(z_s)
    return {"bench": "tridexel", "program": "3axis", "source": WAVY[0], "tool": tool.kind,
            "moves": int(len(moves)), "spacing_mm": spacing, "lattice": list(stock.shape),
            "tri_s": round(tri_med, 3), "z_s": round(z_med, 3), "ratio": _ratio(tri_s, z_s),
            "tri_moves_per_s": round(len(moves) / tri_med), "z_moves_per_s": round(len(moves) / z_med),
            "threads_gain": _ratio(one_s, many_s), "grids_at_once_gain": _ratio(one_s, at_once_s),
            "seconds_by_grid": by_grid,
            "threads": threads, "pairs": pairs, "loadavg": _loadavg()}


def _rotary_stock(name: str) -> TriDexel:
    """The stock of rotary_bench's program ``name`` on a tri-dexel lattice."""
    if name == "4axis":  # the 30 mm bar, 60 long, on the A axis
        return TriDexel.cylinder(0.0, 60.0, 15.0, ROTARY_SPACING)
    return TriDexel.box((-5, -5, -10), (29, 29, 0), ROTARY_SPACING)


def rotary(case, pairs: int, threads: int) -> dict:
    name, kin, tool, _, moves = case
    stock = _rotary_stock(name)
    TriCutter(stock.copy(), tool, kinematics=kin, threads=threads).cut_moves(moves[:4])
    count = instance_count(Cutter(stock.grids["x"], tool, kinematics=kin), moves)

    def tri():
        TriCutter(stock.copy(), tool, kinematics=kin, threads=threads).cut_moves(moves)

    def z_alone():
        Cutter(stock.grids["z"].copy(), tool, kinematics=kin, threads=threads).cut_moves(
            moves, record_changes=False)

    tri_s, z_s = _pairs(tri, z_alone, pairs)
    tri_med = statistics.median(tri_s)
    return {"bench": "tridexel", "program": name, "kinematics": kin.name, "tool": tool.kind,
            "moves": int(len(moves)), "instances": count, "spacing_mm": ROTARY_SPACING,
            "lattice": list(stock.shape), "tri_s": round(tri_med, 3),
            "instances_per_s": round(count / tri_med), "z_s": round(statistics.median(z_s), 3),
            "ratio": _ratio(tri_s, z_s), "threads": threads, "pairs": pairs, "loadavg": _loadavg()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared")
    ap.add_argument("--spacing", type=float, default=0.5, help="3-axis lattice spacing, mm")
    ap.add_argument("--moves", type=int, default=4000, help="3-axis program prefix, rows")
    ap.add_argument("--pairs", type=int, default=3)
    ap.add_argument("--threads", type=int, default=bands.default_threads())
    args = ap.parse_args(argv)
    if (args.shared / WAVY[0]).is_file():
        print(json.dumps(three_axis(args.shared, args.spacing, args.moves, args.pairs, args.threads)),
              flush=True)
    else:
        print(json.dumps({"bench": "tridexel", "program": "3axis",
                          "skipped": f"{args.shared / WAVY[0]} not found (pass --shared)"}), flush=True)
    for case in (four_axis(), five_axis()):
        print(json.dumps(rotary(case, args.pairs, args.threads)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
