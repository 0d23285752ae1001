"""Sensor heads: rings of 3 or 4 laser distance sensors on the pressure foot.

TCS (mm): ``+z`` is the tool axis, pointing from the head toward the surface. Sensor ``i`` of a
ring of radius ``r`` sits at azimuth ``phi_i = phi0 + 2 pi i / n + jitter`` with zero point
``P0_i = (r cos phi_i, r sin phi_i, -z0)`` and unit beam direction

    u_i = cos(beta_i) z + sin(beta_i) (-cos(gamma_i) e_r + sin(gamma_i) e_phi),

inclined by ``beta_i`` toward the axis (radial unit ``e_r``, tangential ``e_phi``) and skewed by
``gamma_i``. The *drawing* (nominal) layout is that; the *true* layout moves each zero point by
a random vector of length 0.1-1 mm and turns each beam by 0.1-2 deg about a random axis
perpendicular to it. Readings of sensor ``i`` are valid on ``range_mm`` and carry Gaussian noise
``noise_mm`` (1 sigma).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.layout import SensorLayout

__all__ = ["Head", "draw_head", "perturb_layout"]


@dataclass(frozen=True)
class Head:
    """A drawn head: the nominal (drawing) and true layouts and how they were drawn.

    Attributes
    ----------
    nominal, true : SensorLayout, mm, TCS
    radius_mm, z0_mm : float, mm
    inclination_rad, skew_rad : (n,) float, rad
    """

    nominal: SensorLayout
    true: SensorLayout
    radius_mm: float
    z0_mm: float
    inclination_rad: np.ndarray
    skew_rad: np.ndarray

    def to_dict(self) -> dict:
        return {"radius_mm": self.radius_mm, "z0_mm": self.z0_mm,
                "inclination_deg": np.degrees(self.inclination_rad).tolist(),
                "skew_deg": np.degrees(self.skew_rad).tolist(),
                "zero_error_mm": (self.true.zero - self.nominal.zero).tolist(),
                "direction_error_deg": np.degrees(np.arccos(np.clip(
                    np.sum(self.true.direction * self.nominal.direction, axis=1), -1, 1))).tolist()}


def perturb_layout(rng: np.random.Generator, layout: SensorLayout, zero_error_mm=(0.1, 1.0),
                   direction_error_deg=(0.1, 2.0)) -> SensorLayout:
    """A copy of ``layout`` with each zero point moved by a random vector whose length is uniform
    in ``zero_error_mm`` and each beam turned by an angle uniform in ``direction_error_deg``."""
    from scipy.spatial.transform import Rotation

    n = layout.n
    v = rng.normal(size=(n, 3))
    dz = v / np.linalg.norm(v, axis=1, keepdims=True) * rng.uniform(*zero_error_mm, size=(n, 1))
    u = layout.direction
    w = np.cross(u, rng.normal(size=(n, 3)))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    ang = np.radians(rng.uniform(*direction_error_deg, size=n))
    u_true = Rotation.from_rotvec(w * ang[:, None]).apply(u)
    return layout.with_params(layout.zero + dz, u_true)


def draw_head(rng: np.random.Generator, n_sensors: int, *, noise_mm: float = 0.005, range_mm=(30.0, 70.0),
              radius_mm=(30.0, 60.0), inclination_deg=(15.0, 35.0), skew_deg: float = 5.0,
              z0_mm=(25.0, 40.0)) -> Head:
    """A random ring head of ``n_sensors`` (3 or more) sensors; see the module docstring."""
    if n_sensors < 3:
        raise ValueError(f"a head needs at least 3 sensors, got {n_sensors}")
    r = float(rng.uniform(*radius_mm))
    z0 = float(rng.uniform(*z0_mm))
    phi = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(n_sensors) / n_sensors
    phi = phi + np.radians(rng.uniform(-5, 5, n_sensors))
    beta = np.radians(rng.uniform(*inclination_deg, size=n_sensors))
    gamma = np.radians(rng.uniform(-skew_deg, skew_deg, n_sensors))
    er = np.stack([np.cos(phi), np.sin(phi), np.zeros(n_sensors)], axis=1)
    ephi = np.stack([-np.sin(phi), np.cos(phi), np.zeros(n_sensors)], axis=1)
    z = np.array([0.0, 0.0, 1.0])
    u = np.cos(beta)[:, None] * z + np.sin(beta)[:, None] * (-np.cos(gamma)[:, None] * er + np.sin(gamma)[:, None] * ephi)
    zero = r * er + np.array([0.0, 0.0, -z0])
    names = tuple(f"L{i + 1}" for i in range(n_sensors))
    nominal = SensorLayout(names, zero, u, np.full(n_sensors, noise_mm), np.tile(np.asarray(range_mm, float), (n_sensors, 1)))
    return Head(nominal, perturb_layout(rng, nominal), r, z0, beta, gamma)
