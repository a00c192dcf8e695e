"""The monitor may propose, never send: corrected lines for a predicted gouge, written to a file.

``dexmon live|dry-run JOB --propose FILE``: when the look-ahead predicts a gouge, the
moves of its lines are corrected as ``dexmon correct`` would (:mod:`sim.correct`, against
the job's design) and the lines that would change are appended to FILE, each original
line followed by what would replace it, for the user to decide. Nothing is sent to the
machine and the program is not touched. A gouge that cannot be corrected (an arc, a loop)
gets its reason written instead. Lines a rotary axis turns are never proposed for: the
correction works on 3-axis lines only (:data:`sim.correct.path.TURNED_WHY`); the file and
the message name them.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np

from sim.errors import InputError


class Proposer:
    """Called by the alerter with each new predicted gouge (a finding dict); appends the
    proposal to ``path`` and returns ``{"file", "lines", "message"}`` (None when the
    finding names no line of the main program)."""

    def __init__(self, job, path):
        self.job = job
        self.path = Path(path)
        self._ready = None
        self._failed = None
        # read the program and cast the design off the monitor's loop, from the start:
        # the first proposal then only waits for what is left of it
        self._thread = threading.Thread(target=self._prepare, name="dexmon-propose", daemon=True)
        self._thread.start()

    def _prepare(self) -> None:
        from monitor.commands.correct import _to_program, setup_from_job
        from sim.correct.gouge import GougeProbe
        from sim.correct.path import correct_moves

        try:
            setup = setup_from_job(self.job)
            program, rows, moves = setup.load(setup.program_path)
            probe = GougeProbe(setup.design, setup.tol)
            correct_moves(moves[:2], probe, setup.tools, setup.tool, setup.tol)  # compiled before it is needed
            self._ready = (setup, program, rows, moves, probe, _to_program(rows, moves),
                           setup.program_path.read_bytes())
        except Exception as exc:  # said with the first proposal asked for
            self._failed = exc

    def _setup(self):
        self._thread.join()
        if self._failed is not None:
            raise self._failed
        return self._ready

    def __call__(self, finding: dict) -> dict | None:
        from sim.correct.path import TURNED_WHY, check_fixed_rows, correct_span
        from sim.correct.rewrite import rewrite_program

        setup, program, rows, moves, probe, to_prog, data = self._setup()
        lines = set(int(v) for v in (finding.get("lines") or [finding.get("line", 0)]))
        sel = np.flatnonzero((moves["file"] == 0) & np.isin(moves["line"], sorted(lines)))
        if sel.size == 0:
            return None
        name = str(setup.program_path)
        head = (f"# {time.strftime('%Y-%m-%d %H:%M:%S')} gouge predicted at line {finding.get('line')} "
                f"({float(finding.get('depth') or 0.0):.3f} mm): proposed by dexmon, NOT sent to the machine\n")
        a, b = int(sel[0]), int(sel[-1]) + 1
        corr = correct_span(moves, a, b, probe, setup.tools, setup.tool, setup.tol, **setup.turning)
        refused = [(r.row + a, r.reason) for r in check_fixed_rows(moves[a:b], probe, setup.tools, setup.tool,
                                                                   setup.tol, setup.tol.chord, **setup.turning)]
        refused += [(r.row, r.reason) for r in corr.refused]
        turned = sorted({int(moves["line"][k]) for k in sel if corr.turned[k]})
        left = f"lines {', '.join(map(str, turned))} left as written, {TURNED_WHY}" if turned else ""
        try:
            if refused:
                row, reason = min(refused)
                raise InputError(f"{reason}: correct it by hand", where=f"{name}:{int(moves['line'][row])}")
            written = rewrite_program(data, name, program, corr, to_prog, moves=rows)
        except InputError as exc:
            text = head + f"# no proposal: {exc}\n"
            changed = []
        else:
            old = data.decode("utf-8", "surrogateescape").splitlines()
            new = written.text.decode("utf-8", "surrogateescape").splitlines()
            body, k = [], 0
            shift = 0  # lines inserted above
            for ln in written.changed:
                k = ln - 1 + shift
                repl = [new[k]]
                while k + 1 < len(new) and "(dexmon: inserted for line" in new[k + 1]:
                    k += 1
                    repl.append(new[k])
                shift += len(repl) - 1
                body.append(f"line {ln}: {old[ln - 1]}\n" + "".join(f"  -> {r}\n" for r in repl))
            changed = list(written.changed)
            if not changed and turned:
                body = [f"# no proposal: {name}:{turned[0]}: {left}\n"]
            elif turned:
                body.append(f"# {left}\n")
            text = head + "".join(body)
        with open(self.path, "a", encoding="utf-8", errors="surrogateescape") as fh:
            fh.write(text)
        what = f"lines {changed}" if changed else "no correction possible"
        what += f"; {left}" if left else ""
        return {"file": str(self.path), "lines": changed,
                "message": f"proposed correction for the gouge at line {finding.get('line')} ({what}) "
                           f"written to {self.path}; nothing was sent to the machine"}
