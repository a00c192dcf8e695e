"""dexmon's interpreter against LinuxCNC's ``rs274`` on whole program collections.

    python bench/rs274_diff.py [--set package|corpus|tests|all] [--record] [--jobs N] [-v]

For every program: rs274 and dexmon run with the same tool table, parameter file and
subroutine folder (tests/sim/gcode/rs274_harness.py), their motion end points are compared,
and one JSON line per program is printed with ``-v``; the last line is the summary
(programs, accepted by each, matching, refused alike, differing). ``--record`` writes
rs274's canon output of the tests and corpus programs to ``tests/data/rs274/canon/``
for the tests (the package's programs are compared live: without the package they are absent).

Sets: ``package`` the .ngc files of Debian's linuxcnc-uspace (needs it installed), ``corpus``
../shared/corpus/gcode, ``tests`` tests/data/rs274/programs.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.sim.gcode import rs274_harness as h  # noqa: E402

def one(case: h.Case, record: bool) -> dict:
    text = h.run_rs274(case.path, case.tools, case.params)
    if record and not case.name.startswith("package/"):
        case.recording.parent.mkdir(parents=True, exist_ok=True)
        h.write_recording(case.recording, text)
    ref = h.parse_canon(text)
    try:
        got = h.dexmon_run(case.path, case.tools, case.params)
    except Exception as exc:  # a crash is a finding of this bench, not its end
        got = h.Run([], error=f"dexmon crashed: {type(exc).__name__}: {exc}", error_text="<crash>")
    res = h.compare(ref, got)
    return dict(name=case.name, status=res.status, detail=res.detail, motions=res.count,
                rs274_refuses=ref.error is not None, dexmon_refuses=got.error is not None)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", default="all", choices=("package", "corpus", "tests", "all"))
    ap.add_argument("--record", action="store_true", help="write rs274's output to tests/data/rs274/canon")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--only", help="substring of the program names to run")
    ap.add_argument("-v", "--verbose", action="store_true", help="one JSON line per program")
    args = ap.parse_args(argv)
    if h.RS274 is None:
        print(json.dumps({"skipped": "rs274 is not on the PATH (apt-get install linuxcnc-uspace)"}))
        return 0
    progs = [c for c in h.cases(args.set) if not args.only or args.only in c.name]
    with concurrent.futures.ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(one, progs, [args.record] * len(progs)))
    for r in results:
        if args.verbose or r["status"] not in ("match", "both_refuse", "by_design"):
            print(json.dumps(r))
    count = {k: sum(r["status"] == k for r in results) for k in ("match", "both_refuse", "by_design", "differ", "refuse_differs")}
    print(json.dumps({"programs": len(results),
                      "rs274_accepts": sum(not r["rs274_refuses"] for r in results),
                      "dexmon_accepts": sum(not r["dexmon_refuses"] for r in results),
                      **count}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
