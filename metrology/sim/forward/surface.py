"""The datum surface: an explicit height field over a reference plane, in the tracker frame.

Geometry (all lengths mm, tracker frame):

- the reference plane has an ``origin`` o (3,), a unit ``normal`` n (3,) that points from the
  surface toward the tool, and in-plane unit axes ``axis_s`` e_s, ``axis_t`` e_t with
  ``e_s x e_t = n``;
- a point p has plane coordinates ``s = e_s.(p - o)``, ``t = e_t.(p - o)`` and height
  ``w = n.(p - o)``; the surface is ``w = h(s, t)``;
- the extent is ``|s| <= half_extent[0]``, ``|t| <= half_extent[1]``; with ``u = s / L_s``,
  ``v = t / L_t`` in [-1, 1] the height is, in mm,

      h = bow_s u^2 + bow_t v^2 + twist u v + sum_jk c_jk P_j(u) P_k(v)

  (``P_j`` Legendre polynomials; ``c_jk`` the optional higher smooth form, ``legendre`` (J, K)).

The gradient ``(dh/ds, dh/dt)`` (unitless) is analytic, and the local unit normal is
``normalise(n - h_s e_s - h_t e_t)``. Nothing here knows about sensors or effects.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.polynomial import legendre as L

__all__ = ["DatumSurface", "flat_surface", "draw_surface", "sample_cloud", "sample_hand_scan", "HAND_SCAN"]


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


@dataclass(frozen=True)
class DatumSurface:
    """A height field over a reference plane (see the module docstring).

    Attributes
    ----------
    origin : (3,) float, mm, tracker frame
    normal : (3,) float, unit, tracker frame
    axis_s, axis_t : (3,) float, unit, tracker frame, ``axis_s x axis_t = normal``
    half_extent : (2,) float, mm, half sizes along s and t
    bow_s, bow_t, twist : float, mm, height of each term at the corner ``u, v = +-1``
    legendre : (J, K) float, mm, coefficients of ``P_j(u) P_k(v)``; empty for none
    """

    origin: np.ndarray
    normal: np.ndarray
    axis_s: np.ndarray
    axis_t: np.ndarray
    half_extent: np.ndarray
    bow_s: float = 0.0
    bow_t: float = 0.0
    twist: float = 0.0
    legendre: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    def __post_init__(self):
        n = _unit(self.normal)
        es = _unit(np.asarray(self.axis_s, float) - np.dot(self.axis_s, n) * n)
        et = np.cross(n, es)
        object.__setattr__(self, "origin", np.asarray(self.origin, dtype=float).reshape(3))
        object.__setattr__(self, "normal", n)
        object.__setattr__(self, "axis_s", es)
        object.__setattr__(self, "axis_t", et)
        he = np.asarray(self.half_extent, dtype=float).reshape(2)
        if np.any(he <= 0):
            raise ValueError(f"half_extent must be positive mm, got {he.tolist()}")
        object.__setattr__(self, "half_extent", he)
        c = np.atleast_2d(np.asarray(self.legendre, dtype=float))
        object.__setattr__(self, "legendre", c if c.size else np.zeros((0, 0)))

    # ------------------------------------------------------------------ heights
    def height(self, s, t):
        """Height ``h(s, t)`` mm above the reference plane; ``s, t`` (...) mm."""
        u = np.asarray(s, float) / self.half_extent[0]
        v = np.asarray(t, float) / self.half_extent[1]
        h = self.bow_s * u**2 + self.bow_t * v**2 + self.twist * u * v
        if self.legendre.size:
            h = h + L.legval2d(u, v, self.legendre)
        return h

    def gradient(self, s, t):
        """``(dh/ds, dh/dt)`` (unitless, mm per mm), each shaped like ``s``."""
        Ls, Lt = self.half_extent
        u = np.asarray(s, float) / Ls
        v = np.asarray(t, float) / Lt
        hu = 2 * self.bow_s * u + self.twist * v
        hv = 2 * self.bow_t * v + self.twist * u
        if self.legendre.size:
            hu = hu + L.legval2d(u, v, L.legder(self.legendre, axis=0)) if self.legendre.shape[0] > 1 else hu
            hv = hv + L.legval2d(u, v, L.legder(self.legendre, axis=1)) if self.legendre.shape[1] > 1 else hv
        return hu / Ls, hv / Lt

    def normal_at(self, s, t):
        """Local unit surface normal ``(..., 3)``, tracker frame, on the side of ``normal``."""
        hs, ht = self.gradient(s, t)
        m = self.normal - hs[..., None] * self.axis_s - ht[..., None] * self.axis_t
        return m / np.linalg.norm(m, axis=-1, keepdims=True)

    # ------------------------------------------------------------------ frames
    def plane_coords(self, points):
        """``(s, t, w)`` mm of tracker-frame points ``(..., 3)`` mm."""
        q = np.asarray(points, float) - self.origin
        return q @ self.axis_s, q @ self.axis_t, q @ self.normal

    def point(self, s, t, w=None):
        """Tracker-frame points ``(..., 3)`` mm at plane coordinates; ``w`` defaults to ``h(s, t)``."""
        s = np.asarray(s, float)
        t = np.asarray(t, float)
        w = self.height(s, t) if w is None else np.asarray(w, float)
        return (self.origin + s[..., None] * self.axis_s + t[..., None] * self.axis_t
                + w[..., None] * self.normal)

    def inside(self, s, t, margin=0.0):
        """True where ``(s, t)`` lies on the datum's extent shrunk by ``margin`` mm."""
        return (np.abs(s) <= self.half_extent[0] - margin) & (np.abs(t) <= self.half_extent[1] - margin)

    def form_peak_to_valley(self, n_grid: int = 81) -> float:
        """Peak-to-valley of ``h`` mm over the extent (on an ``n_grid``^2 grid, corners included)."""
        s = np.linspace(-1, 1, n_grid) * self.half_extent[0]
        t = np.linspace(-1, 1, n_grid) * self.half_extent[1]
        h = self.height(*np.meshgrid(s, t, indexing="ij"))
        return float(h.max() - h.min())

    def to_dict(self) -> dict:
        return {
            "origin_mm": self.origin.tolist(), "normal": self.normal.tolist(),
            "axis_s": self.axis_s.tolist(), "axis_t": self.axis_t.tolist(),
            "half_extent_mm": self.half_extent.tolist(), "bow_s_mm": float(self.bow_s),
            "bow_t_mm": float(self.bow_t), "twist_mm": float(self.twist),
            "legendre_mm": self.legendre.tolist(),
        }


