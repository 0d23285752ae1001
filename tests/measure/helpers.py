"""Readings of planes and spheres cast from the physics (a ray meets a surface), for tests of
metrology.measure: written here, apart from metrology.core.model and metrology.measure."""

from __future__ import annotations

import numpy as np

from metrology.core.layout import SensorLayout


def tilted_normals(rng, n, lo_deg=0.5, hi_deg=5.0, axis=(0.0, 0.0, 1.0)):
    """(n, 3) unit normals at angles uniform in [lo, hi] deg from ``axis`` (+-z), random azimuth;
    and those angles (rad)."""
    a = np.radians(rng.uniform(lo_deg, hi_deg, n))
    az = rng.uniform(0, 2 * np.pi, n)
    s = np.sign(axis[2])
    nrm = np.stack([np.sin(a) * np.cos(az), np.sin(a) * np.sin(az), s * np.cos(a)], axis=1)
    return nrm, a


def cast_plane(zero, direction, normal, point):
    """Distance along each beam ``E + t u`` to the plane through ``point (N, 3)`` with ``normal (N, 3)``:
    ``t = n.(p - E) / n.u`` (N, n), mm."""
    E = np.asarray(zero)[None]
    u = np.asarray(direction)[None]
    num = np.einsum("pj,pnj->pn", normal, point[:, None, :] - E)
    return num / np.einsum("pj,nj->pn", normal, direction)


def cast_sphere(zero, direction, centre, radius):
    """Distance along each beam to the sphere ``|p - c| = R`` (N, n), mm: the first root of
    ``|E + t u - c|^2 = R^2``."""
    E = np.asarray(zero)[None]
    u = np.asarray(direction)[None]
    w = E - centre[:, None, :]
    b = np.einsum("pnj,pnj->pn", w, np.broadcast_to(u, w.shape))
    c = np.einsum("pnj,pnj->pn", w, w) - radius ** 2
    return -b - np.sqrt(b * b - c)


def standoff_point(layout: SensorLayout, standoff_mm: float, n: int):
    """(n, 3): the drill point on the drill axis (the TCS z axis), ``standoff_mm`` beyond the zero
    points' mean height; and the axis (signed the way the beams point)."""
    axis = np.array([0.0, 0.0, 1.0 if layout.direction[:, 2].mean() > 0 else -1.0])
    return np.tile(np.array([0.0, 0.0, layout.zero[:, 2].mean()]) + standoff_mm * axis, (n, 1)), axis


def ring_layout(n=3, radius=50.0, z0=-35.0, inclination_deg=30.0, noise=None):
    """A symmetric ring of ``n`` sensors whose beams lean toward the axis (TCS +z)."""
    from metrology.core.layout import SensorLayout

    phi = 2 * np.pi * np.arange(n) / n + 0.3
    b = np.radians(inclination_deg)
    er = np.stack([np.cos(phi), np.sin(phi), np.zeros(n)], axis=1)
    u = np.cos(b) * np.array([0.0, 0.0, 1.0]) - np.sin(b) * er
    zero = radius * er + np.array([0.0, 0.0, z0])
    return SensorLayout(tuple(f"L{i + 1}" for i in range(n)), zero, u,
                        None if noise is None else np.full(n, noise))


def cast_cylinder(zero, direction, centre, radius, axis_dir):
    """Distance along each beam to the cylinder of ``radius`` whose axis passes through
    ``centre (N, 3)`` along ``axis_dir (N, 3)`` (unit): the first root, (N, n) mm."""
    E, u = np.asarray(zero)[None], np.asarray(direction)[None]
    c, a = centre[:, None, :], axis_dir[:, None, :]
    w = E - c
    wp = w - (w * a).sum(-1, keepdims=True) * a
    up = u - (u * a).sum(-1, keepdims=True) * a
    A, B, C = (up * up).sum(-1), (wp * up).sum(-1), (wp * wp).sum(-1) - radius ** 2
    return (-B - np.sqrt(B * B - A * C)) / A
