"""A small recorded run (run file with trace, moves, cuts, findings) for replay/report tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from monitor.runfile import RunWriter
from monitor.trace_io import store_trace_chunk
from sim.gcode.moves import MoveKind, empty_moves
from sim.trace import Trace
from tests.sim.trace_helpers import ball_cut, box

#: tip path of the recorded program (work coords, mm); each leg is one move
PATH = np.array([[2.0, 2.0, 12.0], [2.0, 2.0, 8.0], [26.0, 4.0, 8.0], [26.0, 16.0, 7.0],
                 [4.0, 16.0, 6.5], [14.0, 9.0, 6.0], [14.0, 9.0, 12.0]])
STEPS = 6  # live stages per move


def program_moves() -> np.ndarray:
    n = len(PATH) - 1
    m = empty_moves(n)
    m["line"] = np.arange(n) + 10
    m["kind"] = MoveKind.FEED
    m["kind"][0] = MoveKind.RAPID
    for k in range(n):
        m["start"][k, :3] = PATH[k]
        m["end"][k, :3] = PATH[k + 1]
    m["feed"] = 600.0
    m["tool"] = 1
    return m


def record_link_trouble(w: RunWriter) -> dict:
    """States with link trouble (3 missed, 2 bad, 4 disconnected polls among 10 fresh ones)
    and the session's records of it (a reset, a gap) as a live session writes them.
    Returns the gap record."""
    from drivers.state import MachineState, RunState
    from monitor.gaps import gap_message

    kinds = [RunState.RUN] * 5 + [RunState.MISSED] * 3 + [RunState.BAD] * 2 + [RunState.DISCONNECTED] * 4 \
        + [RunState.ALARM] * 5
    for i, k in enumerate(kinds):
        w.append_state(MachineState(t=100.0 + 0.5 * i, mpos=tuple(PATH[1]), state=k,
                                    raw="" if k == RunState.RUN else "why"))
    w.append_link_event(106.0, "reset", {"event": "link", "kind": "reset",
                                         "message": "grbl:///dev/ttyUSB0: Grbl 1.1h banner"})
    gap = {"event": "gap", "t_lost": 102.5, "run_s": 2.5, "t_back": 107.0, "seconds": 4.5, "reason": "port gone",
           "polls_missed": 9, "missed": 3, "bad": 2, "disconnected": 4, "lines_lost": 2,
           "came_back": "reset: Grbl 1.1h banner", "jump_mm": 12.5, "from_line": 11,
           "resync": {"how": "lost", "line": 11, "row": 1, "progress_s": 2.0, "distance_mm": 30.0},
           "rows_cut_unchecked": []}
    gap["message"] = gap_message(gap)
    w.append_link_event(107.0, "gap", gap)
    return gap


def record_run(path, chunk_every: int = 5, stop_after: int | None = None, writer_hook=None, air_cuts: int = 0,
               link_trouble: bool = False):
    """Cut the program in small live stages, writing the run file as a session would.

    Returns ``(snapshots {stage: DexelGrid}, writer)``; the writer is closed unless
    ``stop_after`` (stages) is given, which leaves it open like a crashed session.
    ``air_cuts``: that many more recorded cuts at the end that remove nothing (a retract
    in the air: stages with no trace block), as a session records them. ``link_trouble``:
    also states and link records of a gap (:func:`record_link_trouble`).
    """
    grid = box(61, 41, 0.5, 0.0, 10.0)
    moves = program_moves()
    w = RunWriter(path, commit_interval=0.05)
    if link_trouble:
        record_link_trouble(w)
    w.put_meta("tool_spec", "ball:6")
    w.put_meta("program_path", "wave.nc")
    w.put_array("moves", moves)
    w.put_array("row_seconds", np.full(len(moves), 2.0))
    trace = Trace(grid)
    store_trace_chunk(w, trace)
    snaps = {0: grid.copy()}
    stage = 0
    for k in range(len(moves)):
        p0, p1 = PATH[k], PATH[k + 1]
        for s in range(1, STEPS + 1):
            q0 = p0 + (p1 - p0) * (s - 1) / STEPS
            q1 = p0 + (p1 - p0) * s / STEPS
            stage += 1
            rays = np.concatenate([ball_cut(grid, q, 3.0, k + 1) for q in (q0, (q0 + q1) / 2, q1)])
            trace.record(grid, rays, stage)
            snaps[stage] = grid.copy()
            w.append_cut(stage, {"p0": q0, "p1": q1}, t=stage * 0.1, move_id=k + 1, line=int(moves["line"][k]))
            if stage % chunk_every == 0:
                store_trace_chunk(w, trace)
                if writer_hook:
                    writer_hook(w, stage)
            if stop_after is not None and stage >= stop_after:
                return snaps, w
    store_trace_chunk(w, trace)
    for _ in range(air_cuts):
        stage += 1
        w.append_cut(stage, {"p0": PATH[-1], "p1": PATH[-1] + [0, 0, 5]}, t=stage * 0.1, move_id=len(moves),
                     line=int(moves["line"][-1]))
    if air_cuts:  # as a session's last chunk: the model is rebuilt up to its last stage
        store_trace_chunk(w, trace, stage_from=stage - air_cuts + 1, stage_to=stage)
    w.append_finding({"kind": "gouge", "line": 13, "lines": [13, 14], "stage": 4,
                      "position": [15.0, 16.0, 6.5], "depth": 0.4, "message": "gouge 0.400 mm deep"})
    w.append_finding({"kind": "rapid_into_stock", "line": 10, "lines": [10], "stage": 1,
                      "position": [2.0, 2.0, 8.0], "volume": 3.2, "message": "rapid through material"})
    w.close()
    return snaps, None


def record_program(run, program, design, stock, tool_spec: str = "ball:6", resolution: float = 0.5,
                   stages: int = 40) -> None:
    """Cut ``program`` into a box ``stock`` with ``tool_spec`` and write a run file: the
    job (design, tool), the move table, one trace stage and one cut record per chunk."""
    from monitor.commands.simulate import build_stock
    from monitor.runfile import RunWriter
    from monitor.trace_io import store_trace_chunk
    from sim.cut import Cutter
    from sim.gcode import load_program
    from sim.tools import parse_tool_spec
    from sim.trace import Trace

    program = Path(program)
    moves = load_program(str(program)).moves
    grid = build_stock("box:" + ",".join(map(str, stock)), resolution)
    cutter = Cutter(grid, parse_tool_spec(tool_spec))
    w = RunWriter(run)
    w.put_meta("job", f'[design]\nstl = "{design}"\n[tools.1]\nspec = "{tool_spec}"\n')
    w.put_meta("program_path", str(program))
    w.put_meta("program", program.read_text())
    w.put_array("moves", moves)
    w.put_array("row_seconds", np.full(len(moves), 0.01))
    trace = Trace(grid)
    store_trace_chunk(w, trace)
    bounds = np.linspace(0, len(moves), stages + 1).astype(int)
    for stage, (a, b) in enumerate(zip(bounds[:-1], bounds[1:]), start=1):
        res = cutter.cut_moves(moves[a:b], move_ids=np.arange(a, b) + 1)
        trace.record(grid, res.changed_rays, stage)
        end = moves["end"][b - 1, :3]
        w.append_cut(stage, {"points": np.stack([moves["start"][a, :3], end])}, t=0.01 * b, move_id=b,
                     line=int(moves["line"][b - 1]))
        store_trace_chunk(w, trace, stage_to=stage)
    w.close()
