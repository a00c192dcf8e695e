"""Machine kinematics: machine axes X Y Z A B C to the tool's tip and axis on the part, and back.

A 3-axis mill moves the tool along X Y Z and the tool axis stays +Z. A rotary axis turns
either the part (a rotary table, a 4th axis, a trunnion) or the tool (a tilting head);
then the tool's tip and axis *on the part* follow from the machine axes through the
machine's kinematics. This module holds those, array in and array out:

* :meth:`Kinematics.forward` ``(axes (n, 6) X Y Z mm A B C deg, tool_length) -> (tip (n, 3),
  axis (n, 3))`` in the workpiece frame;
* :meth:`Kinematics.inverse` ``(tip, axis, tool_length, previous) -> axes (n, 6)``, the
  solution closest to a previous pose; :meth:`Kinematics.inverse_path` along a path, each
  row near the one before (CAM cutter-location data to machine axes);
* :meth:`Kinematics.machine_xyz` ``(tip, rotary (n, 3), tool_length) -> (n, 3)``: the
  linear axes that put the tip there with the rotaries given (what a LinuxCNC TCP
  kinematics does with a program's X Y Z A B C);
* :meth:`Kinematics.tool_points` ``(axes, tool_length, local (m, 3)) -> (n, m, 3)``: any
  points fixed to the tool, in the workpiece frame;
* :meth:`Kinematics.instance_counts` ``(start, end, tool_length, height, radius, step)``:
  how many instances of motion (Huang & Oliver) a move from machine pose ``start`` to
  ``end`` needs so that no point of the tool moves more than ``step`` between two, and
  :func:`instance_poses` the machine poses themselves; :meth:`Kinematics.move_instances`
  the tips and axes of one move's instances, ready for ``Cutter.cut_poses``.

Frames and points
-----------------
* **Machine frame**: the machine's X Y Z, what a controller reports as MPos (mm).
* **Workpiece frame**: fixed to the part, turning with every table axis the part sits
  on; it coincides with the machine frame when A = B = C = 0. Head axes turn the tool,
  not the part, so on a head-head machine the two frames are the same. (The job's work
  coordinates are this frame less the work offset's X Y Z, ``wco[:3]``, on a machine
  whose G54 is a translation, as GRBL's and LinuxCNC's trivkins are.)
* **Machine X Y Z** are the position of the spindle's *gauge point* (the point a tool of
  length 0 would cut with: the controlled point before the G43 length offset), as in
  :mod:`sim.gcode.moves`. With every head axis at 0 the tip is ``X Y Z - (0, 0, L)``.
* **Tip**: the tool's lowest point on its axis, ``tool_length`` (L, mm, the G43 offset in
  force) from the gauge point along the axis.
* **Axis**: unit vector along the tool from the tip toward the spindle (the CAM "K" or
  tool-orientation vector of LinuxCNC's 5-axis chapter); +Z on a 3-axis machine.

Directions of the rotary axes
-----------------------------
Each rotary has a sign ``s``: when the axis value grows by ``t`` degrees the tool turns
by ``s * t`` about the axis's +X / +Y / +Z direction (right hand) *relative to the part*.
``s = +1`` is the RS274/NGC convention (LinuxCNC "CNC Machine Overview", Rotational Axes:
positive is counterclockwise seen from the positive end, from the workpiece's point of
view; a table turning the part makes it by turning the other way). LinuxCNC's own 5-axis
modules do not all follow it, and a LinuxCNC user's machine is configured the way they
do, so their signs are the default here (``conventional_directions=False``):

===============================  ==========  ==========================================
kinematics                       signs       LinuxCNC reference
===============================  ==========  ==========================================
xyza, xyzb (4th axis, table)     A/B -1      as the trt tables: A = +90 turns the part's
                                             +Y to +Z
xyzac-trt, xyzbc-trt (tables)    all -1      trtfuncs (xyzac-trt-kins, xyzbc-trt-kins)
                                             with ``conventional-directions`` = 0: "the
                                             directions of the rotational axes are the
                                             opposite of the conventional" (5-Axis
                                             Kinematics chapter)
xyzbc-head, xyzac-head           tilt -1,    5axiskins: B = +90 swings the tip toward
(head-head)                      C +1        +X (an A head, by analogy: A = +90 toward
                                             -Y); C turns the tool counterclockwise
xyzbc-head-table, xyzac-head-    all -1      the head tilt as 5axiskins, the table C as
table (head tilt, C table)                   trtfuncs
===============================  ==========  ==========================================

``conventional_directions=True`` makes every sign +1 (LinuxCNC trtfuncs'
``conventional-directions`` = 1).

The machines
------------
* ``xyz``: trivkins. The tool axis is +Z; A B C are carried but turn nothing.
* ``xyza`` / ``xyzb``: a 4th axis, the stock turning about a line parallel to X (A) or
  Y (B) through ``rot_point`` (machine coords, mm), the hobby and grblHAL setup.
* ``xyzac-trt`` / ``xyzbc-trt``: table-table (trunnion). The tilting table (A about X, or
  B about Y) carries the rotary table C. Offsets as LinuxCNC's trtfuncs: ``rot_point``
  is a point of the C axis (its x-rot-point, y-rot-point, z-rot-point) and the tilt axis
  passes through ``rot_point + rot_offset`` (its x-offset, y-offset, z-offset; the offset
  along the tilt axis itself changes nothing). The forward transform is trtfuncs':
  ``tip = Rz(s C) [R_tilt(s tilt) (P - rot_point - offset) + offset] + rot_point`` with
  P the tip in the machine frame (``X Y Z - (0, 0, L)``) and ``tip`` on the part.
* ``xyzbc-head-table`` / ``xyzac-head-table``: the head tilts about Y (B) or X (A) at a
  pivot ``pivot_length`` above the gauge point; the part sits on a C table whose axis
  passes through ``rot_point``.
* ``xyzbc-head`` / ``xyzac-head``: head-head (fork head), as 5axiskins: the C axis turns
  the tilting fork, both axes through the pivot ``pivot_length`` above the gauge point
  (5axiskins' pivot-length is ours plus the tool length: it reaches the tip).

Against LinuxCNC: for the trt modules, LinuxCNC's world position (program X Y Z, which
its motion module shifts by the tool offset before the kinematics) is ``tip + (0, 0, L)``
with its tool-offset pin = L; for 5axiskins, its world is ``tip + (0, 0, L)`` with its
pivot-length = ``pivot_length + L``. tests/sim/test_kinematics.py checks both.

Inverse and singularities
-------------------------
A tilt with a C (two rotaries) reaches every axis direction twice: tilt ``t`` with C
``c``, and tilt ``-t`` with C ``c + 180``; each angle may also add whole turns. The
inverse takes the one closest to ``previous`` (least sum of |angle change|, in degrees;
a tie goes to the positive tilt). When the axis is parallel to the C axis (tilt 0 or
180: the *singularity*, the tool along the table's or head's Z) C is free: it keeps the
previous C. Near it a tiny change of axis swings C a long way, as on the machine. One
rotary (xyza, xyzb) reaches only axes square to its own axis; 3-axis only +Z: anything
else raises :class:`KinematicsError` naming the row. Rotary columns the kinematics does
not use are copied from ``previous``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.errors import InputError

#: column of each rotary axis in the (n, 6) X Y Z A B C arrays
ROTARY_COLUMN = {"A": 3, "B": 4, "C": 5}
#: the machine direction each rotary turns about
ROTARY_ABOUT = {"A": "x", "B": "y", "C": "z"}
#: an axis direction this close (unit-vector components) to the reachable set counts as on it
AXIS_TOL = 1e-9
#: sin(tilt) below this is the singularity: the axis lies along the C axis and C is free
SINGULAR_SIN = 1e-12

_Z = np.array([0.0, 0.0, 1.0])
_UNIT = {"x": np.array([1.0, 0.0, 0.0]), "y": np.array([0.0, 1.0, 0.0]), "z": _Z}


class KinematicsError(InputError):
    """A kinematics configuration that cannot be, or a pose the machine cannot reach."""


# --- array helpers ----------------------------------------------------------------------

def rotate(v: np.ndarray, about: str, degrees) -> np.ndarray:
    """Vectors ``v`` (n, 3) turned by ``degrees`` ((n,) or scalar) about machine ``about``.

    ``about`` is ``"x"``, ``"y"`` or ``"z"``; positive is counterclockwise seen from the
    positive end (right hand). Returns a new float64 (n, 3) array.
    """
    v = np.asarray(v, np.float64)
    t = np.radians(np.asarray(degrees, np.float64))
    c, s = np.cos(t), np.sin(t)
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    out = np.empty_like(v)
    if about == "x":
        out[:, 0], out[:, 1], out[:, 2] = x, c * y - s * z, s * y + c * z
    elif about == "y":
        out[:, 0], out[:, 1], out[:, 2] = c * x + s * z, y, -s * x + c * z
    elif about == "z":
        out[:, 0], out[:, 1], out[:, 2] = c * x - s * y, s * x + c * y, z
    else:
        raise ValueError(f"about must be 'x', 'y' or 'z', got {about!r}")
    return out


def nearest_turn(degrees: np.ndarray, previous: np.ndarray) -> np.ndarray:
    """``degrees`` plus the whole turns (360 deg) that bring each nearest ``previous``, (n,)."""
    degrees = np.asarray(degrees, np.float64)
    return degrees + 360.0 * np.round((np.asarray(previous, np.float64) - degrees) / 360.0)


def _unit_axes(axis, n: int) -> np.ndarray:
    """Tool axes as unit vectors (n, 3); zero or non-finite ones raise KinematicsError."""
    a = np.broadcast_to(np.asarray(axis, np.float64), (n, 3))
    norm = np.linalg.norm(a, axis=1)
    bad = ~(np.isfinite(norm) & (norm > 0))
    if bad.any():
        k = int(np.nonzero(bad)[0][0])
        raise KinematicsError(f"row {k}: tool axis {a[k].tolist()} is not a direction")
    return a / norm[:, None]


def _rows(x, n: int, width: int, name: str) -> np.ndarray:
    a = np.asarray(x, np.float64)
    if a.ndim == 1 and a.shape[0] == width:
        a = np.broadcast_to(a, (n, width))
    if a.shape != (n, width):
        raise ValueError(f"{name}: expected shape ({n}, {width}) or ({width},), got {a.shape}")
    return a


def _lengths(tool_length, n: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(tool_length, np.float64), (n,))


# --- the machine's chain ----------------------------------------------------------------

@dataclass(frozen=True)
class TableAxis:
    """A rotary axis that turns the part: ``letter`` (A/B/C) about a line through
    ``point`` ((3,) mm, machine coords with every rotary at 0) parallel to its machine
    direction; ``sign`` as in the module docstring."""

    letter: str
    point: tuple[float, float, float]
    sign: float


@dataclass(frozen=True)
class HeadAxis:
    """A rotary axis that turns the tool about its machine direction through the head's pivot."""

    letter: str
    sign: float


