"""Findings: what the checks report (gouge, undercut, collisions, limits), and their merging.

A :class:`Finding` is one problem a machinist should look at: its kind, the program
line(s) that caused it, the stage (move id) at which it happened, where (machine
coordinates of the tool tip or the dexel point, mm) and how big (depth mm, area mm^2,
volume mm^3 as fits the kind).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

#: every kind a check can report, in the order a report lists them
KINDS = (
    "setup",                     # the job cannot be what was meant (path misses the stock ...)
    "gouge",                     # material removed inside the design beyond t_l
    "undercut",                  # material left outside the design beyond t_h
    "rapid_into_stock",          # a rapid (G0) removed / would remove material
    "holder_contact",            # the tool holder touches material
    "shank_contact",             # the shank touches material
    "above_flute_contact",       # the tool body above its flute length touches material
    "fixture_collision",         # tool, shank or holder enters a fixture
    "spindle_stopped_cutting",   # material removed with the spindle off
    "non_center_cutting_plunge", # steep entry into material with a tool that does not cut at its centre
    "depth_of_cut",              # axial depth of cut over the limit
    "travel_limit",              # a machine axis outside its travel
)

#: kinds that are collisions (a machine may be damaged), as opposed to part quality
COLLISION_KINDS = frozenset(KINDS[KINDS.index("rapid_into_stock"):])


@dataclass(frozen=True)
class Finding:
    """One problem found by a check.

    Attributes
    ----------
    kind : str
        One of :data:`KINDS`.
    line : int
        The program line where the finding starts (the line of its first move); 0 when
        unknown.
    lines : tuple of int
        Every program line involved, sorted, distinct (includes ``line``).
    stage : int
        Move id (row index + 1 of the move table; 0 = stock) of the worst hit.
    position : tuple of 3 float
        Machine coordinates X Y Z of the worst hit, mm: the contact point (where the tool
        met what it should not, the deepest point of a region).
    depth : float
        mm: gouge depth / undercut height / axial depth of cut / distance past a travel
        limit / penetration of a collision along the dexel direction; NaN if not measured.
    area : float
        mm^2 of design surface affected (gouge, undercut); NaN otherwise.
    volume : float
        mm^3 of material concerned (removed by a gouge, rapid, stopped spindle; touched by
        shank/holder/fixture; left by an undercut); NaN if not measured.
    message : str
        One line for a person.
    stages : tuple of int
        Every move id involved (used to merge hits of consecutive moves).
    detail : dict
        Extra facts of the kind (axis and limit for travel limits, body for contacts ...).
        ``detail["cause"]``: hits naming the same cause (the spindle off since one move)
        are one finding however far apart their moves are (:func:`merge_findings`).
    worst_line : int
        The line of the worst hit (the move ``stage``); defaults to ``line``.
    programmed : tuple of 3 float
        The programmed tool tip at the end of the worst hit's move (mm, the move table's
        coordinates); NaN when not known (see ``Checker.annotate``).
    time_s : float
        Machine time (s from the program start, the move table's timing) at which the
        worst hit's move starts; NaN when not known.
    """

    kind: str
    line: int = 0
    lines: tuple = ()
    stage: int = 0
    position: tuple = (math.nan, math.nan, math.nan)
    depth: float = math.nan
    area: float = math.nan
    volume: float = math.nan
    message: str = ""
    stages: tuple = ()
    detail: dict = field(default_factory=dict, compare=False, hash=False)
    worst_line: int = 0
    programmed: tuple = (math.nan, math.nan, math.nan)
    time_s: float = math.nan

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"unknown finding kind {self.kind!r}; expected one of {', '.join(KINDS)}")
        lines = tuple(sorted({int(x) for x in self.lines} | ({int(self.line)} if self.line else set())))
        object.__setattr__(self, "lines", lines)
        object.__setattr__(self, "line", int(self.line) if self.line else (lines[0] if lines else 0))
        stages = tuple(sorted({int(x) for x in self.stages} | ({int(self.stage)} if self.stage else set())))
        object.__setattr__(self, "stages", stages)
        object.__setattr__(self, "stage", int(self.stage))
        object.__setattr__(self, "worst_line", int(self.worst_line) if self.worst_line else self.line)
        object.__setattr__(self, "position", tuple(float(v) for v in self.position))
        object.__setattr__(self, "programmed", tuple(float(v) for v in self.programmed))
        for name in ("depth", "area", "volume", "time_s"):
            object.__setattr__(self, name, float(getattr(self, name)))

    @property
    def is_collision(self) -> bool:
        return self.kind in COLLISION_KINDS

    def to_json(self, max_lines: int = 200) -> dict:
        """A JSON-ready dict: kind, line (where it starts), worst_line, lines, stage,
        position (= contact, the worst point), programmed (the tip its move was programmed
        to) and time_s when known, the measured sizes, message.

        Sizes that were not measured (NaN) are left out. ``lines`` longer than
        ``max_lines`` is cut to its first ``max_lines`` and ``lines_total`` says how many;
        ``line_range`` is always the first and last line.
        """
        out = {"kind": self.kind, "line": self.line, "worst_line": self.worst_line,
               "lines": list(self.lines[:max_lines])}
        if len(self.lines) > max_lines:
            out["lines_total"] = len(self.lines)
        if self.lines:
            out["line_range"] = [self.lines[0], self.lines[-1]]
        out["stage"] = self.stage
        out["position"] = [round(v, 4) for v in self.position]
        out["contact"] = out["position"]
        if all(math.isfinite(v) for v in self.programmed):
            out["programmed"] = [round(v, 4) for v in self.programmed]
        if math.isfinite(self.time_s):
            out["time_s"] = round(self.time_s, 3)
        for name in ("depth", "area", "volume"):
            v = getattr(self, name)
            if not math.isnan(v):
                out[name] = round(v, 6)
        if self.detail:
            out["detail"] = {k: _jsonable(v) for k, v in self.detail.items()}
        out["message"] = self.message or describe(self)
        return out

    def __str__(self) -> str:
        return self.message or describe(self)


def _jsonable(v):
    if isinstance(v, (np.floating, float)):
        return float(v)
    if isinstance(v, (np.integer, int)):
        return int(v)
    if isinstance(v, (tuple, list, np.ndarray)):
        return [_jsonable(x) for x in v]
    return v


def describe(f: Finding) -> str:
    """A default one-line message for a finding."""
    where = "line ?" if not f.line else (
        f"line {f.line}" if len(f.lines) <= 1 else f"lines {f.lines[0]}-{f.lines[-1]}")
    pos = ", ".join(f"{v:.3f}" for v in f.position)
    sizes = []
    if not math.isnan(f.depth):
        sizes.append(f"depth {f.depth:.4f} mm")
    if not math.isnan(f.area):
        sizes.append(f"area {f.area:.3f} mm^2")
    if not math.isnan(f.volume):
        sizes.append(f"volume {f.volume:.4f} mm^3")
    what = f.kind.replace("_", " ")
    if f.detail.get("group"):
        what += f" ({f.detail['group']})"
    if f.detail.get("cause"):
        what += f" ({f.detail['cause']})"
    if len(f.lines) > 1 and f.worst_line:
        where += f", worst at line {f.worst_line}"
    return f"{what} at {where} ({pos})" + (": " + ", ".join(sizes) if sizes else "")


def line_span(lines) -> str:
    """``"line 12"`` or ``"lines 12-40"``: the first and last of a run's sorted lines, for a message."""
    return f"line {lines[0]}" if len(lines) == 1 else f"lines {lines[0]}-{lines[-1]}"


def _worse(a: Finding, b: Finding) -> Finding:
    """The one of two hits that stands for both (deeper, else bigger, else first)."""
    da = -math.inf if math.isnan(a.depth) else a.depth
    db = -math.inf if math.isnan(b.depth) else b.depth
    if db > da:
        return b
    if db == da:
        va = -math.inf if math.isnan(a.volume) else a.volume
        vb = -math.inf if math.isnan(b.volume) else b.volume
        if vb > va:
            return b
    return a


def _nansum(a: float, b: float) -> float:
    if math.isnan(a):
        return b
    if math.isnan(b):
        return a
    return a + b


def _nanmax(a: float, b: float) -> float:
    if math.isnan(a):
        return b
    if math.isnan(b):
        return a
    return max(a, b)


def _first(f: Finding) -> int:
    """The move id where a hit starts (its stage when it has no list)."""
    return f.stages[0] if f.stages else f.stage


def _merge_two(a: Finding, b: Finding) -> Finding:
    w = _worse(a, b)
    # the finding starts where the earlier of the two starts; it is worst where w is
    first = a if (_first(a), a.line or 1 << 62) <= (_first(b), b.line or 1 << 62) else b
    detail = dict(a.detail)
    for k, v in b.detail.items():
        detail.setdefault(k, v)
    if "ray_box" in a.detail and "ray_box" in b.detail:
        ba, bb = a.detail["ray_box"], b.detail["ray_box"]
        detail["ray_box"] = (min(ba[0], bb[0]), min(ba[1], bb[1]), max(ba[2], bb[2]), max(ba[3], bb[3]))
        detail["rays"] = a.detail.get("rays", 0) + b.detail.get("rays", 0)
    if "box" in a.detail and "box" in b.detail:
        ba, bb = a.detail["box"], b.detail["box"]
        detail["box"] = (min(ba[0], bb[0]), min(ba[1], bb[1]), max(ba[2], bb[2]), max(ba[3], bb[3]))
    return replace(
        w,
        line=first.line or w.line,
        worst_line=w.worst_line,
        lines=a.lines + b.lines,
        stages=a.stages + b.stages,
        depth=_nanmax(a.depth, b.depth),
        area=_nansum(a.area, b.area),
        volume=_nansum(a.volume, b.volume),
        message="",
        detail=detail,
    )


def _touch(a: Finding, b: Finding) -> bool:
    """Hits of one kind touch when their moves are consecutive (or shared).

    Hits without stages (e.g. whole-model error regions) never merge here: those are
    merged by ray adjacency when they are found.
    """
    if a.kind != b.kind:
        return False
    if a.detail.get("cause") is not None and a.detail.get("cause") == b.detail.get("cause"):
        return True  # one cause: one finding, however far apart its moves
    if not a.stages or not b.stages:
        return False
    if a.detail.get("group") != b.detail.get("group"):
        return False
    if not (b.stages[0] <= a.stages[-1] + 1 and a.stages[0] <= b.stages[-1] + 1):
        return False
    ba, bb = a.detail.get("ray_box"), b.detail.get("ray_box")
    if ba is not None and bb is not None:
        # error regions (gouge, undercut) of one pass are separate unless they touch
        return bb[0] <= ba[2] + 1 and ba[0] <= bb[2] + 1 and bb[1] <= ba[3] + 1 and ba[1] <= bb[3] + 1
    return True


def merge_findings(findings) -> list[Finding]:
    """Merge touching hits of one kind into one finding.

    Two hits touch when they are of the same kind (and the same ``detail["group"]``,
    e.g. the axis and side of a travel limit, or the body of a contact) and their move
    ids (``stages``) are equal or consecutive, or when they name the same
    ``detail["cause"]``. The merged finding keeps all lines and stages, the first hit's
    line as ``line``, the worst hit's line (``worst_line``), stage and position, the
    maximum depth and the summed area and volume (the checks measure hits that do not
    overlap, so the sum is the union's).

    Returns the merged findings ordered by first stage, then kind.
    """
    by_kind: dict[tuple, list[Finding]] = {}
    order = []
    for f in findings:
        key = (f.kind, f.detail.get("group"), f.detail.get("cause"))
        if key not in by_kind:
            by_kind[key] = []
            order.append(key)
        by_kind[key].append(f)
    out: list[Finding] = []
    for key in order:
        hits = sorted(by_kind[key], key=lambda f: (f.stages[0] if f.stages else 0))
        cur = None
        for f in hits:
            if cur is not None and _touch(cur, f):
                cur = _merge_two(cur, f)
            else:
                if cur is not None:
                    out.append(cur)
                cur = f
        if cur is not None:
            out.append(cur)
    out.sort(key=lambda f: (f.stages[0] if f.stages else f.stage, KINDS.index(f.kind)))
    return out


def group_passes(findings, reach: float) -> list[Finding]:
    """Merge hits of one kind that repeat along consecutive passes over one place.

    After :func:`merge_findings` a raster that rubs the same feature on every pass still
    gives one finding per pass. Here, in stage order, a hit joins an earlier group of its
    kind (and ``detail["group"]``) when its position is within ``reach`` mm in X and Y of
    the box of that group's positions (a pass's stepover away). Error regions (findings
    with a ``ray_box``) are left as they are. The merged finding keeps the worst hit's
    line, stage and position, all lines and stages, and ``detail["hits"]`` the number of
    hits merged.
    """
    out: list[Finding] = []
    groups: dict[tuple, list[list]] = {}
    for f in sorted(findings, key=lambda f: (f.stages[0] if f.stages else f.stage)):
        if "ray_box" in f.detail or not all(math.isfinite(v) for v in f.position[:2]):
            out.append(f)
            continue
        x, y = f.position[0], f.position[1]
        hit = None
        for g in groups.setdefault((f.kind, f.detail.get("group")), []):
            x0, y0, x1, y1 = g[1]
            if x0 - reach <= x <= x1 + reach and y0 - reach <= y <= y1 + reach:
                hit = g
                break
        if hit is None:
            groups[(f.kind, f.detail.get("group"))].append([f, (x, y, x, y), f.detail.get("hits", 1)])
            continue
        hit[0] = _merge_two(hit[0], f)
        x0, y0, x1, y1 = hit[1]
        hit[1] = (min(x0, x), min(y0, y), max(x1, x), max(y1, y))
        hit[2] += f.detail.get("hits", 1)
    for gs in groups.values():
        for f, _, n in gs:
            out.append(replace(f, detail={**f.detail, "hits": n}) if n > 1 else f)
    out.sort(key=lambda f: (f.stages[0] if f.stages else f.stage, KINDS.index(f.kind)))
    return out


def findings_json(findings, max_lines: int = 200) -> list[dict]:
    """``[f.to_json() for f in findings]``."""
    return [f.to_json(max_lines) for f in findings]
