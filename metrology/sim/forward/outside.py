"""Effects outside the diagnosis' catalogue, drawn from their physics (issue 54's blind set).

Each kind is a physical mechanism that none of the catalogued families describes; it acts on one
sensor (``heavy_tails`` replaces that sensor's noise). Written from the physics, apart from the
diagnosis and its search (nothing here reads either): each kind says what it is, the variable it
follows (``variables``, the truth the blind study scores) and how its term is drawn.

========================  ==================================================================  =====================
kind                      physics, term added to the reading (mm)                             variables
========================  ==================================================================  =====================
``backlash``              play in the sensor's slide or its mount: the reading lags by ``h``   ``sign_delta_d``
                          in the direction the stand-off last moved, ``h sign(d_k - d_k-1)``
``fringe``                a periodic error of the measuring scale (an interpolation or         ``d``
                          fringe error): ``A sin(2 pi d / L + phi)``, ``L`` 2.5-12 mm
``crosstalk_square``      light of a neighbour's spot, or a shared supply loaded by it, that   ``d_other``
                          grows with the square of the neighbour's distance:
                          ``c (x_j^2 - mean)``, ``x_j`` its distance over its span, in [-1, 1]
``plate_texture``         the plate's reflectance (a machining texture, a stain) biases one    ``spot``
                          sensor's spot: a smooth field over the plate ``sum a_k cos(k.s +
                          phi_k)``, wavelengths 40-160 mm, at the spot's position
``thermal_cycle``         the sensor's electronics on a cycle of their own (a fan, a heater     ``time``
                          controller) that the logged air temperature does not follow:
                          ``A sin(2 pi t / P + phi)``, ``P`` 8-30 % of the run
``incidence_reading``     the spot's footprint grows with the distance and its asymmetry with  ``incidence``, ``d``
                          the incidence: ``c tan^2(gamma) (d - d_mid)``
``heavy_tails``           speckle and dust: 12-45 % of the readings get an extra scatter of     ``tails``
                          three times the stated noise (a contaminated normal)
``gravity_sag``           the sensor's mount sags under its own weight as the head turns        ``attitude``
                          against gravity: ``c (R^T g) . e``, ``g`` gravity in the tracker
                          frame, ``e`` the mount's compliant direction (TCS)
``temperature_rate``      a gradient across the housing while the air warms or cools: the      ``temperature_rate``
                          zero follows ``dT/dt``, ``c dT/dt``
========================  ==================================================================  =====================

Sizes are drawn at 1.5-4 times a detectable size made from the term's own shape (:func:`detectable`):
the amplitude at which the term, less what a calibration of the zero point and the beam absorbs
(its projection on a constant, the datum normal's two TCS components and the distance), stands
:data:`DETECT_Z` noise standard deviations out of the noise (``|g_perp| A / sigma``); for
``heavy_tails`` the fraction of readings whose extra scatter lifts the sensor's chi-square by
:data:`DETECT_Z` of its standard deviations.
"""

from __future__ import annotations

import numpy as np

from metrology.sim.forward.families import Effect

__all__ = ["OUTSIDE_KINDS", "DETECT_Z", "SIZE_FACTORS", "TAIL_SCALE", "draw_outside_effect", "detectable",
           "absorbed_basis"]

#: the kinds and the variables each follows (see the module)
OUTSIDE_KINDS = {
    "backlash": ("sign_delta_d",),
    "fringe": ("d",),
    "crosstalk_square": ("d_other",),
    "plate_texture": ("spot",),
    "thermal_cycle": ("time",),
    "incidence_reading": ("incidence", "d"),
    "heavy_tails": ("tails",),
    "gravity_sag": ("attitude",),
    "temperature_rate": ("temperature_rate",),
}
#: a term's detectable size: its part a calibration cannot absorb stands this many noise sigmas out
#: (the one-sided 5e-5 level plus 95 % power: a search over a few hundred terms at a family-wise
#: 1 % would find it about as often as not; a rule of thumb from the normal, not from any search)
DETECT_Z = 5.5
#: sizes are drawn uniformly between these multiples of the detectable size
SIZE_FACTORS = (1.5, 4.0)
#: ``heavy_tails``: the contaminated readings' extra scatter, in noise sigmas
TAIL_SCALE = 3.0


def absorbed_basis(d_true_i, normal_tcs):
    """``(p, 4)``: what a calibration of a sensor's zero point and beam absorbs, to first order: a
    constant, the datum normal's two transverse TCS components and the distance ``d_true_i (p,)`` mm
    (``normal_tcs (p, 3)`` the datum normal seen from each pose)."""
    return np.column_stack([np.ones(len(d_true_i)), normal_tcs[:, 0], normal_tcs[:, 1], d_true_i])


def detectable(shape, basis, noise_mm: float) -> float:
    """The amplitude (the unit of ``shape``) at which ``shape (p,)`` (NaN-free), less its projection on
    ``basis (p, k)``, stands :data:`DETECT_Z` noise sigmas ``noise_mm`` out."""
    g = np.asarray(shape, float)
    r = g - basis @ np.linalg.lstsq(basis, g, rcond=None)[0]
    norm = float(np.linalg.norm(r))
    return float("inf") if norm <= 1e-9 * max(float(np.linalg.norm(g)), 1e-300) else DETECT_Z * noise_mm / norm


