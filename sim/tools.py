"""Milling tools as solids of revolution: the cutting part, plus shank and holder bodies.

A tool stands on its *tip* (the lowest point on the axis, the controlled point after the
G43 length offset) and extends up the axis. Heights ``h`` are measured up the axis from the
tip, radii ``r`` out from the axis, both in mm.

Shapes of the cutting part (APT-like; ``R = diameter / 2``):

=========  ==========================================================  ===============
kind       radius r(h) for 0 <= h <= flute_length                      spec
=========  ==========================================================  ===============
flat       R                                                           ``flat:D``
ball       sqrt(R^2 - (R - h)^2) below h = R, R above                  ``ball:D``
bull       (R - rc) + sqrt(rc^2 - (rc - h)^2) below h = rc, R above     ``bull:D:rc``
vbit       h * tan(angle / 2) up to R, R above (angle = included)      ``vbit:D:angle``
drill      as vbit (angle = point angle, 118 deg by default)           ``drill:D[:angle]``
custom     a polyline of (h, r) points                                 :meth:`Tool.custom`
=========  ==========================================================  ===============

Every spec takes ``:L=flute_length`` (default: 4 x D, at least the height of the tip
profile); also ``:S=shank_diameter`` and ``:H=holder_diameter`` to give non-cutting
bodies (shank from the flute top 30 mm long, holder above it 40 mm long unless given
with ``:SL=`` / ``:HL=``).

The shank and holder are :class:`Body` objects: solids of revolution that never cut
and are swept only to look for contact (``Cutter.probe_moves(..., body=tool.shank)``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from sim.errors import InputError
from sim.tolerance import DEFAULT, Tolerance

#: kind codes used by the compiled sweep kernels
KIND_CODES = {"flat": 0, "ball": 1, "bull": 2, "vbit": 3, "drill": 3, "custom": 4, "body": 0}

DEFAULT_DRILL_ANGLE = 118.0
DEFAULT_SHANK_LENGTH = 30.0
DEFAULT_HOLDER_LENGTH = 40.0


@dataclass(frozen=True, eq=False)
class Body:
    """A non-cutting solid of revolution about the tool axis (shank, holder, ...).

    ``profile`` is float64 (k, 2) of ``(h, r)`` points in mm, ``h`` non-decreasing from
    ``profile[0, 0]`` (the body's bottom, above the tip) to ``profile[-1, 0]`` (its top);
    the body is ``{(h, rho): h0 <= h <= h1, rho <= r(h)}`` with ``r`` linear between points.
    """

    name: str
    profile: np.ndarray

    def __post_init__(self):
        p = np.asarray(self.profile, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 2:
            raise InputError(f"{self.name}: profile must be (k >= 2, 2) points of (h, r) in mm")
        if not np.all(np.isfinite(p)) or np.any(p[:, 1] < 0) or np.any(np.diff(p[:, 0]) < 0):
            raise InputError(f"{self.name}: profile heights must not decrease and radii must be >= 0")
        if p[-1, 0] - p[0, 0] <= 0:
            raise InputError(f"{self.name}: profile has no height")
        object.__setattr__(self, "profile", p)

    @classmethod
    def cylinder(cls, name: str, diameter: float, bottom: float, length: float) -> "Body":
        """A cylinder of ``diameter`` from ``bottom`` to ``bottom + length`` above the tip (mm)."""
        if not (diameter > 0 and length > 0):
            raise InputError(f"{name}: diameter and length must be positive, got {diameter}, {length}")
        r = diameter / 2.0
        return cls(name, np.array([[bottom, r], [bottom + length, r]]))

    @property
    def bottom(self) -> float:
        return float(self.profile[0, 0])

    @property
    def top(self) -> float:
        return float(self.profile[-1, 0])

    @property
    def max_radius(self) -> float:
        return float(self.profile[:, 1].max())

    @property
    def is_cylinder(self) -> bool:
        return bool(np.all(self.profile[:, 1] == self.profile[0, 1]))

    def radius_at(self, h) -> np.ndarray:
        """Radius (mm) at heights ``h`` (any shape); 0 outside the body."""
        h = np.asarray(h, dtype=np.float64)
        p = self.profile
        r = np.interp(h, p[:, 0], p[:, 1])
        return np.where((h < p[0, 0]) | (h > p[-1, 0]), 0.0, r)

    def volume(self) -> float:
        """Volume of the body (mm^3), exact for the polyline profile (frusta)."""
        h = np.diff(self.profile[:, 0])
        r0, r1 = self.profile[:-1, 1], self.profile[1:, 1]
        return float(np.sum(math.pi * h * (r0 * r0 + r0 * r1 + r1 * r1) / 3.0))


@dataclass(frozen=True, eq=False)
class Tool:
    """A milling tool: the cutting part (a solid of revolution) plus optional shank and holder.

    Lengths in mm, ``angle`` in degrees (included angle of a vbit / point angle of a drill).
    ``profile`` is the cutting part as a polyline of ``(h, r)`` (float64 (k, 2)), exact for
    flat, vbit, drill and custom tools and within ``tol.chord`` of the arcs of ball and
    bull-nose tools; sweeps of those use the closed forms instead where they can.
    """

    kind: str
    diameter: float
    flute_length: float
    corner_radius: float = 0.0
    angle: float = 0.0
    shank: Body | None = None
    holder: Body | None = None
    center_cutting: bool = True
    number: int | None = None
    name: str = ""
    profile: np.ndarray = field(default=None, repr=False)

    def __post_init__(self):
        kind = self.kind
        if kind not in KIND_CODES or kind == "body":
            raise InputError(f"unknown tool kind {kind!r}; expected flat, ball, bull, vbit, drill or custom")
        d = float(self.diameter)
        if not (math.isfinite(d) and d > 0):
            raise InputError(f"tool diameter must be a positive length in mm, got {self.diameter}")
        R = d / 2.0
        rc = float(self.corner_radius)
        if kind == "ball":
            rc = R
        elif kind == "bull" and not (0 < rc <= R):
            raise InputError(f"bull-nose corner radius must be in (0, {R:g}] mm (the radius), got {rc:g}")
        elif kind in ("flat", "vbit", "drill"):
            rc = 0.0
        ang = float(self.angle)
        if kind in ("vbit", "drill") and not (0 < ang < 180):
            raise InputError(f"{kind} angle must be in (0, 180) degrees, got {ang:g}")
        object.__setattr__(self, "diameter", d)
        object.__setattr__(self, "corner_radius", rc)
        object.__setattr__(self, "angle", ang)
        L = float(self.flute_length)
        if not (math.isfinite(L) and L > 0):
            raise InputError(f"flute length must be a positive length in mm, got {self.flute_length}")
        object.__setattr__(self, "flute_length", L)
        if kind == "custom":
            p = np.asarray(self.profile, dtype=np.float64)
            Body("custom tool", p)  # validates the shape
            if abs(p[0, 0]) > 0:
                raise InputError("custom tool profile must start at h = 0 (the tip)")
            object.__setattr__(self, "profile", p)
            object.__setattr__(self, "diameter", 2.0 * float(p[:, 1].max()))
            object.__setattr__(self, "flute_length", float(p[-1, 0]))
        else:
            object.__setattr__(self, "profile", self._polyline(DEFAULT))

    # --- construction ---------------------------------------------------------------
    @classmethod
    def custom(cls, profile, **kw) -> "Tool":
        """A tool whose cutting part is the polyline ``profile`` of (h, r) points (mm).

        The profile starts at the tip (h = 0); it may narrow upwards (dovetail, T-slot,
        lollipop cutters), so the tool can cut from below.
        """
        p = np.asarray(profile, dtype=np.float64)
        return cls("custom", diameter=2.0 * float(np.max(p[:, 1])) if p.size else 0.0,
                   flute_length=float(p[-1, 0]) if p.size else 0.0, profile=p, **kw)

    def _polyline(self, tol: Tolerance) -> np.ndarray:
        R, rc, L = self.radius, self.corner_radius, self.flute_length
        if self.kind == "flat":
            pts = [(0.0, R), (L, R)]
        elif self.kind in ("ball", "bull"):
            # arc of the corner (centre at h = rc, r = R - rc) within tol.chord
            dth = 2.0 * math.acos(max(0.0, 1.0 - tol.chord / rc)) if rc > tol.chord else math.pi / 2
            n = max(2, int(math.ceil((math.pi / 2) / max(dth, 1e-9))))
            th = np.linspace(0.0, math.pi / 2, n + 1)
            h = rc - rc * np.cos(th)
            r = (R - rc) + rc * np.sin(th)
            keep = h <= L
            pts = list(zip(h[keep], r[keep]))
            if h[-1] < L:
                pts.append((L, R))
            elif pts[-1][0] < L:
                pts.append((L, float(self.radius_at(L))))
            if self.kind == "bull":
                pts[0] = (0.0, R - rc)
                pts.insert(0, (0.0, 0.0))
        else:  # vbit / drill: a cone, then the cylinder
            hR = R / math.tan(math.radians(self.angle) / 2.0)
            if hR >= L:
                pts = [(0.0, 0.0), (L, L * math.tan(math.radians(self.angle) / 2.0))]
            else:
                pts = [(0.0, 0.0), (hR, R), (L, R)]
        return np.array(pts, dtype=np.float64)

    # --- shape ------------------------------------------------------------------------
    @property
    def radius(self) -> float:
        return self.diameter / 2.0

    @property
    def code(self) -> int:
        """Kind code of the compiled kernels (see :data:`KIND_CODES`)."""
        return KIND_CODES[self.kind]

    @property
    def cutting_radius(self) -> float:
        """Largest radius of the cutting part (mm): R unless the flutes end inside the tip shape."""
        return float(self.profile[:, 1].max())

    @property
    def tip_height(self) -> float:
        """Height (mm) at which the tip shape reaches the full radius (0 for flat tools)."""
        if self.kind in ("ball", "bull"):
            return self.corner_radius
        if self.kind in ("vbit", "drill"):
            return self.radius / math.tan(math.radians(self.angle) / 2.0)
        if self.kind == "custom":
            return float(self.profile[int(np.argmax(self.profile[:, 1])), 0])
        return 0.0

    @property
    def is_convex(self) -> bool:
        """True when the cutting part is convex (r(h) concave and non-decreasing)."""
        if self.kind != "custom":
            return True
        p = self.profile
        if len(p) > 2 and p[0, 0] == p[1, 0] and p[1, 1] >= p[0, 1]:
            p = p[1:]  # a flat bottom (step out at the tip) keeps the tool convex
        dh = np.diff(p[:, 0])
        if np.any(dh <= 0):  # a step anywhere else is a shoulder or an undercut
            return False
        slopes = np.diff(p[:, 1]) / dh
        return bool(np.all(slopes >= 0) and np.all(np.diff(slopes) <= 1e-12))

    def radius_at(self, h) -> np.ndarray:
        """Exact radius of the cutting part (mm) at heights ``h`` (any shape); 0 outside it."""
        h = np.asarray(h, dtype=np.float64)
        R, rc = self.radius, self.corner_radius
        inside = (h >= 0) & (h <= self.flute_length)
        if self.kind == "flat":
            r = np.full_like(h, R)
        elif self.kind in ("ball", "bull"):
            hh = np.clip(h, 0.0, rc)
            r = np.where(h < rc, (R - rc) + np.sqrt(np.maximum(rc * rc - (rc - hh) ** 2, 0.0)), R)
        elif self.kind in ("vbit", "drill"):
            r = np.minimum(h * math.tan(math.radians(self.angle) / 2.0), R)
        else:
            r = np.interp(h, self.profile[:, 0], self.profile[:, 1])
        return np.where(inside, r, 0.0)

    def lowest_height(self, d) -> np.ndarray:
        """Lowest height (mm above the tip) of the cutting part at distance ``d`` from the axis.

        NaN where ``d`` is beyond the cutting radius. For the standard (convex) tools this
        is the lower face of the tool seen along the axis: 0 under a flat bottom,
        ``R - sqrt(R^2 - d^2)`` under a ball.
        """
        d = np.abs(np.asarray(d, dtype=np.float64))
        R, rc = self.radius, self.corner_radius
        out = np.full_like(d, np.nan)
        ok = d <= self.cutting_radius
        if self.kind == "flat":
            out[ok] = 0.0
        elif self.kind in ("ball", "bull"):
            a = R - rc
            e = np.clip(d - a, 0.0, rc)
            out[ok] = (rc - np.sqrt(np.maximum(rc * rc - e * e, 0.0)))[ok]
        elif self.kind in ("vbit", "drill"):
            out[ok] = d[ok] / math.tan(math.radians(self.angle) / 2.0)
        else:
            p = self.profile
            for q in np.nonzero(ok)[0]:
                out[q] = _first_height(p, d[q])
        return out

    def volume(self) -> float:
        """Volume of the cutting part (mm^3); exact for all kinds but custom (polyline)."""
        R, rc, L = self.radius, self.corner_radius, self.flute_length
        if self.kind == "flat":
            return math.pi * R * R * L
        if self.kind in ("ball", "bull") and L >= rc:
            a = R - rc
            # corner zone 0..rc: solid of revolution of the quarter torus plus inner cylinder
            corner = math.pi * (a * a * rc + a * math.pi * rc * rc / 2.0 + 2.0 * rc**3 / 3.0)
            return corner + math.pi * R * R * (L - rc)
        return Body("tool", self.profile).volume()

    def bodies(self) -> list[Body]:
        """The non-cutting bodies (shank, holder) that exist."""
        return [b for b in (self.shank, self.holder) if b is not None]

    def describe(self) -> str:
        """The spec string this tool would be written as."""
        if self.kind == "bull":
            s = f"bull:{self.diameter:g}:{self.corner_radius:g}"
        elif self.kind in ("vbit", "drill"):
            s = f"{self.kind}:{self.diameter:g}:{self.angle:g}"
        else:
            s = f"{self.kind}:{self.diameter:g}"
        return f"{s}:L={self.flute_length:g}"


def _first_height(profile: np.ndarray, d: float) -> float:
    """Lowest h at which the polyline radius reaches ``d`` (NaN if never)."""
    h, r = profile[:, 0], profile[:, 1]
    for k in range(len(h) - 1):
        r0, r1 = r[k], r[k + 1]
        if r0 >= d:
            return float(h[k])
        if r1 >= d:
            return float(h[k] + (h[k + 1] - h[k]) * (d - r0) / (r1 - r0))
    return float("nan")


_NUM = r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"
_SPEC_HELP = ("expected flat:D, ball:D, bull:D:r, vbit:D:angle or drill:D[:angle], "
              "optionally :L=flute_length (mm, degrees)")


def parse_tool_spec(spec: str, tol: Tolerance = DEFAULT) -> Tool:
    """Parse a tool spec such as ``"ball:6"``, ``"bull:6:1:L=20"``, ``"vbit:6:90"``.

    Options after the shape: ``L=`` flute length, ``S=`` shank diameter, ``SL=`` shank
    length, ``H=`` holder diameter, ``HL=`` holder length, ``nocenter`` (not centre
    cutting). All mm / degrees. Raises :class:`InputError` naming what was expected.
    """
    text = str(spec).strip()
    parts = [p.strip() for p in text.split(":")]
    kind = parts[0].lower()
    if kind not in ("flat", "ball", "bull", "vbit", "drill") or len(parts) < 2:
        raise InputError(f"unknown tool spec {text!r}; {_SPEC_HELP}")
    pos: list[float] = []
    opts: dict[str, float] = {}
    center = True
    for p in parts[1:]:
        if p.lower() == "nocenter":
            center = False
            continue
        m = re.fullmatch(r"([A-Za-z]+)\s*=\s*(" + _NUM + ")", p)
        if m:
            key = m.group(1).upper()
            if key not in ("L", "S", "SL", "H", "HL"):
                raise InputError(f"tool spec {text!r}: unknown option {key}=; {_SPEC_HELP}")
            opts[key] = float(m.group(2))
            continue
        if opts or not re.fullmatch(_NUM, p):
            raise InputError(f"tool spec {text!r}: bad field {p!r}; {_SPEC_HELP}")
        pos.append(float(p))
    need = {"flat": (1, 1), "ball": (1, 1), "bull": (2, 2), "vbit": (2, 2), "drill": (1, 2)}[kind]
    if not need[0] <= len(pos) <= need[1]:
        raise InputError(f"tool spec {text!r}: {kind} takes {need[0]}"
                         f"{'' if need[0] == need[1] else '-' + str(need[1])} number(s); {_SPEC_HELP}")
    D = pos[0]
    if not (math.isfinite(D) and D > 0):
        raise InputError(f"tool spec {text!r}: diameter must be a positive length in mm")
    rc = pos[1] if kind == "bull" else 0.0
    angle = pos[1] if kind == "vbit" else (pos[1] if len(pos) > 1 else DEFAULT_DRILL_ANGLE) if kind == "drill" else 0.0
    tip = {"ball": D / 2, "bull": rc}.get(kind, 0.0)
    if kind in ("vbit", "drill") and 0 < angle < 180:
        tip = D / 2 / math.tan(math.radians(angle) / 2)
    L = opts.get("L", max(4.0 * D, tip))
    try:
        tool = Tool(kind, D, L, corner_radius=rc, angle=angle, center_cutting=center, name=text)
    except InputError as exc:
        raise InputError(f"tool spec {text!r}: {exc}") from None
    shank = holder = None
    if "S" in opts:
        shank = Body.cylinder("shank", opts["S"], L, opts.get("SL", DEFAULT_SHANK_LENGTH))
    if "H" in opts:
        base = shank.top if shank is not None else L
        holder = Body.cylinder("holder", opts["H"], base, opts.get("HL", DEFAULT_HOLDER_LENGTH))
    if shank is not None or holder is not None:
        object.__setattr__(tool, "shank", shank)
        object.__setattr__(tool, "holder", holder)
    return tool


def with_bodies(tool: Tool, shank: Body | None = None, holder: Body | None = None) -> Tool:
    """A copy of ``tool`` carrying the given shank / holder bodies."""
    kw = dict(kind=tool.kind, diameter=tool.diameter, flute_length=tool.flute_length,
              corner_radius=tool.corner_radius, angle=tool.angle, shank=shank, holder=holder,
              center_cutting=tool.center_cutting, number=tool.number, name=tool.name)
    if tool.kind == "custom":
        kw["profile"] = tool.profile
    return Tool(**kw)
