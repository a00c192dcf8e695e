"""The one tolerance object. Kernels take their epsilons from here, never from literals."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Tolerance:
    """Geometric tolerances, all in millimetres.

    Attributes
    ----------
    length : float
        Two lengths closer than this are equal (segment merging, empty segments).
    gouge : float
        t_l in Huang & Oliver: a dexel point more than this below the design surface
        is a gouge.
    undercut : float
        t_h: material more than this above the design surface is undercut (excess).
        Scallop-sized by default (0.05 mm), independent of ``gouge``: the cusps a
        ball-end finishing pass leaves are not findings.
    interest : float
        Range of interest: errors beyond this (either sign) are outside the error map
        and shown in the tool colour.
    chord : float
        Chordal tolerance when arcs are linearised or curved profiles polygonised.
    instance_fraction : float
        Instances of motion are spaced at most this fraction of the grid spacing apart.
    """

    length: float = 1e-6
    gouge: float = 0.002
    undercut: float = 0.05
    interest: float = 1.0
    chord: float = 0.001
    instance_fraction: float = 0.5


DEFAULT = Tolerance()
