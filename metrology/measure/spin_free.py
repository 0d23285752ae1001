"""A hole judged over every spin keeps the CAD's terms beyond second order (a tight radius).

Where the head's spin is not known (:mod:`metrology.measure.spin`: refuted by the redundant reading, an unstated
convention's alias, or 3 sensors with none stated), :func:`metrology.measure.surface.surface_hole_normals` fits the
shape's isotropic part (the mean curvature, the same at every spin) and bounds its deviatoric part over every spin; it
leaves out the CAD beyond second order, which turns with the head too. Over a footprint large against the radius that
part is not small: on a sphere R 50 under Table 6 (spots 26.6 mm out) the quartic's sag is ~0.5 mm, and the fit
without it tilts the normal by 0.12-0.20 deg against a U95 of 0.02 deg (the deviatoric bound is 0 on a sphere, so
nothing covers it); on cylinders R 50-100 its misfit is taken for a gross reading (rule 2 refused 19 % and 7.5 % of a
free spin's holes; benchmarks/results/spin_alias_tight_radii.md).

:func:`free_beyond` takes it the way the deviatoric part is taken: what the CAD beyond second order does at each of
:data:`FREE_BEYOND_SPINS` spins over the whole turn (a fit with it less one without, the shape turned with the head:
the terms of degree ``d`` move as harmonics up to ``d psi``, odd ones too off a symmetric crest), their mean (the
isotropic part, the same at every spin) applied to the tilt, their largest departure from it a bound
over every spin added to the spin's (:data:`metrology.measure.budget.SPIN`, kind BOUND); and rule 2's allowance for
the redundant reading's misfit (``misfit_bound``) the most any of those spins' whole fits (the shape and the CAD
beyond it turned with the head) moves it from the fit over every spin, over ``cos(2 pi / n)`` (the largest a
``2 psi`` harmonic reaches between ``n`` steps).
Only where it can matter (:data:`FREE_BEYOND_SHARE`, :data:`FREE_BEYOND_SDS`): elsewhere the holes are left as they were.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from metrology.measure.budget import PANEL_SHAPE, SPIN, SPIN_READ, SURFACE_MODEL, Budget, combine

__all__ = ["FREE_BEYOND_SPINS", "FREE_BEYOND_SHARE", "FREE_BEYOND_SDS", "needs_beyond", "free_beyond"]

#: spins over the whole turn at which the CAD beyond second order is fitted for a hole whose spin is not known: the
#: mean of ``n`` equal steps is exact for harmonics under ``n psi`` (the footprint's terms reach degree 8); the largest
#: departure is sampled, a ``k psi`` harmonic's peak found to ``cos(k pi / n)`` (2 psi 92 %, 4 psi 71 %: the higher
#: ones are the smaller terms); 32 fits a hole at a tight radius
FREE_BEYOND_SPINS = 16

#: a hole judged over every spin takes the CAD beyond second order (:func:`free_beyond`) where a sphere of its largest
#: curvature ``k`` would tilt the normal by over this share of its U95 with its quartic alone: the sag ``k^3 r^4 / 8`` at
#: the spots' largest radius ``r`` over ``r``, an upper bound (sphere R 50 under Table 6, r 26.6 mm: 1.08 deg against
#: the 0.12-0.20 deg measured, 5-9x: the head's near symmetry cancels most of an isotropic sag). Under it the tilt left
#: out is under 0.1 U95 (as :data:`metrology.measure.spin.SPIN_ALIAS_SHARE`: a normal's coverage 94.6 %). The fits (32
#: a hole) are spent at tight radii only: a cylinder R 300 under Table 6 (0.005 deg against its U95 over every spin,
#: 0.16 deg) and R 500 stay under it, a sphere R 100 (0.13 deg against 0.016: no deviatoric part to cover it) does not
FREE_BEYOND_SHARE = 0.5


#: and, with a redundant reading, where that sag ``k^3 r^4 / 8`` is over this many of the misfit's sd: the misfit's
#: anisotropic part of it is not bounded by the fit over every spin, and rule 2 (4 sd beyond its bound) took it for a
#: gross reading (cylinder R 100 under Table 6, a free spin: sag 63 um, 7.5 % of the holes refused; R 200 8 um, R 300
#: 2 um: none). Under one sd, a fraction of it reaching the misfit moves the 4-sd test by a fraction of an sd
FREE_BEYOND_SDS = 1.0


def needs_beyond(sub, dd, shape, h):
    """(h,) bool: the holes whose CAD beyond second order :func:`free_beyond` takes (:data:`FREE_BEYOND_SHARE`,
    :data:`FREE_BEYOND_SDS`); ``sub`` SensorLayout, ``dd`` (h, n) mm, ``shape`` (h, 3, 3) 1/mm TCS, ``h`` HoleNormals
    over every spin."""
    k00, k01, k11 = shape[:, 0, 0], shape[:, 0, 1], shape[:, 1, 1]
    k = np.abs(0.5 * (k00 + k11)) + np.sqrt(0.25 * (k00 - k11) ** 2 + k01 * k01)  # 1/mm, the largest |curvature|
    z, u = sub.zero, sub.direction
    r = np.hypot(z[None, :, 0] + dd * u[None, :, 0], z[None, :, 1] + dd * u[None, :, 1]).max(1)  # mm, the spots'
    sag = k ** 3 * r ** 4 / 8.0  # mm
    with np.errstate(invalid="ignore"):
        need = sag / r > FREE_BEYOND_SHARE * h.U95
        if h.residual_sd is not None:
            need |= sag > FREE_BEYOND_SDS * h.residual_sd
    return need


def free_beyond(fit, spun, sub, dd, shape, u_shape, higher, h):
    """``(h, z)``: ``h`` (HoleNormals of holes judged over every spin, their fit without the CAD beyond second order)
    with that part's mean over every spin applied and its departure from the mean a bound (module docstring); ``z``
    (h,) the redundant reading's misfit beyond what any spin gives, in its sd (4 sensors; else None).

    Parameters
    ----------
    fit : ``fit(sub, dd, shape, u_shape, spin, higher) -> (HoleNormals, PanelFit)`` (:func:`metrology.measure.spin._fit`)
    spun : ``spun(shape, higher, psi) -> (shape, higher)``, the head turned by ``psi (h,)`` rad
    sub : SensorLayout; dd : (h, n) float, mm; shape : (h, 3, 3) float, 1/mm, TCS; u_shape : (h,) 1/mm
    higher : Beyond of the holes (the CAD beyond second order, at the convention's spin)
    h : HoleNormals of the holes judged over every spin
    """
    k = len(dd)
    zero = np.zeros(k)
    dg, dn, rho = [], [], []
    for p in 2.0 * np.pi * np.arange(FREE_BEYOND_SPINS) / FREE_BEYOND_SPINS:
        K, hi = spun(shape, higher, np.full(k, p))
        w, wo = fit(sub, dd, K, u_shape, zero, hi)[0], fit(sub, dd, K, u_shape, zero, None)[0]
        dg.append(w.budget.tilt - wo.budget.tilt)
        dn.append(w.normal - wo.normal)
        rho.append(w.residual)
    dg, dn = np.nan_to_num(np.array(dg)), np.nan_to_num(np.array(dn))
    g_mean = dg.mean(0)  # (h, 2): the isotropic part, the same at every spin
    dev = dg - g_mean  # (spins, h, 2)
    b = h.budget
    g = b.tilt + g_mean
    reach = np.sqrt((dev * dev).sum(2)).max(0) / (1.0 + (g * g).sum(1))  # rad, as free_spin's half-width
    spread = np.stack([(dev[..., 0] ** 2).mean(0), (dev[..., 0] * dev[..., 1]).mean(0), (dev[..., 1] ** 2).mean(0)], 1)
    src = b.source(SPIN)
    spin_src = replace(src, cov=src.cov + spread, half_width=src.half_width + reach)
    b = Budget(g, tuple(spin_src if s.name == SPIN else s for s in b.sources))
    un = combine(b)
    normal = h.normal + dn.mean(0)
    normal = normal / np.linalg.norm(normal, axis=1, keepdims=True)
    bad = ~np.isfinite(h.angle)
    panel = np.sqrt(un.of(PANEL_SHAPE) ** 2 + un.of(SPIN) ** 2 + un.of(SPIN_READ) ** 2 + un.of(SURFACE_MODEL) ** 2) \
        if h.curvature_bound is not None else None
    out = replace(h, normal=np.where(bad[:, None], np.nan, normal), angle=np.where(bad, np.nan, un.angle),
                  u_angle=np.where(bad, np.nan, un.u), U95=np.where(bad, np.nan, un.U95), budget=b,
                  curvature_bound=panel)
    z = None
    if h.signature is not None and h.misfit_bound is not None:  # 4 sensors: the misfit's allowance over every spin
        res = h.residual
        moved = np.fmax.reduce(np.abs(np.array(rho) - res), axis=0)  # a spin whose fit failed (NaN) left out
        bound = np.fmax(h.misfit_bound, moved / np.cos(2.0 * np.pi / FREE_BEYOND_SPINS))
        out = replace(out, misfit_bound=bound)
        with np.errstate(invalid="ignore", divide="ignore"):  # as surface_hole_normals's, the spin not known
            z = np.sign(res) * np.maximum(np.abs(res) - bound, 0.0) / h.residual_sd
    return out, z
