"""Analytic panels for the hole-log simulator: flat, sphere and cylinder, with closed-form rays.

Panel frame (mm): the panel passes through the origin with its outward unit normal ``+z`` there;
the head works on the ``+z`` (convex) side. A sphere of radius ``R`` has its centre at
``c = (0, 0, -R)``; a cylinder of radius ``R`` has its axis through ``c`` along a unit ``axis``
in the ``xy`` plane. A ray ``p(t) = e + t u`` (``u`` unit) meets

- the plane ``z = 0`` at ``t = -e_z / u_z``;
- the sphere where ``|e - c + t u|^2 = R^2``;
- the cylinder where ``|q + t w|^2 = R^2`` with ``q``, ``w`` the parts of ``e - c`` and ``u``
  perpendicular to the axis;

the hit is the nearest root with ``t >= 0`` that enters the surface from outside (the ray runs
toward the panel); a ray that misses, or whose hit lies behind its start, is NaN. The quadratic
``a t^2 + 2 b t + k = 0`` is solved in the cancellation-free form ``t = k / (-b + sqrt(b^2 - a k))``.
The outward unit normal at a surface point is ``+z`` (plane), ``(p - c) / R`` (sphere) or the part
of ``p - c`` perpendicular to the axis over ``R`` (cylinder). Nothing here knows about sensors.

One class per surface behind one interface (:class:`Panel`); :data:`PANELS` maps the CLI's names
to them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Panel", "FlatPanel", "SpherePanel", "CylinderPanel", "PANELS", "make_panel"]


class Panel:
    """The interface: closed-form ray hits, outward normals and drilling points.

    Every method is vectorised over leading axes; points and directions are ``(..., 3)`` float,
    mm and unit, panel frame.
    """

    kind = "panel"

    def intersect(self, origin, direction):
        """Distance ``t`` (mm) along unit ``direction`` from ``origin`` to the panel, ``(...)``; NaN on a miss."""
        raise NotImplementedError

    def normal_at(self, points):
        """Outward unit normals ``(..., 3)`` at surface ``points`` ``(..., 3)`` mm."""
        raise NotImplementedError

    def height(self, x, y):
        """``z`` mm of the surface above ``(x, y)`` mm; NaN off the surface."""
        raise NotImplementedError

    def sample(self, rng: np.random.Generator, n: int, half_mm: float):
        """``(n, 3)`` surface points mm over the square patch ``|x|, |y| <= half_mm``."""
        x = rng.uniform(-half_mm, half_mm, n)
        y = rng.uniform(-half_mm, half_mm, n)
        return np.stack([x, y, self.height(x, y)], axis=-1)

    def shape_at(self, points):
        """Shape operators ``(m, 3, 3)`` 1/mm, panel frame, at surface ``points (m, 3)`` mm: positive where
        the surface bends away from the head (:func:`metrology.sim.forward.curvature.shape_from_height`)."""
        from metrology.sim.forward.curvature import shape_from_height

        p = np.asarray(points, float).reshape(-1, 3)
        return shape_from_height(self.height, p[:, 0], p[:, 1])[1]

    def check_patch(self, half_mm: float) -> None:
        """Raise ValueError when the square patch of half side ``half_mm`` does not fit the panel."""
        if not (half_mm > 0 and math.isfinite(half_mm)):
            raise ValueError(f"patch half side must be a positive number of mm, got {half_mm}")

    def to_dict(self) -> dict:
        return {"kind": self.kind}


def _entering_root(a, b, k):
    """Smallest root ``t >= 0`` of ``a t^2 + 2 b t + k = 0`` for a ray starting outside
    (``k > 0``) and running inward (``b < 0``); NaN otherwise."""
    disc = b * b - a * k
    with np.errstate(invalid="ignore", divide="ignore"):
        t = k / (-b + np.sqrt(disc))
    return np.where((disc >= 0) & (b < 0) & (k >= 0), t, np.nan)


@dataclass(frozen=True)
class FlatPanel(Panel):
    """The plane ``z = 0``."""

    kind = "flat"

    def intersect(self, origin, direction):
        ez = np.asarray(origin, float)[..., 2]
        uz = np.asarray(direction, float)[..., 2]
        with np.errstate(invalid="ignore", divide="ignore"):
            t = -ez / uz
        return np.where((t >= 0) & (ez >= 0), t, np.nan)

    def normal_at(self, points):
        p = np.asarray(points, float)
        out = np.zeros(p.shape)
        out[..., 2] = 1.0
        return out

    def height(self, x, y):
        return np.zeros(np.broadcast(np.asarray(x), np.asarray(y)).shape)


@dataclass(frozen=True)
class SpherePanel(Panel):
    """A sphere of radius ``radius_mm`` centred at ``(0, 0, -radius_mm)``."""

    radius_mm: float
    kind = "sphere"

    def __post_init__(self):
        if not (self.radius_mm > 0 and math.isfinite(self.radius_mm)):
            raise ValueError(f"sphere radius must be a positive number of mm, got {self.radius_mm}")

    def intersect(self, origin, direction):
        e = np.asarray(origin, float)
        u = np.asarray(direction, float)
        R = self.radius_mm
        qx, qy, qz = e[..., 0], e[..., 1], e[..., 2] + R
        b = qx * u[..., 0] + qy * u[..., 1] + qz * u[..., 2]
        k = (qx * qx + qy * qy + qz * qz) - R * R
        return _entering_root(1.0, b, k)

    def normal_at(self, points):
        p = np.asarray(points, float).copy()
        p[..., 2] += self.radius_mm
        return p / np.linalg.norm(p, axis=-1, keepdims=True)

    def height(self, x, y):
        R = self.radius_mm
        with np.errstate(invalid="ignore"):
            return np.sqrt(R * R - np.asarray(x, float) ** 2 - np.asarray(y, float) ** 2) - R

    def check_patch(self, half_mm):
        super().check_patch(half_mm)
        if half_mm * math.sqrt(2) >= 0.9 * self.radius_mm:
            raise ValueError(f"patch half side {half_mm:g} mm: the patch's corners must lie within 0.9 R of the "
                             f"sphere's pole (R {self.radius_mm:g} mm)")

    def to_dict(self):
        return {"kind": self.kind, "radius_mm": self.radius_mm}


@dataclass(frozen=True)
class CylinderPanel(Panel):
    """A cylinder of radius ``radius_mm``, axis through ``(0, 0, -radius_mm)`` along ``axis`` (in ``xy``)."""

    radius_mm: float
    axis: tuple = field(default=(0.0, 1.0, 0.0))
    kind = "cylinder"

    def __post_init__(self):
        if not (self.radius_mm > 0 and math.isfinite(self.radius_mm)):
            raise ValueError(f"cylinder radius must be a positive number of mm, got {self.radius_mm}")
        a = np.asarray(self.axis, float).reshape(3)
        if not np.all(np.isfinite(a)) or np.hypot(a[0], a[1]) < 1e-9 or abs(a[2]) > 1e-9 * np.linalg.norm(a):
            raise ValueError(f"cylinder axis must be a direction in the panel's xy plane, got {list(self.axis)}")
        object.__setattr__(self, "axis", tuple((a / np.linalg.norm(a)).tolist()))

    @property
    def across(self) -> np.ndarray:
        """Unit vector across the axis in the ``xy`` plane: ``z x axis``, (3,)."""
        ax, ay, _ = self.axis
        return np.array([-ay, ax, 0.0])

    def _perp(self, v):
        ax, ay, _ = self.axis
        along = v[..., 0] * ax + v[..., 1] * ay
        return v[..., 0] - along * ax, v[..., 1] - along * ay, v[..., 2]

    def intersect(self, origin, direction):
        e = np.asarray(origin, float).copy()
        e[..., 2] += self.radius_mm
        qx, qy, qz = self._perp(e)
        wx, wy, wz = self._perp(np.asarray(direction, float))
        a = wx * wx + wy * wy + wz * wz
        b = qx * wx + qy * wy + qz * wz
        k = (qx * qx + qy * qy + qz * qz) - self.radius_mm ** 2
        return _entering_root(a, b, k)

    def normal_at(self, points):
        p = np.asarray(points, float).copy()
        p[..., 2] += self.radius_mm
        m = np.stack(self._perp(p), axis=-1)
        return m / np.linalg.norm(m, axis=-1, keepdims=True)

    def height(self, x, y):
        c = self.across
        w = np.asarray(x, float) * c[0] + np.asarray(y, float) * c[1]
        R = self.radius_mm
        with np.errstate(invalid="ignore"):
            return np.sqrt(R * R - w * w) - R + 0.0 * np.asarray(y, float)

    def check_patch(self, half_mm):
        super().check_patch(half_mm)
        if half_mm * math.sqrt(2) >= 0.9 * self.radius_mm:
            raise ValueError(f"patch half side {half_mm:g} mm: the patch must lie within 0.9 R of the cylinder's "
                             f"crest (R {self.radius_mm:g} mm)")

    def to_dict(self):
        return {"kind": self.kind, "radius_mm": self.radius_mm, "axis": list(self.axis)}


#: the panels by name (the CLI's ``--panel``); each takes ``radius_mm`` except ``flat``
PANELS = {"flat": FlatPanel, "sphere": SpherePanel, "cylinder": CylinderPanel}


def make_panel(kind: str, radius_mm: float | None = None, axis=(0.0, 1.0, 0.0)) -> Panel:
    """The panel ``kind`` (a key of :data:`PANELS`) of radius ``radius_mm`` (sphere, cylinder)."""
    if kind not in PANELS:
        raise ValueError(f"panel {kind!r}: expected one of {', '.join(PANELS)}")
    if kind == "flat":
        return FlatPanel()
    if radius_mm is None:
        raise ValueError(f"a {kind} panel needs a radius (mm)")
    return SpherePanel(float(radius_mm)) if kind == "sphere" else CylinderPanel(float(radius_mm), tuple(axis))
