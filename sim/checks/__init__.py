"""Error assessment and collision checks (Huang & Oliver 1994 section 3.2, plus the
collision checks machinists ask for).

The monitor calls :class:`Checker`: ``cut_and_check(moves)`` while cutting (incremental),
``predict(moves)`` for look-ahead on a scratch window, ``assess_model()`` after a run.
The pieces are usable alone: :mod:`.findings`, :mod:`.travel` (travel limits),
:mod:`.spindle` (cutting with the spindle stopped), :mod:`.engagement` (depth of cut,
plunges), :mod:`.collisions` (rapids, shank/holder/above-flute contact, fixtures),
:mod:`.error_map` (design model, signed errors, colours); :mod:`.motion` holds the path
geometry they share.
"""

from sim.checks.findings import KINDS, Finding, findings_json, merge_findings

__all__ = ["KINDS", "Checker", "DesignModel", "Finding", "Fixture", "error_colors", "findings_json",
           "merge_findings"]


def __getattr__(name):  # the heavy parts load on use
    if name == "Checker":
        from sim.checks.checker import Checker
        return Checker
    if name == "DesignModel":
        from sim.checks.error_map import DesignModel
        return DesignModel
    if name == "error_colors":
        from sim.checks.error_map import error_colors
        return error_colors
    if name == "Fixture":
        from sim.checks.collisions import Fixture
        return Fixture
    raise AttributeError(name)
