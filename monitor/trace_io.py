"""Traces in the run file, and everything replay and report read from a finished run.

The run file (:mod:`monitor.runfile`) keeps trace chunks as rows of named raw arrays;
:func:`store_trace_chunk` appends what a :class:`sim.trace.Trace` recorded since its last
chunk, :func:`load_trace` reads them back (stopping at the first damaged or missing row, so
a run cut short or damaged replays up to its last intact stage). :class:`RunView` gathers
the rest a picture needs: frame, moves in work coordinates, stage -> move/line, findings,
tools.
"""

from __future__ import annotations

import json
from functools import cached_property
from pathlib import Path

import numpy as np

from sim.errors import InputError
from sim.trace import Trace


def store_trace_chunk(writer, trace: Trace, stage_from: int | None = None, stage_to: int | None = None) -> bool:
    """Append ``trace.take_chunk()`` to ``writer`` (a ``RunWriter``); False when nothing new.

    A chunk's ``stage_to`` says the model is rebuilt up to that stage (readers end the run
    there when its cuts go further): by default the last stage the chunk holds; ``stage_to``
    (as a session writes it) also covers later stages that removed nothing, and writes the
    chunk even when it is empty."""
    chunk = trace.take_chunk()
    if not chunk and stage_to is None:
        return False
    stages = chunk.get("z/stage", chunk.get("t/stage", np.zeros(0, np.int64)))
    lo = int(stages[0]) if stages.size else (int(stage_from) if stage_from is not None else 0)
    hi = int(stages[-1]) if stages.size else lo
    hi = hi if stage_to is None else max(hi, int(stage_to))
    writer.append_trace_chunk(lo if stage_from is None else int(stage_from), hi, chunk)
    return True


#: what decoding trace arrays that passed their checks can still raise on a damaged or
#: unchecked run file
_DECODE_ERRORS = (ValueError, IndexError, KeyError, TypeError, OverflowError, MemoryError)


def load_trace(run) -> Trace:
    """The trace of a run file (path or ``RunReader``) up to its first damaged or missing
    chunk; InputError if it recorded none, RunFileError if none is readable."""
    return _load_trace(run)[0]


def _load_trace(run) -> tuple[Trace, int]:
    """:func:`load_trace` and the last stage its chunks rebuild: their last ``stage_to``
    (stages after the last trace block that removed nothing are the same model), or the
    trace's last stage when it was cut short inside a chunk or damaged."""
    from monitor.runreader import RunReader

    reader = run if hasattr(run, "trace_chunks") else RunReader(run)
    before = len(reader.damage)
    rows = reader.trace_chunks()
    chunks = [arrays for _, _, arrays in rows]
    stopped = any(d.startswith(("trace", "table trace")) for d in reader.damage[before:])
    if not chunks:
        if stopped:
            raise reader.damaged(f"no stage can be rebuilt ({reader.damage[before]})")
        raise InputError("the run has no trace recorded (was sim.trace available when it ran?)",
                         str(reader.path))
    try:
        trace = Trace.from_chunks(chunks, where=str(reader.path))
    except _DECODE_ERRORS as exc:
        raise reader.damaged(f"its trace does not decode ({type(exc).__name__}: {str(exc)[:80]})") from exc
    if stopped and trace.z is not None:
        trace.z.truncated = True
    last = trace.last_stage
    if not trace.truncated:
        last = max(last, max(int(b) for _, b, _ in rows))
    return trace, last