def _unit_shape(kind, rng, i, d, inc, time_s, temp_c, rot, spot_st, range_mm):
    """``(shape (p,), parameters dict)``: the term of ``kind`` on sensor ``i`` at unit amplitude."""
    p, n = d.shape
    di = d[:, i]
    if kind == "backlash":
        s = np.sign(np.diff(di, prepend=di[0]))
        s[0] = float(rng.choice([-1.0, 1.0]))  # the direction the slide came from before the run
        s[s == 0] = 1.0
        return s, {}
    if kind == "fringe":
        period = float(rng.uniform(2.5, 12.0))
        phase = float(rng.uniform(0, 2 * np.pi))
        return np.sin(2 * np.pi * di / period + phase), {"period_mm": period, "phase_rad": phase}
    if kind == "crosstalk_square":
        j = int(rng.choice([k for k in range(n) if k != i]))
        lo, hi = float(np.min(d[:, j])), float(np.max(d[:, j]))
        x = (2 * d[:, j] - lo - hi) / max(hi - lo, 1e-9)
        return x**2 - np.mean(x**2), {"source": j}
    if kind == "plate_texture":
        waves = []
        g = np.zeros(p)
        for _ in range(int(rng.integers(1, 4))):
            lam = float(rng.uniform(40.0, 160.0))
            ang = float(rng.uniform(0, np.pi))
            ph = float(rng.uniform(0, 2 * np.pi))
            a = float(rng.uniform(0.5, 1.0))
            k = 2 * np.pi / lam * np.array([np.cos(ang), np.sin(ang)])
            g += a * np.cos(spot_st[:, i] @ k + ph)
            waves.append({"wavelength_mm": lam, "direction_rad": ang, "phase_rad": ph, "weight": a})
        return g, {"waves": waves}
    if kind == "thermal_cycle":
        period = float(rng.uniform(0.08, 0.30) * time_s[-1])
        phase = float(rng.uniform(0, 2 * np.pi))
        return np.sin(2 * np.pi * time_s / period + phase), {"period_s": period, "phase_rad": phase}
    if kind == "incidence_reading":
        mid = 0.5 * (range_mm[0] + range_mm[1])
        return np.tan(inc[:, i]) ** 2 * (di - mid), {"d_mid_mm": mid}
    if kind == "gravity_sag":
        # gravity in the tracker frame: anywhere from along the plate's normal to across it
        g = rng.normal(size=3)
        g /= np.linalg.norm(g)
        e = rng.normal(size=3)
        e /= np.linalg.norm(e)
        return np.einsum("pji,j,i->p", rot, g, e), {"gravity_tracker": g.tolist(), "compliant_tcs": e.tolist()}
    if kind == "temperature_rate":
        rate = np.gradient(temp_c, time_s) * 3600.0  # K/h
        return rate, {"unit_of_c": "mm per K/h"}
    raise ValueError(f"kind must be one of {tuple(OUTSIDE_KINDS)}, got {kind!r}")


def draw_outside_effect(rng: np.random.Generator, kind: str, *, sensor: int, names, d_true, incidence, time_s,
                        temp_c, rot, spot_st, normal_tcs, noise_mm: float, range_mm, factor: float | None = None):
    """One effect of ``kind`` on sensor index ``sensor``, its size ``factor`` (drawn in
    :data:`SIZE_FACTORS` when None) times its detectable size.

    ``d_true (p, n)`` mm, ``incidence (p, n)`` rad, ``time_s (p,)`` s, ``temp_c (p,)`` deg C,
    ``rot (p, 3, 3)`` the true tcs2tracker rotations, ``spot_st (p, n, 2)`` mm the spots on the
    plate's axes, ``normal_tcs (p, 3)`` the datum normal in each pose's TCS, ``noise_mm`` the
    reading noise (1 sigma). Returns ``(Effect, offset (p, n) mm, noise_scale (p, n) or None)``:
    the term to add before the noise and, for ``heavy_tails``, the per-reading multiple of the
    stated noise to draw instead of 1.
    """
    p, n = d_true.shape
    factor = float(rng.uniform(*SIZE_FACTORS)) if factor is None else float(factor)
    off = np.zeros((p, n))
    if kind == "heavy_tails":
        # chi-square per reading rises by q (k^2 - 1) on average, its sd is sqrt(2 p): detectable q
        q_det = DETECT_Z * np.sqrt(2.0 / p) / (TAIL_SCALE**2 - 1.0)
        q = min(0.6, factor * q_det)
        hit = rng.random(p) < q
        scale = np.ones((p, n))
        scale[hit, sensor] = np.sqrt(1.0 + TAIL_SCALE**2)
        shape = {"kind": kind, "variables": list(OUTSIDE_KINDS[kind]), "fraction": q, "extra_sigmas": TAIL_SCALE,
                 "factor": factor, "detectable": float(q_det), "readings": int(hit.sum())}
        return Effect("outside", (names[sensor],), q, shape), off, scale
    g, params = _unit_shape(kind, rng, sensor, d_true, incidence, time_s, temp_c, rot, spot_st, range_mm)
    det = detectable(g, absorbed_basis(d_true[:, sensor], normal_tcs), noise_mm)
    amp = float(rng.choice([-1.0, 1.0])) * factor * det
    off[:, sensor] = amp * g
    if "source" in params:
        params["source"] = names[params["source"]]
    shape = {"kind": kind, "variables": list(OUTSIDE_KINDS[kind]), "amplitude": amp, "factor": factor,
             "detectable": det, "rms_mm": float(np.std(amp * g)), **params}
    return Effect("outside", (names[sensor],), abs(amp), shape), off, None
