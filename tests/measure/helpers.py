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


def hole_log(layout, n=400, seed=0, angle_deg=(0.5, 5.0), after_deg=None, noise=0.003, cells=("C1",),
             start="2026-11-25T08:00:00", shift=None):
    """A hole log (dict of columns) cast at planes: ``n`` holes per cell, true angles uniform in
    ``angle_deg``; with ``after_deg`` (lo, hi) after-readings at those angles; ``shift`` (sensor
    index, hole, mm) adds a zero jump. Returns (columns, truth angles before, after) in rad."""
    import datetime as dt

    rng = np.random.default_rng(seed)
    cols = {"hole_id": [], "time": [], "cell": [], "panel": []}
    for s in layout.names:
        cols[f"d_{s}"] = []
        if after_deg is not None:
            cols[f"d_{s}_after"] = []
    t0 = dt.datetime.fromisoformat(start)
    truth_b, truth_a = [], []
    for cell in cells:
        p, axis = standoff_point(layout, float(np.mean(layout.range_mm[0])) if np.all(np.isfinite(layout.range_mm))
                                 else 50.0, n)
        def read(angles, suffix, truth):
            nrm, a = tilted_normals(rng, n, *angles, axis=axis)
            d = cast_plane(layout.zero, layout.direction, nrm, p) + rng.normal(0, noise, (n, layout.n))
            if shift is not None:
                d[shift[1]:, shift[0]] += shift[2]
            truth.append(a)
            for j, s in enumerate(layout.names):
                cols[f"d_{s}{suffix}"] += np.round(d[:, j], 5).tolist()

        read(angle_deg, "", truth_b)
        if after_deg is not None:
            read(after_deg, "_after", truth_a)
        cols["hole_id"] += [f"{cell}-{i:06d}" for i in range(n)]
        cols["time"] += [(t0 + dt.timedelta(seconds=20 * i)).isoformat() + "Z" for i in range(n)]
        cols["cell"] += [cell] * n
        cols["panel"] += ["P1"] * n
    return cols, np.concatenate(truth_b), (np.concatenate(truth_a) if truth_a else None)


def write_log_csv(cols, path):
    import pyarrow as pa
    import pyarrow.csv as pcsv

    pcsv.write_csv(pa.table(cols), path)
    return path


def calibrated_layout(noise=0.003):
    """Table 6's layout with a stated noise, a 40-60 mm range and a block-diagonal calibration
    covariance of 5 um / 0.01 deg (1 sigma)."""
    from metrology.core.layout import SensorLayout
    from metrology.core.paper import TABLE6_NOMINAL, layout_from_table

    t6 = layout_from_table(TABLE6_NOMINAL)
    n = t6.n
    C = np.diag(np.tile([0.005 ** 2] * 3 + [np.radians(0.01) ** 2] * 2, n))
    return SensorLayout(t6.names, t6.zero, t6.direction, np.full(n, noise), np.tile([40.0, 60.0], (n, 1)),
                        covariance=C)


def table6_cell_spec(panel, seed=7, **kw):
    """A forward-simulated cell's ``LogSpec``: the paper's Table 6 head (3 um noise) perturbed as a real one
    (2-10 um, 0.001-0.01 deg, drawn by ``seed``), the cell's layout the nominal with a 5 um / 0.01 deg covariance, on ``panel``."""
    from metrology.core.paper import TABLE6_NOMINAL, layout_from_table
    from metrology.sim.forward import perturb_layout
    from metrology.sim.forward.log_spec import LogSpec

    rng = np.random.default_rng(seed)
    nominal = layout_from_table(TABLE6_NOMINAL, noise_mm=0.003)
    nominal = nominal.with_params(nominal.zero, nominal.direction, range_mm=np.tile([30.0, 70.0], (4, 1)))
    true = perturb_layout(rng, nominal, zero_error_mm=(0.002, 0.01), direction_error_deg=(0.001, 0.01))
    cov = np.diag(np.tile([0.005 ** 2] * 3 + [np.radians(0.01) ** 2] * 2, 4))
    return LogSpec(true_layout=true, cell_layout=nominal.with_params(nominal.zero, nominal.direction, covariance=cov),
                   panel=panel, **kw)