class Kinematics:
    """A machine's kinematics: the rotaries on the table (base first: each carries the
    next) and on the head (base first), and the head's pivot length (mm, from the gauge
    point up the spindle axis to the pivot where the head's axes cross).

    Use the subclasses (:class:`Trivial`, :class:`FourthAxis`, :class:`TableTable`,
    :class:`HeadTable`, :class:`HeadHead`) or :func:`make_kinematics`.
    """

    name = "xyz"

    def __init__(self, table: tuple[TableAxis, ...] = (), head: tuple[HeadAxis, ...] = (),
                 pivot_length: float = 0.0):
        self.table = tuple(table)
        self.head = tuple(head)
        self.pivot_length = float(pivot_length)
        _check_chain(self)
        # the rotations from the tool's own +Z to its axis on the part, leftmost first:
        # the table's in reverse (the innermost turns the part last), then the head's
        self._orient = tuple((ax.letter, ax.sign) for ax in reversed(self.table)) + \
            tuple((ax.letter, ax.sign) for ax in self.head)

    @property
    def rotaries(self) -> tuple[str, ...]:
        """The rotary letters this kinematics uses, table's then head's."""
        return tuple(ax.letter for ax in self.table) + tuple(ax.letter for ax in self.head)

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name}>"

    def __eq__(self, other) -> bool:
        return isinstance(other, Kinematics) and (self.name, self.table, self.head, self.pivot_length) == \
            (other.name, other.table, other.head, other.pivot_length)

    def __hash__(self) -> int:
        return hash((self.name, self.table, self.head, self.pivot_length))

    # --- forward ---------------------------------------------------------------------

    def forward(self, axes, tool_length=0.0) -> tuple[np.ndarray, np.ndarray]:
        """Tip and tool axis on the part for machine axes.

        axes: (n, 6) or (6,) X Y Z (mm, gauge point, machine coords) A B C (deg).
        tool_length: scalar or (n,) mm, the G43 offset in force.
        Returns tip (n, 3) mm and axis (n, 3) unit vectors, both in the workpiece frame.
        """
        axes = np.atleast_2d(np.asarray(axes, np.float64))
        if axes.ndim != 2 or axes.shape[1] != 6:
            raise ValueError(f"axes: expected shape (n, 6) X Y Z A B C, got {axes.shape}")
        n = len(axes)
        tip, axis = self._tip_in_machine(axes[:, :3], axes, _lengths(tool_length, n))
        for ax in self.table:  # base first: the base turns the part's frame first
            tip, axis = self._table_turn(ax, tip, axis, axes[:, ROTARY_COLUMN[ax.letter]], +1)
        return tip, axis

    def tool_points(self, axes, tool_length, local) -> np.ndarray:
        """Points fixed to the tool, in the workpiece frame, (n, m, 3) mm.

        axes: (n, 6) machine axes; tool_length: scalar or (n,) mm; local: (m, 3) mm in the
        tool's frame: origin at the tip, z up the tool axis, x and y as the machine's
        when every rotary is 0 (``[0, 0, 0]`` is the tip, ``[0, 0, h]`` a point up the axis).
        """
        axes = np.atleast_2d(np.asarray(axes, np.float64))
        local = np.atleast_2d(np.asarray(local, np.float64))
        n, m = len(axes), len(local)
        tip, _ = self._tip_in_machine(axes[:, :3], axes, _lengths(tool_length, n))
        offsets = np.repeat(local[None], n, axis=0).reshape(n * m, 3)
        pts = np.repeat(tip, m, axis=0) + self._head_turn(offsets, np.repeat(axes, m, axis=0))
        axis = np.zeros_like(pts)
        for ax in self.table:
            pts, axis = self._table_turn(ax, pts, axis, np.repeat(axes[:, ROTARY_COLUMN[ax.letter]], m), +1)
        return pts.reshape(n, m, 3)

    def _head_turn(self, v: np.ndarray, angles: np.ndarray) -> np.ndarray:
        """Vectors of the tool's frame (n, 3) in the machine frame: the head's rotations."""
        for ax in reversed(self.head):  # the innermost turns the tool first
            v = rotate(v, ROTARY_ABOUT[ax.letter], ax.sign * angles[:, ROTARY_COLUMN[ax.letter]])
        return v

    def _head_axis(self, angles: np.ndarray, n: int) -> np.ndarray:
        """The tool axis in the machine frame (n, 3): the head's rotations of +Z."""
        return self._head_turn(np.tile(_Z, (n, 1)), angles)

    # --- instances of motion -----------------------------------------------------------

    def instance_counts(self, start, end, tool_length, height: float, radius: float, step: float) -> np.ndarray:
        """Instances of motion each move needs, (n,) int >= 1: with the machine axes
        interpolated linearly from ``start`` to ``end`` ((n, 6), as GRBL and LinuxCNC's
        joint moves do) in that many equal steps, no point of the tool moves more than
        ``step`` mm in the workpiece frame from one instance to the next.

        The tool is taken as the cylinder ``radius`` x ``height`` (mm) standing on the
        tip (its cutting part, or shank and holder too). The bound: a point moves at most
        ``|dXYZ| + sum over rotaries of |dangle| (rad) * its distance from that axis``,
        the distance bounded over the whole move (the gauge point's from the axis at the
        ends, plus the tool's reach, plus the offsets between axes), so it holds between
        the ends too, not only at them.
        """
        start = np.atleast_2d(np.asarray(start, np.float64))
        end = np.atleast_2d(np.asarray(end, np.float64))
        n = len(start)
        _rows(end, n, 6, "end")
        if not (step > 0 and math.isfinite(step)):
            raise ValueError(f"step must be a positive number (mm), got {step!r}")
        lengths = _lengths(tool_length, n)
        # every tool point lies within `cyl` of the cylinder's centre, which sits
        # `centre` below the pivot along the tool axis (the gauge point on a fixed head)
        half = 0.5 * float(height)
        cyl = math.hypot(half, float(radius))
        centre = self.pivot_length + lengths - half
        bound = np.linalg.norm(end[:, :3] - start[:, :3], axis=1)
        turn = np.radians(np.abs(end[:, 3:] - start[:, 3:]))
        for ax in self.head:  # the head's axes pass through the pivot
            bound = bound + turn[:, ROTARY_COLUMN[ax.letter] - 3] * (np.abs(centre) + cyl)
        if self.table:
            # the tool's centre at the ends; a fixed head's moves on a line, a turning
            # head's within pivot_length + |centre| of the gauge point, which moves on one
            if self.head:
                ends = (start[:, :3], end[:, :3])
                slack = self.pivot_length + np.abs(centre) + cyl
            else:
                drop = (lengths - half)[:, None] * _Z
                ends = (start[:, :3] - drop, end[:, :3] - drop)
                slack = np.full(n, cyl)
            base = self.table[0]
            p0 = np.asarray(base.point, np.float64)
            # the base axis stays put: the distance from its line, largest at an end
            # (distance from a line is convex along a segment)
            e0 = _UNIT[ROTARY_ABOUT[base.letter]]
            to_line = np.maximum(*(_line_distance(q, p0, e0) for q in ends)) + slack
            bound = bound + turn[:, ROTARY_COLUMN[base.letter] - 3] * to_line
            # an inner axis turns with the base: from its point, which stays within the
            # offsets of the base point
            reach = np.maximum(*(np.linalg.norm(q - p0, axis=1) for q in ends)) + slack
            prev = p0
            for ax in self.table[1:]:
                p = np.asarray(ax.point, np.float64)
                reach = reach + np.linalg.norm(p - prev)
                prev = p
                bound = bound + turn[:, ROTARY_COLUMN[ax.letter] - 3] * reach
        return np.maximum(1, np.ceil(bound / step - 1e-12)).astype(np.int64)

    def _tip_in_machine(self, xyz, angles, lengths):
        k = self._head_axis(angles, len(xyz))
        pivot = xyz + self.pivot_length * _Z
        return pivot - (self.pivot_length + lengths)[:, None] * k, k

    @staticmethod
    def _table_turn(ax: TableAxis, tip, axis, degrees, direction: int):
        """Machine -> part through one table axis (``direction`` +1), or back (-1)."""
        about, turn = ROTARY_ABOUT[ax.letter], direction * ax.sign * degrees
        p = np.asarray(ax.point, np.float64)
        return rotate(tip - p, about, turn) + p, rotate(axis, about, turn)

    # --- inverse ---------------------------------------------------------------------

    def machine_xyz(self, tip, rotary, tool_length=0.0) -> np.ndarray:
        """Machine X Y Z (n, 3) mm that put the tip at ``tip`` (n, 3) (workpiece frame)
        with the rotaries at ``rotary`` (n, 3) A B C deg (or (n, 6), whose A B C are used)."""
        tip = np.atleast_2d(np.asarray(tip, np.float64))
        n = len(tip)
        rot = np.atleast_2d(np.asarray(rotary, np.float64))
        angles = np.zeros((n, 6))
        angles[:, 3:] = _rows(rot[:, -3:] if rot.shape[-1] == 6 else rot, n, 3, "rotary")
        p = tip
        axis = np.tile(_Z, (n, 1))
        for ax in reversed(self.table):  # part -> machine: the innermost comes off first
            p, axis = self._table_turn(ax, p, axis, angles[:, ROTARY_COLUMN[ax.letter]], -1)
        k = self._head_axis(angles, n)
        pivot = p + (self.pivot_length + _lengths(tool_length, n))[:, None] * k
        return pivot - self.pivot_length * _Z

    def inverse(self, tip, axis, tool_length=0.0, previous=None) -> np.ndarray:
        """Machine axes (n, 6) X Y Z mm A B C deg that put the tool's tip at ``tip`` with
        its axis along ``axis`` (both (n, 3) or (3,), workpiece frame).

        previous: (6,) or (n, 6) machine axes to stay near (default all 0): of the
        solutions, the one whose rotaries moved least (module docstring); rotary columns
        this kinematics does not use are copied from it. Raises KinematicsError for an
        axis the machine cannot reach.
        """
        tip = np.atleast_2d(np.asarray(tip, np.float64))
        n = len(tip)
        _rows(tip, n, 3, "tip")
        k = _unit_axes(axis, n)
        prev = _rows(np.zeros(6) if previous is None else previous, n, 6, "previous")
        out = np.array(prev, np.float64, copy=True)
        for letter, degrees in self._solve_angles(k, prev).items():
            out[:, ROTARY_COLUMN[letter]] = degrees
        out[:, :3] = self.machine_xyz(tip, out[:, 3:], tool_length)
        return out

    def inverse_path(self, tip, axis, tool_length=0.0, start=None) -> np.ndarray:
        """Machine axes (n, 6) along a path of tips and axes ((n, 3) each, workpiece
        frame): each row's solution the one nearest the row before, the first nearest
        ``start`` ((6,), default all 0), so the rotaries turn no more than they must."""
        tip = np.atleast_2d(np.asarray(tip, np.float64))
        n = len(tip)
        k = _unit_axes(axis, n)
        lengths = _lengths(tool_length, n)
        out = np.empty((n, 6))
        prev = np.zeros(6) if start is None else _rows(start, 1, 6, "start")[0]
        for i in range(n):
            prev = self.inverse(tip[i:i + 1], k[i:i + 1], lengths[i], previous=prev)[0]
            out[i] = prev
        return out

    def _solve_angles(self, k: np.ndarray, prev: np.ndarray) -> dict[str, np.ndarray]:
        """Machine angles (deg) of the rotaries that turn +Z into ``k`` (n, 3), near ``prev``."""
        if not self._orient:
            _must_reach(k, np.abs(k - _Z).max(axis=1), "only +Z (3-axis: nothing tilts the tool)")
            return {}
        if len(self._orient) == 1:
            (letter, sign), = self._orient
            phi = _single_tilt(k, ROTARY_ABOUT[letter], letter)
            return {letter: nearest_turn(phi / sign, prev[:, ROTARY_COLUMN[letter]])}
        (c_letter, c_sign), (t_letter, t_sign) = self._orient
        return _tilt_and_turn(k, ROTARY_ABOUT[t_letter], prev, c_letter, c_sign, t_letter, t_sign)


