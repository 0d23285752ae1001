"""Smooth panels as height fields: the generated aircraft panels and panels off their CAD shape.

Panel frame (mm) as in :mod:`.panels`: the surface is ``z = f(x, y)``, passes through the origin
with its outward unit normal ``+z`` there, and the head works on the ``+z`` side. A panel covers
``|x|, |y| <= half_mm``; off it ``f`` is NaN (a beam there misses the panel).

- A ray ``p(t) = e + t u`` meets the surface where ``g(t) = e_z + t u_z - f(e_x + t u_x, e_y + t u_y)
  = 0``: Newton's method from the plane ``z = f(0, 0)`` crossing, ``t <- t - g / g'`` with
  ``g' = u_z - f_x u_x - f_y u_y``, until the step is under :data:`NEWTON_TOL_MM`; a ray that
  starts under the surface, runs away from it, or leaves the panel is NaN.
- The outward unit normal is ``(-f_x, -f_y, 1) / |.|``.
- The shape operator (panel frame, 1/mm) of ``F = z - f`` is ``S = P H P / |grad F|`` with
  ``H = -hess f`` (embedded in 3 x 3) and ``P = I - n n^T``: positive where the surface bends away
  from the head (a sphere seen from outside ``+1/R``, a barrel seen from inside ``-1/R``).

Derivatives are central differences of ``f`` (:mod:`.curvature`).

The generated panels (:data:`GENERATED`; each also exported as a mesh, the CAD, by
:mod:`.meshes`):

- ``wing``: a doubly curved skin with twist, ``f = -x^2 / (2 Rc) - y^2 / (2 Rs) + tau x y``
  (Rc 1500 mm chordwise, Rs 6000 mm spanwise, twist tau 10 deg per m);
- ``barrel``: a fuselage barrel seen from inside (concave), ``f = R - sqrt(R^2 - x^2)``, R 2000 mm,
  axis along ``y``;
- ``nacelle``: a nacelle lip, a torus of tube radius r 400 mm about a ring of radius 800 mm
  (axis ``y``): ``f = sqrt((Rm + sqrt(r^2 - y^2))^2 - x^2) - Rm - r``, principal radii 400 mm
  (along ``y``) and 1200 mm (along ``x``) at the origin;
- ``saddle``: ``f = (y^2 - x^2) / (2 R)``, R 800 mm.

A panel off its CAD (:class:`OffCadPanel`): the true surface is the CAD one moved and bent,
``f_true(x, y) = f_cad(x - sx, y - sy) + sz + bump(x, y)`` with

- ``dent``: ``bump = -A (1 + cos(pi r / w)) / 2`` for ``r < w`` (``r`` the distance from the dent's
  centre, ``w`` half its width: depth ``A`` over a width of ``2 w``; default 0.2 mm over 100 mm);
- ``springback``: ``bump = A (x / w)^2`` (the panel opens: it rises by ``A`` at ``+-w`` from the
  centre line, a chord of ``2 w``; default 0.2 mm over 100 mm);
- ``shift``: a rigid translation ``(sx, sy, sz)`` mm (default 1 mm along ``z``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from metrology.sim.forward.curvature import _grad, shape_from_height
from metrology.sim.forward.panels import Panel

__all__ = ["HeightPanel", "GeneratedPanel", "OffCadPanel", "GENERATED", "generated_panel", "shape_from_height",
           "parse_off_cad", "OFF_CAD_KINDS"]

#: Newton stops when the step along the ray is under this (mm)
NEWTON_TOL_MM = 1e-11
NEWTON_STEPS = 40
class HeightPanel(Panel):
    """A panel ``z = f(x, y)`` over ``|x|, |y| <= half_mm`` (module docstring); subclasses give :meth:`f`."""

    kind = "height"
    half_mm = math.inf

    def f(self, x, y):
        """``z`` mm of the surface at ``x, y`` mm (any shape, broadcast); NaN where it is not defined."""
        raise NotImplementedError

    def height(self, x, y):
        x, y = np.asarray(x, float), np.asarray(y, float)
        z = self.f(x, y)
        inside = (np.abs(x) <= self.half_mm) & (np.abs(y) <= self.half_mm)
        return np.where(inside, z, np.nan)

    def intersect(self, origin, direction):
        e = np.asarray(origin, float)
        u = np.asarray(direction, float)
        shape = np.broadcast_shapes(e.shape, u.shape)[:-1]
        e, u = np.broadcast_to(e, shape + (3,)).reshape(-1, 3), np.broadcast_to(u, shape + (3,)).reshape(-1, 3)
        f = self.height
        with np.errstate(invalid="ignore", divide="ignore"):
            above = e[:, 2] - f(e[:, 0], e[:, 1])  # NaN when the start is off the panel's square: use z0
            z0 = float(self.f(np.array(0.0), np.array(0.0)))
            t = (z0 - e[:, 2]) / u[:, 2]
            for _ in range(NEWTON_STEPS):
                x, y = e[:, 0] + t * u[:, 0], e[:, 1] + t * u[:, 1]
                g = e[:, 2] + t * u[:, 2] - self.f(x, y)
                fx, fy = _grad(self.f, x, y)
                step = g / (u[:, 2] - fx * u[:, 0] - fy * u[:, 1])
                t = t - step
                if not np.any(np.abs(step) > NEWTON_TOL_MM):
                    break
            x, y = e[:, 0] + t * u[:, 0], e[:, 1] + t * u[:, 1]
            fx, fy = _grad(self.f, x, y)
            toward = (u[:, 2] - fx * u[:, 0] - fy * u[:, 1]) < 0  # the ray runs into the outside face
            ok = (t >= 0) & toward & np.isfinite(self.height(x, y)) & ~(above < 0) & (np.abs(step) < 1e-6)
        return np.where(ok, t, np.nan).reshape(shape)

    def normal_at(self, points):
        p = np.asarray(points, float)
        fx, fy = _grad(self.f, p[..., 0], p[..., 1])
        g = np.stack([-fx, -fy, np.ones_like(fx)], axis=-1)
        return g / np.linalg.norm(g, axis=-1, keepdims=True)

    def shape_at(self, points):
        """Shape operators ``(m, 3, 3)`` 1/mm, panel frame, at surface ``points (m, 3)`` mm."""
        p = np.asarray(points, float).reshape(-1, 3)
        return shape_from_height(self.f, p[:, 0], p[:, 1])[1]

    def check_patch(self, half_mm):
        super().check_patch(half_mm)
        if half_mm > self.half_mm:
            raise ValueError(f"patch half side {half_mm:g} mm: the {self.kind} panel is only {2 * self.half_mm:g} mm wide")


@dataclass(frozen=True)
class GeneratedPanel(HeightPanel):
    """One of the generated aircraft panels (:data:`GENERATED`), ``2 half_mm`` wide."""

    name: str
    half_mm: float = 125.0
    params: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        if self.name not in GENERATED:
            raise ValueError(f"generated panel {self.name!r}: expected one of {', '.join(GENERATED)}")
        if not (self.half_mm > 0 and math.isfinite(self.half_mm)):
            raise ValueError(f"panel half width must be a positive number of mm, got {self.half_mm}")
        object.__setattr__(self, "params", dict(GENERATED[self.name]))

    @property
    def kind(self):
        return self.name

    def f(self, x, y):
        p, x, y = self.params, np.asarray(x), np.asarray(y)
        with np.errstate(invalid="ignore"):
            if self.name == "wing":
                return -x * x / (2 * p["rc_mm"]) - y * y / (2 * p["rs_mm"]) + math.radians(p["twist_deg_per_m"]) / 1000 * x * y
            if self.name == "barrel":
                R = p["radius_mm"]
                return R - np.sqrt(R * R - x * x) + 0.0 * y
            if self.name == "nacelle":
                r, Rm = p["tube_mm"], p["ring_mm"]
                return np.sqrt((Rm + np.sqrt(r * r - y * y)) ** 2 - x * x) - Rm - r
            R = p["radius_mm"]  # saddle
            return (y * y - x * x) / (2 * R)

    def to_dict(self):
        return {"kind": self.name, "half_mm": self.half_mm, **self.params}


#: the generated panels and their parameters (module docstring)
GENERATED = {
    "wing": {"rc_mm": 1500.0, "rs_mm": 6000.0, "twist_deg_per_m": 10.0},
    "barrel": {"radius_mm": 2000.0},
    "nacelle": {"tube_mm": 400.0, "ring_mm": 800.0},
    "saddle": {"radius_mm": 800.0},
}


def generated_panel(name: str, half_mm: float = 125.0) -> GeneratedPanel:
    """The generated panel ``name`` (a key of :data:`GENERATED`), ``2 half_mm`` mm wide."""
    return GeneratedPanel(name, half_mm)


#: the ways a panel may sit or be formed off its CAD, with their default sizes
OFF_CAD_KINDS = {"dent": 0.2, "springback": 0.2, "shift": (0.0, 0.0, 1.0)}


@dataclass(frozen=True)
class OffCadPanel(HeightPanel):
    """The true panel: ``cad`` (any panel with :meth:`Panel.height`) moved by ``shift_mm`` and bent by a
    dent or a spring-back (module docstring).

    Attributes
    ----------
    cad : Panel, the CAD shape
    kind : str, ``"dent"``, ``"springback"`` or ``"shift"``
    size_mm : float, mm, the dent's depth or the spring-back's rise (0 for a shift)
    width_mm : float, mm, over which the dent or spring-back spans (100 mm)
    centre_mm : (2,) float, mm, the dent's centre (x, y); the spring-back's centre line is ``x = cx``
    shift_mm : (3,) float, mm, the rigid translation
    """

    cad: Panel
    off: str = "dent"
    size_mm: float = 0.2
    width_mm: float = 100.0
    centre_mm: tuple = (0.0, 0.0)
    shift_mm: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self):
        if self.off not in OFF_CAD_KINDS:
            raise ValueError(f"off-CAD kind {self.off!r}: expected one of {', '.join(OFF_CAD_KINDS)}")
        vals = [self.size_mm, self.width_mm, *self.centre_mm, *self.shift_mm]
        if not all(math.isfinite(v) for v in vals) or self.width_mm <= 0:
            raise ValueError(f"off-CAD {self.off}: sizes must be finite and the width positive, got {vals}")

    @property
    def kind(self):
        return f"{self.cad.kind}+{self.off}"

    @property
    def half_mm(self):
        return getattr(self.cad, "half_mm", math.inf)

    def f(self, x, y):
        sx, sy, sz = self.shift_mm
        x, y = np.asarray(x, float), np.asarray(y, float)
        z = self.cad.height(x - sx, y - sy) + sz
        cx, cy = self.centre_mm
        if self.off == "dent":
            w = self.width_mm / 2
            r = np.hypot(x - cx, y - cy)
            z = z - np.where(r < w, self.size_mm * (1 + np.cos(np.pi * np.minimum(r, w) / w)) / 2, 0.0)
        elif self.off == "springback":
            w = self.width_mm / 2
            z = z + self.size_mm * ((x - cx) / w) ** 2
        return z

    def height(self, x, y):
        return self.f(x, y)

    def to_dict(self):
        return {"kind": self.kind, "cad": self.cad.to_dict(), "off_cad": self.off, "size_mm": self.size_mm,
                "width_mm": self.width_mm, "centre_mm": list(self.centre_mm), "shift_mm": list(self.shift_mm)}


def parse_off_cad(value: str, cad: Panel) -> OffCadPanel:
    """``dent[:MM[@X,Y]]``, ``springback[:MM[@X]]`` or ``shift[:X,Y,Z]`` (mm) -> the true panel off ``cad``."""
    text = value.strip()
    cut = min([i for i in (text.find(":"), text.find("@")) if i >= 0], default=len(text))
    kind, rest = text[:cut], text[cut + 1:] if cut < len(text) and text[cut] == ":" else text[cut:]
    if rest.startswith("@"):
        rest = rest  # no size: "@X,Y" follows the kind
    if kind not in OFF_CAD_KINDS:
        raise ValueError(f"--off-cad {value}: expected dent[:MM[@X,Y]], springback[:MM[@X]] or shift[:X,Y,Z]")
    if not hasattr(cad, "height"):
        raise ValueError(f"--off-cad {value}: the panel {cad.kind} has no height field to move")
    size, _, at = rest.partition("@")

    def nums(s, n, what):
        try:
            v = [float(p) for p in s.split(",")]
        except ValueError:
            raise ValueError(f"--off-cad {value}: {what} {s!r} is not {n} number(s)") from None
        if len(v) != n or not all(math.isfinite(a) for a in v):
            raise ValueError(f"--off-cad {value}: {what} {s!r}: expected {n} finite number(s)")
        return v

    if kind == "shift":
        if at:
            raise ValueError(f"--off-cad {value}: a shift takes no @centre")
        shift = nums(size, 3, "shift") if size else list(OFF_CAD_KINDS["shift"])
        return OffCadPanel(cad, "shift", 0.0, shift_mm=tuple(shift))
    a = nums(size, 1, "size")[0] if size else OFF_CAD_KINDS[kind]
    if kind == "dent":
        centre = nums(at, 2, "centre") if at else [0.0, 0.0]
    else:
        centre = [nums(at, 1, "centre")[0], 0.0] if at else [0.0, 0.0]
    return OffCadPanel(cad, kind, a, centre_mm=tuple(centre))
