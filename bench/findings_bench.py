"""How many findings a machinist has to read: ``dexmon simulate --json`` at its defaults on
the corpus finishing paths (../shared/corpus/parts), and with ``--dry-run`` the whole
carpet path with an 8 mm ball through ``dexmon dry-run --json`` (minutes): its findings
and the bytes of its JSON stream.

Prints one JSON line per case. Usage: python bench/findings_bench.py [SHARED_DIR] [--dry-run]
"""

from __future__ import annotations

import collections
import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from monitor.cli import main  # noqa: E402

STOCK = {"sphere_on_plate": [0, 0, -1, 76.4923, 76.4923, 30.8718], "carpet1": [0, -82, -10, 152, 66, 5.197857]}
CASES = [("sphere_on_plate", "ball:6"), ("carpet1", "ball:6"), ("carpet1", "ball:8")]


def run_cli(argv) -> tuple[int, str]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = main(argv)
    return rc, out.getvalue()


def simulate(parts: Path, part: str, tool: str, resolution: float) -> dict:
    t0 = time.perf_counter()
    rc, out = run_cli(["simulate", str(parts / f"{part}_ball6_finish.ngc"), "--stock",
                       "box:" + ",".join(map(str, STOCK[part])), "--tool", tool, "--resolution", str(resolution),
                       "--design", str(parts / f"{part}.stl"), "--json"])
    found = json.loads(out)["findings"]
    return {"case": f"simulate {part} {tool}", "resolution": resolution, "exit": rc, "findings": len(found),
            "kinds": dict(collections.Counter(f["kind"] for f in found)), "bytes": len(out),
            "wall_s": round(time.perf_counter() - t0, 2)}


def dry_run(parts: Path, tmp: Path) -> dict:
    job = tmp / "carpet8.toml"
    job.write_text(f"""resolution = 0.5
[program]
path = "{parts / 'carpet1_ball6_finish.ngc'}"
[stock]
box = {STOCK['carpet1']}
[tools]
1 = "ball:8:L=20"
[design]
stl = "{parts / 'carpet1.stl'}"
""")
    t0 = time.perf_counter()
    rc, out = run_cli(["dry-run", str(job), "--clock", "sim", "--speed", "400", "--json", "--run", str(tmp / "r.sqlite")])
    events = [json.loads(x) for x in out.splitlines()]
    return {"case": "dry-run carpet1 ball:8 (whole path)", "exit": rc,
            "findings": sum(e["event"] == "finding" for e in events),
            "updates": sum(e["event"] == "finding_update" for e in events), "json_bytes": len(out),
            "wall_s": round(time.perf_counter() - t0, 1)}


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    parts = Path(args[0] if args else ROOT.parent / "shared") / "corpus" / "parts"
    for part, tool in CASES:
        for res in (0.2, 0.4):
            print(json.dumps(simulate(parts, part, tool, res)), flush=True)
    if "--dry-run" in sys.argv:
        with tempfile.TemporaryDirectory() as d:
            print(json.dumps(dry_run(parts, Path(d))), flush=True)