def flat_surface(origin, normal, half_extent=(400.0, 400.0)) -> DatumSurface:
    """A flat datum (h = 0) through ``origin`` mm with unit ``normal``, tracker frame."""
    n = _unit(normal)
    axis = np.eye(3)[np.argmin(np.abs(n))]
    return DatumSurface(origin, n, axis - np.dot(axis, n) * n, None, half_extent)


def draw_surface(rng: np.random.Generator, *, distance_mm=(1500.0, 2500.0), half_extent_mm=(300.0, 500.0),
                 form_mm: float = 0.0, shape: str = "flat") -> tuple[DatumSurface, dict]:
    """A random datum 1.5-2.5 m from the tracker origin, facing the tracker within 50 deg.

    ``shape`` is ``flat``, ``bow``, ``twist``, ``higher`` (random Legendre terms of degree 3-4)
    or ``mixed`` (all three); the form is scaled so its peak-to-valley over the extent is
    ``form_mm``. Returns the surface and the shape parameters (for the truth).
    """
    from scipy.spatial.transform import Rotation

    dist = rng.uniform(*distance_mm)
    dirn = _unit(rng.normal(size=3))
    origin = dist * dirn
    # normal: toward the tracker (-dirn), tipped by up to 50 deg about a random perpendicular axis
    perp = np.cross(dirn, _unit(rng.normal(size=3)))
    tip = rng.uniform(0, np.radians(50))
    normal = Rotation.from_rotvec(tip * _unit(perp)).apply(-dirn)
    spin = rng.uniform(0, 2 * np.pi)
    axis0 = np.eye(3)[np.argmin(np.abs(normal))]
    axis0 = _unit(axis0 - np.dot(axis0, normal) * normal)
    axis_s = Rotation.from_rotvec(spin * normal).apply(axis0)
    he = rng.uniform(*half_extent_mm, size=2)
    base = DatumSurface(origin, normal, axis_s, None, he)
    if shape == "flat" or form_mm == 0:
        return base, {"shape": "flat"}
    parts = {"bow": shape in ("bow", "mixed"), "twist": shape in ("twist", "mixed"), "higher": shape in ("higher", "mixed")}
    if not any(parts.values()):
        raise ValueError(f"datum shape must be flat, bow, twist, higher or mixed, got {shape!r}")
    bow_s = rng.normal() if parts["bow"] else 0.0
    bow_t = rng.normal() if parts["bow"] else 0.0
    twist = rng.normal() if parts["twist"] else 0.0
    coeffs = np.zeros((5, 5))
    if parts["higher"]:
        for _ in range(int(rng.integers(2, 5))):
            j, k = [(3, 0), (0, 3), (2, 1), (1, 2), (4, 0), (0, 4), (2, 2), (3, 1), (1, 3)][int(rng.integers(9))]
            coeffs[j, k] += rng.normal()
    raw = DatumSurface(origin, normal, axis_s, None, he, bow_s, bow_t, twist, coeffs)
    k = form_mm / raw.form_peak_to_valley()
    surf = DatumSurface(origin, normal, axis_s, None, he, k * bow_s, k * bow_t, k * twist, k * coeffs)
    return surf, {"shape": shape, "bow_s_mm": surf.bow_s, "bow_t_mm": surf.bow_t, "twist_mm": surf.twist,
                  "legendre_mm": surf.legendre.tolist()}


