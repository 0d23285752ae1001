"""Reading errors that are not a smooth function of one physical variable.

All act on a reading table ``d (p, n)`` mm (rows poses, columns sensors) and return a new table:

- noise: Gaussian, ``sigma`` mm per sensor (1 sigma);
- gross readings (multipath): a few readings replaced by ``d + delta``, ``|delta|`` 0.1-2 mm,
  random sign;
- blanks: the PLC's "no reading", a NaN (an empty cell in the export);
- periodic error (outside the catalogue): ``A sin(2 pi x / P + phi)`` with ``x`` the pose index or
  the time in s;
- cross-talk (outside the catalogue): sensor ``j`` reads ``c (d_k - mean d_k)`` mm more, in
  proportion to sensor ``k``'s true distance.
"""

from __future__ import annotations

import numpy as np

__all__ = ["add_noise", "add_gross", "add_blanks", "periodic_offset", "crosstalk_offset"]


def add_noise(rng: np.random.Generator, d, sigma_mm):
    """``d (p, n)`` mm plus Gaussian noise of ``sigma_mm`` (scalar, ``(n,)`` or ``(p, n)``) mm."""
    d = np.asarray(d, float)
    return d + rng.normal(size=d.shape) * np.broadcast_to(np.asarray(sigma_mm, float), d.shape)


def add_gross(rng: np.random.Generator, d, count: int, sensors=None, delta_mm=(0.1, 2.0)):
    """Replace ``count`` finite readings (on columns ``sensors``, default all) by ``d + delta``.

    Returns the new table ``(p, n)`` and the list of ``(pose index, sensor index, delta mm)``.
    """
    d = np.array(d, float)
    cols = np.arange(d.shape[1]) if sensors is None else np.asarray(sensors)
    cells = [(i, j) for i in range(d.shape[0]) for j in cols if np.isfinite(d[i, j])]
    if count > len(cells):
        raise ValueError(f"gross readings: {count} asked, only {len(cells)} finite readings")
    pick = rng.choice(len(cells), size=count, replace=False)
    hits = []
    for k in sorted(pick):
        i, j = cells[k]
        delta = float(rng.choice([-1.0, 1.0]) * rng.uniform(*delta_mm))
        d[i, j] += delta
        hits.append((int(i), int(j), delta))
    return d, hits


def add_blanks(rng: np.random.Generator, d, count: int):
    """Set ``count`` random readings of ``d (p, n)`` to NaN; returns the table and the cells."""
    d = np.array(d, float)
    flat = rng.choice(d.size, size=count, replace=False)
    cells = sorted((int(k // d.shape[1]), int(k % d.shape[1])) for k in flat)
    for i, j in cells:
        d[i, j] = np.nan
    return d, cells


def periodic_offset(x, amplitude_mm: float, period: float, phase_rad: float):
    """``A sin(2 pi x / P + phi)`` mm at ``x (p,)`` (pose index or time s, ``P`` in the same unit)."""
    return amplitude_mm * np.sin(2 * np.pi * np.asarray(x, float) / period + phase_rad)


def crosstalk_offset(d_true_source, coupling: float):
    """``c (d_k - mean d_k)`` mm for the source sensor's true distances ``d_true_source (p,)`` mm."""
    d = np.asarray(d_true_source, float)
    return coupling * (d - np.nanmean(d))