def head_only(kin: Kinematics) -> Kinematics | None:
    """The part of ``kin`` that turns the tool: its head axes and pivot, no table (what
    stays put while the table turns the part, a fixture bolted to the machine, sees only
    these); None when the head turns nothing."""
    if not kin.head:
        return None
    out = Kinematics(head=kin.head, pivot_length=kin.pivot_length)
    out.name = f"{kin.name} (head)"
    return out


def move_instances(kin: Kinematics, start, end, tool_length, height: float, radius: float,
                   step: float) -> tuple[np.ndarray, np.ndarray]:
    """Tips and axes ((k, 3) each, workpiece frame) of the instances of motion of one
    move from machine pose ``start`` to ``end`` ((6,) each): :meth:`Kinematics.instance_counts`
    equal steps, both ends included, ready for ``Cutter.cut_poses``."""
    count = int(kin.instance_counts(start, end, tool_length, height, radius, step)[0])
    return kin.forward(instance_poses(start, end, count), tool_length)


def instance_poses(start, end, count: int) -> np.ndarray:
    """Machine poses (count + 1, 6) from ``start`` to ``end`` ((6,) each) in ``count``
    equal steps of every axis, both ends included (exactly ``start`` and ``end``)."""
    start = np.asarray(start, np.float64).reshape(6)
    end = np.asarray(end, np.float64).reshape(6)
    s = np.linspace(0.0, 1.0, int(count) + 1)[:, None]
    out = start + s * (end - start)
    out[-1] = end
    return out