def sample_cloud(surface: DatumSurface, rng: np.random.Generator, n_points: int = 2000, noise_mm: float = 0.010,
                 fill: float = 0.95):
    """Points ``(n_points, 3)`` mm, tracker frame, uniform over ``fill`` of the extent, on the
    height field plus isotropic Gaussian noise of ``noise_mm`` (1 sigma per axis)."""
    s = rng.uniform(-1, 1, n_points) * surface.half_extent[0] * fill
    t = rng.uniform(-1, 1, n_points) * surface.half_extent[1] * fill
    return surface.point(s, t) + rng.normal(scale=noise_mm, size=(n_points, 3))


#: a datum scanned with a hand-held tracker probe: point noise (1 sigma per axis, mm), point count,
#: share of stray points, the share of the extent covered, and how far a stray lies off the surface
#: (mm; a probe lifted, touching an edge or a clamp)
HAND_SCAN = {"noise_mm": (0.040, 0.080), "n_points": (400, 1500), "stray_share": (0.01, 0.03), "fill": (0.6, 0.95),
             "stray_mm": (0.3, 3.0)}


def sample_hand_scan(surface: DatumSurface, rng: np.random.Generator, noise_mm: float | None = None,
                     n_points: int | None = None, stray_share: float | None = None, fill: float | None = None):
    """A hand-probe scan of the datum: points ``(m, 3)`` mm, tracker frame, and what was drawn.

    Uniform over a centred patch of ``fill`` of the extent (drawn per axis in ``HAND_SCAN``),
    on the height field plus isotropic Gaussian noise of ``noise_mm``; a share ``stray_share``
    of them are strays, lifted off the surface along its normal by ``HAND_SCAN["stray_mm"]``
    (either side). Unset arguments are drawn uniformly in :data:`HAND_SCAN`'s ranges, so the
    plane fitted to it is off the true one by its own uncertainty (tens of urad).

    Returns
    -------
    points : (m, 3) float, mm, tracker frame
    drawn : dict, the scan's noise_mm, n_points, stray_share, fill, n_strays
    """
    H = HAND_SCAN
    noise_mm = float(rng.uniform(*H["noise_mm"])) if noise_mm is None else float(noise_mm)
    n_points = int(rng.integers(H["n_points"][0], H["n_points"][1] + 1)) if n_points is None else int(n_points)
    stray_share = float(rng.uniform(*H["stray_share"])) if stray_share is None else float(stray_share)
    fill = rng.uniform(*H["fill"], size=2) if fill is None else np.broadcast_to(float(fill), (2,))
    s = rng.uniform(-1, 1, n_points) * surface.half_extent[0] * fill[0]
    t = rng.uniform(-1, 1, n_points) * surface.half_extent[1] * fill[1]
    w = surface.height(s, t)
    n_strays = int(round(stray_share * n_points))
    idx = rng.choice(n_points, n_strays, replace=False)
    w[idx] += rng.choice((-1.0, 1.0), n_strays) * rng.uniform(*H["stray_mm"], size=n_strays)
    pts = surface.point(s, t, w) + rng.normal(scale=noise_mm, size=(n_points, 3))
    return pts, {"noise_mm": noise_mm, "n_points": n_points, "stray_share": stray_share,
                 "fill": [float(f) for f in fill], "n_strays": n_strays}
