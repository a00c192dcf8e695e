"""Fuzz the live path with late polls: dry runs whose polls come at random intervals.

On the wall clock a busy computer polls late: the machine runs seconds of the program
between two states. A monitor must judge the same path however the polls fall. Each job
here runs once on the simulated clock with regular polls, then ``--seeds`` times with the
machine time between polls drawn at random (0.2 to 30 times the regular step, a few long
stalls among mostly regular ones); every run must report the same findings, by kind and
line, as the regular one. (It found a look-ahead restarted from the live model before a
late poll's path was cut in: a false rapid into stock, see ``tests/monitor/
test_multi_fixture.py``.)

    python bench/poll_jitter_fuzz.py [--seeds 40] [--speed 10]

Prints one JSON line per job (the regular run's findings, the seeds that differed and
how) and a final one with the totals. Jobs: the bundled example (its two planted faults)
and the two multi-fixture jobs of ``tests/data/fixtures2`` (clean).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

#: the regular step's multiples the late polls are drawn from (most polls are on time)
STALLS = (1.0, 1.0, 1.0, 3.0, 8.0, 20.0)


def jobs(tmp: Path) -> dict[str, list[str]]:
    """name -> the ``dexmon dry-run`` arguments of each job."""
    from monitor.commands.dry_run import EXAMPLE_JOB

    data = ROOT / "tests" / "data" / "fixtures2"
    near = tmp / "near.var"
    near.write_text("5221 -200\n5222 -100\n5223 -50\n5241 -180\n5242 -100\n5243 -50\n")  # G55 = G54 + 20
    return {"bundled example": [str(EXAMPLE_JOB)],
            "two stations": [str(data / "two_station.toml"), "--var", str(near)],
            "g92 shift": [str(data / "g92.toml")]}


def findings_of(args: list[str], speed: float, run: Path, rng) -> list[tuple[str, int]]:
    """The (kind, line) findings of one dry run; polls at random intervals when ``rng``."""
    from drivers.virtual.controller import VirtualController
    from monitor.cli import main

    poll = VirtualController.poll

    def late_poll(self):
        self.speed = speed * float(rng.choice(STALLS)) * float(rng.uniform(0.2, 1.5))
        return poll(self)
    if rng is not None:
        VirtualController.poll = late_poll
    out = io.StringIO()
    try:
        with contextlib.redirect_stdout(out):
            main(["dry-run", *args, "--speed", str(speed), "--clock", "sim", "--json", "--run", str(run)])
    finally:
        VirtualController.poll = poll
        run.unlink(missing_ok=True)
    events = [json.loads(x) for x in out.getvalue().splitlines()]
    return sorted({(e["kind"], int(e["line"])) for e in events if e["event"] == "finding"})


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=40, help="late-poll runs per job (default 40)")
    ap.add_argument("--speed", type=float, default=10.0, help="simulated s per poll period (default 10)")
    a = ap.parse_args(argv)
    total = differed = 0
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name, args in jobs(tmp).items():
            regular = findings_of(args, a.speed, tmp / "run.sqlite", None)
            diffs = {}
            for seed in range(a.seeds):
                got = findings_of(args, a.speed, tmp / "run.sqlite", np.random.default_rng(seed))
                if got != regular:
                    diffs[seed] = got
            total += a.seeds
            differed += len(diffs)
            print(json.dumps({"bench": "poll_jitter_fuzz", "job": name, "findings": regular, "seeds": a.seeds,
                              "differed": len(diffs), "examples": dict(list(diffs.items())[:5])}), flush=True)
    print(json.dumps({"bench": "poll_jitter_fuzz", "runs": total, "differed": differed}), flush=True)
    return 1 if differed else 0


if __name__ == "__main__":
    sys.exit(main())