class RunView:
    """What replay and report need from one run file (read lazily)."""

    def __init__(self, path):
        from monitor.runreader import RunReader

        self.path = Path(path)
        self.reader = RunReader(self.path)

    def close(self) -> None:
        self.reader.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    @property
    def damage_line(self) -> str | None:
        """One line naming what was damaged and skipped so far, or None."""
        return self.reader.damage_line()

    @cached_property
    def meta(self) -> dict:
        return self.reader.meta()

    def meta_json(self, key: str, default=None):
        text = self.meta.get(key)
        if text is None:
            return default
        try:
            return json.loads(text)
        except json.JSONDecodeError:
            return text

    @cached_property
    def _trace_and_end(self) -> tuple[Trace, int]:
        return _load_trace(self.reader)

    @property
    def trace(self) -> Trace:
        return self._trace_and_end[0]

    @property
    def frame(self):
        return self.trace.frame

    def grid_at(self, stage: int):
        """The model at ``stage`` in one grid this view reuses (overwritten by the next
        call: copy to keep): stepping between nearby stages applies only the changes."""
        buf = self.__dict__.get("_grid_buf")
        self.__dict__["_grid_buf"] = g = self.trace.grid_at(stage, out=buf)
        return g

    def state_at(self, stage: int) -> tuple[np.ndarray, np.ndarray]:
        """Heights (nv, nu) float32 mm and top face ids (nv, nu) int32 at ``stage``, in two
        arrays this view reuses (overwritten by the next call: copy to keep)."""
        buf = self.__dict__.get("_state_buf")
        if buf is None:
            n = self.frame.n_rays
            buf = self.__dict__["_state_buf"] = (np.empty(n, np.float32), np.empty(n, np.int32))
        if self.trace.t is None:
            return self.trace.state_at(stage)
        h, ids = self.trace.state_at(stage, out=buf)
        return h.reshape(self.frame.shape), ids.reshape(self.frame.shape)

    # Stages, one definition for the whole run: stage n is the model after the n-th
    # recorded cut (the session's stage counter, the ``cuts`` table), stage 0 the stock
    # when the monitor started. Cuts that removed nothing leave no trace block, so the
    # trace may end before the last cut: the model stays the same up to it, as far as the
    # trace chunks' ``stage_to`` says. A run whose cuts go past that (killed, the disk
    # full, damaged) is cut short: it ends at the last stage the trace rebuilds, never at
    # a stage it would show with an older model.
    @property
    def first_stage(self) -> int:
        return int((self.trace.z or self.trace.t).first_stage)

    @property
    def last_stage(self) -> int:
        """The last stage of the run the model is rebuilt at (every recorded cut, unless
        the run was cut short: see :attr:`cut_short`)."""
        return int(self._trace_and_end[1])

    @property
    def recorded_stage(self) -> int:
        """The last stage the run recorded (its last readable cut), whether or not the trace
        rebuilds it."""
        tab = self.stage_table
        return max(self.last_stage, int(tab["stage"].max()) if tab.size else 0)

    @property
    def cut_short(self) -> str | None:
        """None, or what replay and report say of a run cut short: ``"cut short: recorded up
        to stage N, the model rebuilds up to stage K"`` (its cuts went past its trace), or
        ``"cut short: the model rebuilds up to stage K"`` (its trace ends damaged)."""
        last, recorded = self.last_stage, self.recorded_stage
        if recorded > last:
            return f"cut short: recorded up to stage {recorded}, the model rebuilds up to stage {last}"
        if self.trace.truncated:
            return f"cut short: the model rebuilds up to stage {last}"
        return None

    def check_stage(self, stage: int, where: str = "--stage") -> int:
        """``stage`` if the run has it, else InputError naming the valid range."""
        first, last = self.first_stage, self.last_stage
        if not first <= stage <= last:
            short = self.cut_short
            end = "the last stage the model rebuilds" if short else "after the last recorded cut"
            raise InputError(f"stage must be {first}..{last} ({first}: the stock before the first cut, "
                             f"{last}: {end}), got {stage}" + (f"; the run was {short}" if short else ""), where)
        return int(stage)

    @cached_property
    def moves(self) -> np.ndarray | None:
        """The move table in the run's model frame (tip, the job's work system), or None
        when the run did not store it. Runs recorded before the frame carried
        ``reference_wco`` place each row in its own work system, as they were recorded."""
        if "moves" not in self.reader.array_names():
            return None
        from monitor.work_coords import work_moves
        from monitor.runfile import RunFileError

        try:
            moves = np.array(self.reader.get_array("moves"))
        except RunFileError:  # damaged: noted by the reader, the run replays without it
            return None
        if not {"line", "start", "end"} <= set(moves.dtype.names or ()):  # unchecked: not a move table
            self.reader.note(f"arrays moves (dtype {str(moves.dtype)[:60]}, expected the move table)")
            return None
        frame = self.meta_json("frame", {})
        ref = frame.get("reference_wco") if isinstance(frame, dict) else None
        try:
            return work_moves(moves, None if ref is None else np.asarray(ref, np.float64))
        except (ValueError, TypeError, IndexError, KeyError) as exc:  # unchecked: meta frame or moves odd
            self.reader.note(f"arrays moves (does not fit the meta frame: {type(exc).__name__})")
            return None

    @cached_property
    def row_seconds(self) -> np.ndarray | None:
        from monitor.runfile import RunFileError

        if "row_seconds" not in self.reader.array_names():
            return None
        try:
            return np.array(self.reader.get_array("row_seconds"), np.float64)
        except (RunFileError, ValueError, TypeError):  # damaged: the run replays without it
            return None

    @cached_property
    def stage_table(self) -> np.ndarray:
        """Per recorded cut: structured (stage, t, move_id, line, p0 (3,), p1 (3,)), stage order."""
        dt = np.dtype([("stage", np.int64), ("t", np.float64), ("move_id", np.int64),
                       ("line", np.int64), ("p0", np.float64, 3), ("p1", np.float64, 3)])
        rows = []
        for c in self.reader.cuts():
            a = c["arrays"]
            pts = a.get("points")  # a session's cut: the travelled polyline (k, 3)
            if pts is not None and np.size(pts) >= 3:
                pts = np.asarray(pts, np.float64).reshape(-1, 3)
                p0, p1 = pts[0], pts[-1]
            else:
                p0 = np.asarray(a.get("p0", np.full(3, np.nan)), np.float64).reshape(-1)[:3]
                p1 = np.asarray(a.get("p1", np.full(3, np.nan)), np.float64).reshape(-1)[:3]
            rows.append((c["stage"], c["t"] if c["t"] is not None else np.nan,
                         c["move_id"] if c["move_id"] is not None else -1,
                         c["line"] if c["line"] is not None else -1, p0, p1))
        return np.array(rows, dtype=dt)

    def stage_info(self, stage: int) -> dict:
        """Move id, line, time and tool tip position at a stage (what is known of them)."""
        tab = self.stage_table
        out = {"stage": int(stage)}
        if tab.size:
            k = int(np.searchsorted(tab["stage"], stage, side="right")) - 1
            if k >= 0:
                r = tab[k]
                out.update(move_id=int(r["move_id"]), line=int(r["line"]), t=float(r["t"]),
                           tip=r["p1"].copy())
        return out

    @cached_property
    def findings(self) -> list[dict]:
        return self.reader.findings()

    @cached_property
    def job(self):
        """The run's job (``monitor.job.Job``) or None: its recorded TOML with relative paths
        resolved against the run file's folder, else the program's folder (where a job file
        sits beside its program, the run recorded elsewhere), else the current folder."""
        text = self.meta.get("job")
        if not text:
            return None
        from monitor.job import parse_job_text

        program = Path(self.meta.get("program_path") or "")
        bases = [self.path.parent] + ([program.parent] if program.is_absolute() else []) + [Path.cwd()]
        for base in bases:
            try:
                return parse_job_text(text, name=f"{self.path.name}:job", base=base)
            except Exception:  # noqa: BLE001 - try the next folder; a run replays without its job
                continue
        return None

    def tool(self, number: int = 0):
        """The sim Tool for tool number ``number`` if the job names one, else None."""
        job = self.job
        spec = None
        if job is not None:
            td = job.tool(number) or job.default_tool or next(iter(job.tools.values()), None)
            spec = getattr(td, "spec", None) if td is not None else None
        spec = spec or self.meta_json("tool_spec")
        if not spec:
            return None
        try:
            from sim.tools import parse_tool_spec
            return parse_tool_spec(spec)
        except Exception:
            return None

    def removal_per_stage(self) -> tuple[np.ndarray, np.ndarray]:
        """(stages (B,) int64, removed volume (B,) mm^3) from the time-trace's surface drops.

        Exact for material taken from the top of each ray (3-axis milling); material
        removed under an overhang is not seen from above.
        """
        t = self.trace.t
        if t is None:
            return np.zeros(0, np.int64), np.zeros(0)
        return t.removal_per_block(self._bottoms)

    def _bottoms(self) -> np.ndarray:
        if self.trace.z is None:
            return np.zeros(self.frame.n_rays)
        g = self.grid_at(self.trace.z.first_stage)
        return np.nan_to_num(g.store["near"].astype(np.float64))

    def removal_per_move(self) -> dict[int, float]:
        """Removed volume per move id (mm^3), mapping stages to moves through the cuts table."""
        stages, vol = self.removal_per_stage()
        tab = self.stage_table
        if tab.size:
            k = np.searchsorted(tab["stage"], stages, side="left")
            k = np.clip(k, 0, tab.size - 1)
            move = np.where(tab["stage"][k] == stages, tab["move_id"][k], stages)
        else:
            move = stages
        out: dict[int, float] = {}
        for m, v in zip(move.tolist(), vol.tolist()):
            out[int(m)] = out.get(int(m), 0.0) + v
        return out