def _line_distance(q: np.ndarray, point: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Distance (n,) of points ``q`` (n, 3) from the line through ``point`` along unit ``direction``."""
    d = q - point
    return np.linalg.norm(d - (d @ direction)[:, None] * direction, axis=1)


def _must_reach(k, miss, reachable: str) -> None:
    bad = miss > AXIS_TOL
    if bad.any():
        i = int(np.nonzero(bad)[0][0])
        raise KinematicsError(f"row {i}: tool axis {np.round(k[i], 9).tolist()} is out of reach: "
                              f"this machine reaches {reachable}")


def _single_tilt(k, about: str, letter: str) -> np.ndarray:
    """The angle phi (deg) of one rotation about ``about`` that turns +Z into ``k``."""
    if about == "x":  # Rx(phi) z = (0, -sin phi, cos phi)
        _must_reach(k, np.abs(k[:, 0]), f"only axes square to X ({letter} turns about X)")
        return np.degrees(np.arctan2(-k[:, 1], k[:, 2]))
    if about == "y":  # Ry(phi) z = (sin phi, 0, cos phi)
        _must_reach(k, np.abs(k[:, 1]), f"only axes square to Y ({letter} turns about Y)")
        return np.degrees(np.arctan2(k[:, 0], k[:, 2]))
    _must_reach(k, np.abs(k - _Z).max(axis=1), f"only +Z ({letter} turns about Z)")
    return np.zeros(len(k))


def _tilt_and_turn(k, tilt_about, prev, c_letter, c_sign, t_letter, t_sign) -> dict[str, np.ndarray]:
    """Angles of Rz(gamma) R_tilt(tau) z = k: both branches, the one nearest ``prev``."""
    sin_tau = np.hypot(k[:, 0], k[:, 1])
    tau = np.degrees(np.arctan2(sin_tau, k[:, 2]))          # in [0, 180]
    if tilt_about == "y":    # Rz(g) Ry(t) z = (cos g sin t, sin g sin t, cos t)
        gamma = np.degrees(np.arctan2(k[:, 1], k[:, 0]))
    else:                    # Rz(g) Rx(t) z = (sin g sin t, -cos g sin t, cos t)
        gamma = np.degrees(np.arctan2(k[:, 0], -k[:, 1]))
    c_prev, t_prev = prev[:, ROTARY_COLUMN[c_letter]], prev[:, ROTARY_COLUMN[t_letter]]
    singular = sin_tau < SINGULAR_SIN
    best = None
    for branch_tau, branch_gamma in ((tau, gamma), (-tau, gamma + 180.0)):
        t = nearest_turn(branch_tau / t_sign, t_prev)
        c = np.where(singular, c_prev, nearest_turn(branch_gamma / c_sign, c_prev))
        cost = np.abs(t - t_prev) + np.abs(c - c_prev)
        if best is None:
            best = (t, c, cost)
        else:
            # ties go to the first branch (positive physical tilt)
            take = cost < best[2] - 1e-9
            best = (np.where(take, t, best[0]), np.where(take, c, best[1]), np.where(take, cost, best[2]))
    return {t_letter: best[0], c_letter: best[1]}


def _check_chain(kin: Kinematics) -> None:
    letters = kin.rotaries
    if len(set(letters)) != len(letters):
        raise KinematicsError(f"{kin.name}: rotary axis used twice in {letters}")
    for ax in kin.table + kin.head:
        if ax.letter not in ROTARY_COLUMN:
            raise KinematicsError(f"{kin.name}: rotary axis must be A, B or C, got {ax.letter!r}")
        if ax.sign not in (1.0, -1.0):
            raise KinematicsError(f"{kin.name}: direction sign of {ax.letter} must be +1 or -1, got {ax.sign!r}")
    for ax in kin.table:
        if len(ax.point) != 3 or not all(math.isfinite(v) for v in ax.point):
            raise KinematicsError(f"{kin.name}: point of the {ax.letter} axis must be 3 finite numbers (mm), "
                                  f"got {list(ax.point)}")
    if not (math.isfinite(kin.pivot_length) and kin.pivot_length >= 0):
        raise KinematicsError(f"{kin.name}: pivot length must be a finite number >= 0 (mm), "
                              f"got {kin.pivot_length!r}")
    if kin.pivot_length and not kin.head:
        raise KinematicsError(f"{kin.name}: a pivot length needs a rotating head; this machine has none")
    orient = tuple(reversed([ax.letter for ax in kin.table])) + tuple(ax.letter for ax in kin.head)
    if len(orient) > 2 or (len(orient) == 2 and (ROTARY_ABOUT[orient[0]] != "z" or ROTARY_ABOUT[orient[1]] == "z")):
        raise KinematicsError(f"{kin.name}: supported are one rotary, or a C carrying a tilt (A or B) "
                              f"toward the tool; got {orient}")


# --- one small class per machine type ---------------------------------------------------

def _sign(conventional: bool, linuxcnc: float) -> float:
    return 1.0 if conventional else linuxcnc


def _point(value, what: str) -> tuple[float, float, float]:
    try:
        p = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise KinematicsError(f"{what} must be 3 numbers (mm), got {value!r}") from None
    if len(p) != 3 or not all(math.isfinite(v) for v in p):
        raise KinematicsError(f"{what} must be 3 finite numbers (mm), got {value!r}")
    return p


class Trivial(Kinematics):
    """``xyz`` (LinuxCNC trivkins): the tool axis is +Z, the tip is X Y Z - (0, 0, L)."""

    name = "xyz"

    def __init__(self):
        super().__init__()


class FourthAxis(Kinematics):
    """``xyza`` / ``xyzb``: the stock turns on a 4th axis, A about a line parallel to X
    (or B parallel to Y) through ``rot_point`` (3,) mm machine coords."""

    def __init__(self, letter: str = "A", rot_point=(0.0, 0.0, 0.0), conventional_directions: bool = False):
        if letter not in ("A", "B"):
            raise KinematicsError(f"a 4th axis is A or B, got {letter!r}")
        self.name = f"xyz{letter.lower()}"
        point = _point(rot_point, f"{self.name}: rot_point")
        super().__init__(table=(TableAxis(letter, point, _sign(conventional_directions, -1.0)),))


class TableTable(Kinematics):
    """``xyzac-trt`` / ``xyzbc-trt`` (LinuxCNC trtfuncs): a tilting table (A about X, or B
    about Y) carrying a rotary table C. ``rot_point``: a point of the C axis; the tilt
    axis passes through ``rot_point + rot_offset`` (mm, machine coords at zero)."""

    def __init__(self, tilt: str = "A", rot_point=(0.0, 0.0, 0.0), rot_offset=(0.0, 0.0, 0.0),
                 conventional_directions: bool = False):
        if tilt not in ("A", "B"):
            raise KinematicsError(f"the trunnion tilts on A or B, got {tilt!r}")
        self.name = f"xyz{tilt.lower()}c-trt"
        c_point = _point(rot_point, f"{self.name}: rot_point")
        offset = _point(rot_offset, f"{self.name}: rot_offset")
        tilt_point = tuple(c + d for c, d in zip(c_point, offset))
        s = _sign(conventional_directions, -1.0)
        super().__init__(table=(TableAxis(tilt, tilt_point, s), TableAxis("C", c_point, s)))


class HeadTable(Kinematics):
    """``xyzbc-head-table`` / ``xyzac-head-table``: the head tilts (B about Y, or A about
    X) at a pivot ``pivot_length`` mm above the gauge point; the part sits on a C table
    turning about a vertical line through ``rot_point``."""

    def __init__(self, tilt: str = "B", pivot_length: float = 0.0, rot_point=(0.0, 0.0, 0.0),
                 conventional_directions: bool = False):
        if tilt not in ("A", "B"):
            raise KinematicsError(f"the head tilts on A or B, got {tilt!r}")
        self.name = f"xyz{tilt.lower()}c-head-table"
        point = _point(rot_point, f"{self.name}: rot_point")
        s = _sign(conventional_directions, -1.0)
        super().__init__(table=(TableAxis("C", point, s),), head=(HeadAxis(tilt, s),),
                         pivot_length=pivot_length)


class HeadHead(Kinematics):
    """``xyzbc-head`` / ``xyzac-head`` (LinuxCNC 5axiskins for B/C): a fork head, C turning
    the tilt (B about Y, or A about X), both through the pivot ``pivot_length`` mm above
    the gauge point. The part does not turn."""

    def __init__(self, tilt: str = "B", pivot_length: float = 0.0, conventional_directions: bool = False):
        if tilt not in ("A", "B"):
            raise KinematicsError(f"the head tilts on A or B, got {tilt!r}")
        self.name = f"xyz{tilt.lower()}c-head"
        super().__init__(head=(HeadAxis("C", _sign(conventional_directions, 1.0)),
                               HeadAxis(tilt, _sign(conventional_directions, -1.0))),
                         pivot_length=pivot_length)


#: kinematics name -> (class, its fixed arguments, the parameters it takes)
KINEMATICS = {
    "xyz": (Trivial, {}, ()),
    "xyza": (FourthAxis, {"letter": "A"}, ("rot_point", "conventional_directions")),
    "xyzb": (FourthAxis, {"letter": "B"}, ("rot_point", "conventional_directions")),
    "xyzac-trt": (TableTable, {"tilt": "A"}, ("rot_point", "rot_offset", "conventional_directions")),
    "xyzbc-trt": (TableTable, {"tilt": "B"}, ("rot_point", "rot_offset", "conventional_directions")),
    "xyzac-head-table": (HeadTable, {"tilt": "A"}, ("pivot_length", "rot_point", "conventional_directions")),
    "xyzbc-head-table": (HeadTable, {"tilt": "B"}, ("pivot_length", "rot_point", "conventional_directions")),
    "xyzac-head": (HeadHead, {"tilt": "A"}, ("pivot_length", "conventional_directions")),
    "xyzbc-head": (HeadHead, {"tilt": "B"}, ("pivot_length", "conventional_directions")),
}
#: LinuxCNC module names accepted for the kinematics they are
ALIASES = {"trivkins": "xyz", "xyzac-trt-kins": "xyzac-trt", "xyzbc-trt-kins": "xyzbc-trt",
           "5axiskins": "xyzbc-head"}
#: every parameter any kinematics takes
PARAMETERS = ("rot_point", "rot_offset", "pivot_length", "conventional_directions")


def kinematics_name(name: str) -> str | None:
    """The canonical name of kinematics ``name`` (case and LinuxCNC aliases), or None."""
    key = str(name).strip().lower()
    key = ALIASES.get(key, key)
    return key if key in KINEMATICS else None


def make_kinematics(name: str = "xyz", **params) -> Kinematics:
    """The kinematics ``name`` (see :data:`KINEMATICS`) with its parameters; a parameter it
    does not take, or an unknown name, raises KinematicsError."""
    key = kinematics_name(name)
    if key is None:
        raise KinematicsError(f"unknown kinematics {name!r}; expected one of {', '.join(KINEMATICS)}")
    cls, fixed, takes = KINEMATICS[key]
    extra = sorted(set(params) - set(takes))
    if extra:
        raise KinematicsError(f"{key} does not take {extra[0]}"
                              + (f"; it takes {', '.join(takes)}" if takes else "; it takes no parameters"))
    return cls(**fixed, **params)
