"""Compiled kernels: the interval a tool (or its swept volume) occupies on each dexel ray,
and the batch cuts that take it out of the store.

Two families:

* **Exact linear sweeps** (:mod:`.shapes`: :func:`~.shapes.linear_interval` and the row
  kernels; :mod:`.linear`: :func:`~.linear.cut_linear_batch`): rays along +Z
  (``Frame.top``), tool axis along +Z, a straight move of the tip; the swept body meets a
  vertical ray in one interval, its lowest point found in closed form (flat, ball, cone)
  or from the one root of a quartic (bull-nose).

* **Instances of motion** (:mod:`.poses`: :func:`~.poses.pose_intervals`,
  :func:`~.poses.cut_poses`): any frame, any tool axis, any profile of revolution (a
  polyline of frusta, Huang & Oliver eq. 3-5).

Both batch cuts return the statuses and resume from the state of :mod:`.batch`, log the
changed rays and their depths of cut (:mod:`.log`) and may write z-trace events as the
rays change (:mod:`.trace_sink`, which also holds the layout of the trace state).

All lengths mm. Per-ray arithmetic is float64; values written to the store are rounded
to float32 *before* comparing with the stored faces, so repeating a cut changes nothing.

Here are re-exported the names the rest of the project reads as
``sweep_kernels.NAME`` (``from sim import sweep_kernels as K``).
"""

from __future__ import annotations

from sim.sweep_kernels.batch import (DONE, STATE_SIZE, STOP_CHANGES, STOP_POOL, STOP_TRACE, TRACE_KEYFRAME,
                                     _stadium_span)
from sim.sweep_kernels.linear import _behind_cut, cut_linear_batch
from sim.sweep_kernels.log import NO_LOG, finish_move
from sim.sweep_kernels.poses import _piece_interval, cut_poses, pose_intervals
from sim.sweep_kernels.shapes import (CODE_BALL, CODE_BULL, CODE_CONE, CODE_FLAT, _rows_any, _rows_ball,
                                      _rows_bull, _rows_cone, _rows_flat, linear_fill)
from sim.sweep_kernels.trace_sink import (NO_TRACE, NO_TS, TRACE_STATE_SIZE, TS_BLK0, TS_KEY_MOVE, TS_NEED_F,
                                          TS_NEED_G, TS_NEED_GEN, TS_NEED_S, TS_NEXT_DUE, TS_NF, TS_NG, TS_NGL,
                                          TS_NR, TS_NS, TS_OPEN)

__all__ = [
    # statuses and state of a batch kernel
    "DONE", "STOP_POOL", "STOP_CHANGES", "STOP_TRACE", "TRACE_KEYFRAME", "STATE_SIZE",
    # tool shapes
    "CODE_FLAT", "CODE_BALL", "CODE_BULL", "CODE_CONE", "linear_fill",
    # the batch cuts, the change log, instances of motion
    "cut_linear_batch", "cut_poses", "finish_move", "NO_LOG", "pose_intervals",
    # the trace sink's state layout
    "NO_TRACE", "NO_TS", "TRACE_STATE_SIZE", "TS_NF", "TS_NG", "TS_NS", "TS_NGL", "TS_OPEN", "TS_NR",
    "TS_BLK0", "TS_NEXT_DUE", "TS_KEY_MOVE", "TS_NEED_F", "TS_NEED_G", "TS_NEED_S", "TS_NEED_GEN",
    # kernels the culling tests and bench/pose_bench.py call directly
    "_rows_ball", "_rows_flat", "_rows_cone", "_rows_bull", "_rows_any", "_behind_cut", "_stadium_span",
    "_piece_interval",
]
