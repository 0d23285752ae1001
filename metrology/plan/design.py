"""D-optimal choice of calibration poses, in an order whose every prefix is itself a good design.

**Criterion.** Each sensor is fitted from its own readings, on the five identifiable
parameters of metro's chart (``x, y, z`` mm and the beam tilts ``a, b`` rad; the sixth number,
the direction's scale, is the gauge no reading sees: :mod:`metrology.core.model`). A pose adds
to sensor ``i``'s information ``M_i = P0^-1 + sum_p J_ip^T J_ip / sigma_i^2`` (``J_ip`` the
(1, 5) chart Jacobian of its reading, ``P0`` the prior of the filters, ``DEFAULT_P0_SIGMA``),
and the design maximises

    Phi = sum_i log det M_i                                   (Bayesian D-optimality)

i.e. minimises the volume of every sensor's confidence ellipsoid. D-optimality does not
depend on the units or the chart (mm against rad; a change of parameters adds a constant to
``log det``), which a sum of variances (A-optimality) would. The prior makes ``Phi`` finite
before five poses and is negligible after them.

**Search.** Greedy forward selection from a seeded candidate set (each step adds the pose of
largest gain ``sum_i log(1 + x_i^T M_i^-1 x_i)``, the matrix determinant lemma, with
``x_i = J_ip^T / sigma_i``), then Fedorov exchanges (swap a chosen pose for a candidate while
``det`` grows: ``(1 + d(x))(1 - d(y)) + d(x, y)^2`` per sensor), then the chosen poses are put
in greedy order again, so that the first ``k`` of them are the best greedy ``k``-subset.
"""

from __future__ import annotations

import numpy as np

from metrology.calibration.estimators import DEFAULT_P0_SIGMA
from metrology.core.effects.characteristic import legendre23
from metrology.core.layout import SensorLayout
from metrology.core.model import jacobian_tangent, readings

__all__ = ["pose_information", "prior_information", "INCIDENCE_PRIOR_MM", "SCALE_PRIOR", "NONLINEARITY_PRIOR_MM",
           "EXTRA_COLUMNS", "greedy_order", "exchange", "log_det", "covariance", "MAX_EXCHANGES"]

#: most Fedorov exchanges tried after the greedy pass (each one raises det)
MAX_EXCHANGES = 200


#: prior 1-sigma (mm) of an incidence coefficient ``c`` (bias ``c tan^2`` of the incidence angle,
#: ``c`` the bias at 45 deg: :class:`metrology.core.effects.sensor.Incidence`) when the design
#: also separates incidence from the beam direction; wide against the catalogue's 0.02-0.15 mm
INCIDENCE_PRIOR_MM = 1.0

#: prior 1-sigma (unitless) of a gain error ``k`` (bias ``k d0``:
#: :class:`metrology.core.effects.characteristic.Scale`) when the design also separates it; wide
#: against real gain errors (10^-4 to 10^-2)
SCALE_PRIOR = 0.1

#: prior 1-sigma (mm) of the bow and S-shape ``c2 P2(x) + c3 P3(x)`` of the characteristic
#: (:class:`metrology.core.effects.characteristic.Nonlinearity`); wide against datasheet linearity
NONLINEARITY_PRIOR_MM = 1.0

#: the extra columns a design may carry per sensor, in this order after the five of the chart:
#: each parameter's name (as the plan reports its standard error) and prior 1-sigma
EXTRA_COLUMNS = {"incidence": (("incidence_c_mm", INCIDENCE_PRIOR_MM),), "scale": (("scale_k", SCALE_PRIOR),),
                 "nonlinearity": (("nonlinearity_c2_mm", NONLINEARITY_PRIOR_MM),
                                  ("nonlinearity_c3_mm", NONLINEARITY_PRIOR_MM))}


def _extra(extra) -> tuple:
    """The extra columns asked for, in :data:`EXTRA_COLUMNS` order (a bool is ``("incidence",)``)."""
    if isinstance(extra, bool):
        extra = ("incidence",) if extra else ()
    unknown = [c for c in extra if c not in EXTRA_COLUMNS]
    if unknown:
        raise ValueError(f"extra design columns {unknown}: expected some of {list(EXTRA_COLUMNS)}")
    return tuple(c for c in EXTRA_COLUMNS if c in extra)


def prior_information(n: int, P0_sigma=DEFAULT_P0_SIGMA, incidence=()) -> np.ndarray:
    """``(n, m, m)`` float, m = 5 plus one per extra column (``incidence``: a tuple of
    :data:`EXTRA_COLUMNS` names, or True for ``("incidence",)``): the inverse of the filters'
    prior covariance per sensor (1/mm^2, 1/rad^2; then 1/mm^2 for the incidence coefficient,
    unitless for the gain, 1/mm^2 for the curve's c2, c3)."""
    s_pos, s_dir = P0_sigma
    diag = [s_pos**-2] * 3 + [s_dir**-2] * 2 + [s**-2 for c in _extra(incidence) for _, s in EXTRA_COLUMNS[c]]
    return np.broadcast_to(np.diag(diag), (n, len(diag), len(diag))).copy()


def pose_information(layout: SensorLayout, normal, offset, sigma_mm, incidence=()) -> np.ndarray:
    """Whitened Jacobian rows of every reading at every pose.

    Parameters
    ----------
    layout : SensorLayout, where to linearise (the nominal: chart at zero)
    normal : (p, 3) float, unit, TCS; offset : (p,) float, mm: the datum at each pose
    sigma_mm : (n,) float, mm, reading noise

    incidence : tuple of str, names of :data:`EXTRA_COLUMNS` (True means ``("incidence",)``)
        Extra columns per sensor, in :data:`EXTRA_COLUMNS` order: ``"incidence"`` the term
        ``tan^2(gamma)`` (``gamma`` the angle between the beam and the datum normal), ``"scale"``
        the gain term ``d0`` (the nominal reading, mm), ``"nonlinearity"`` the bow and S-shape
        ``P2(x), P3(x)`` of the reading normalised over the sensor's range (two columns, as
        :class:`~metrology.core.effects.characteristic.Nonlinearity`): the design then also tells those
        causes from the beam geometry and from each other. On a canted beam both follow the
        tilt (tilting toward the beam shortens the reading and lowers ``gamma``), so a plan
        that spreads tilts alone leaves ``k d0`` and ``c tan^2`` nearly collinear.

    Returns
    -------
    X : (p, n, 5 + extra) float, 1/sigma times ``dd/d(x, y, z)`` (1/mm * mm/mm), ``dd/d(a, b)``,
        ``dd/dc``, ``dd/dk`` (mm) and ``dd/d(c2, c3)``; zero where the beam misses the plane (no reading, no
        information)
    """
    extra = _extra(incidence)
    J = jacobian_tangent(layout.zero, layout.direction, np.zeros((layout.n, 2)), normal, offset)
    cols = []
    if "incidence" in extra:
        cos = np.abs(np.asarray(normal, float) @ layout.direction.T)
        with np.errstate(divide="ignore"):
            cols.append(1.0 / cos**2 - 1.0)
    if "scale" in extra or "nonlinearity" in extra:
        d0 = readings(layout.zero, layout.direction, normal, offset)[0]
    if "scale" in extra:
        cols.append(d0)
    if "nonlinearity" in extra:
        lo, hi = np.asarray(layout.range_mm, float).T
        x = (2 * d0 - lo - hi) / (hi - lo)
        cols += list(legendre23(x))
    if cols:
        J = np.concatenate([J, np.stack(cols, axis=-1)], axis=-1)
    X = J / np.asarray(sigma_mm, float)[None, :, None]
    return np.where(np.isfinite(X), X, 0.0)


def log_det(X, prior) -> float:
    """``sum_i log det(prior_i + X_i^T X_i)`` of the poses ``X (k, n, 5)``; ``prior (n, 5, 5)``."""
    M = prior + np.einsum("pni,pnj->nij", X, X)
    sign, ld = np.linalg.slogdet(M)
    return float(np.sum(np.where(sign > 0, ld, -np.inf)))


def covariance(X) -> np.ndarray:
    """``(n, m, m)`` float, mm and rad: the data-only covariance ``(X_i^T X_i)^-1``; inf where the
    poses do not determine every parameter (fewer than five, or a rank-deficient set)."""
    M = np.einsum("pni,pnj->nij", X, X)
    out = np.full(M.shape, np.inf)
    for i in range(len(M)):
        s = np.linalg.svd(M[i], compute_uv=False)
        if s[-1] > 1e-12 * s[0]:
            out[i] = np.linalg.inv(M[i])
    return out


def _gains(X, Minv):
    """``(c,)`` log-det gain of adding each candidate ``X (c, n, 5)`` to information with inverse ``Minv``."""
    return np.sum(np.log1p(np.einsum("cni,nij,cnj->cn", X, Minv, X)), axis=1)


def greedy_order(X, k: int, prior, pool=None) -> np.ndarray:
    """Indices of ``k`` poses of ``X (c, n, 5)`` chosen one by one, each with the largest gain.

    Parameters
    ----------
    X : (c, n, 5) float, whitened rows (:func:`pose_information`)
    k : int, poses to choose (at most the pool's size)
    prior : (n, 5, 5) float
    pool : (q,) int, optional, the candidates to choose from (default all)

    Returns
    -------
    order : (k,) int, indices into ``X`` in the order chosen
    """
    pool = np.arange(len(X)) if pool is None else np.asarray(pool)
    if k > len(pool):
        raise ValueError(f"{k} poses asked for, only {len(pool)} feasible candidates")
    Minv = np.linalg.inv(prior)
    free = np.ones(len(pool), bool)
    order = []
    Xp = X[pool]
    for _ in range(k):
        g = np.where(free, _gains(Xp, Minv), -np.inf)
        j = int(np.argmax(g))
        free[j] = False
        order.append(pool[j])
        x = Xp[j]  # (n, 5): Sherman-Morrison per sensor
        Mx = np.einsum("nij,nj->ni", Minv, x)
        Minv = Minv - np.einsum("ni,nj->nij", Mx, Mx) / (1.0 + np.einsum("ni,ni->n", x, Mx))[:, None, None]
    return np.array(order, int)


def exchange(X, chosen, prior, pool=None, max_swaps: int = MAX_EXCHANGES) -> np.ndarray:
    """Fedorov exchanges on the set ``chosen``: swap the pair (chosen y, candidate x) that raises
    ``det`` most, while one does (by more than one part in 10^9).

    Returns the improved set (unordered), ``(k,)`` int indices into ``X``.
    """
    pool = np.arange(len(X)) if pool is None else np.asarray(pool)
    chosen = np.array(chosen, int)
    for _ in range(max_swaps):
        M = prior + np.einsum("pni,pnj->nij", X[chosen], X[chosen])
        Minv = np.linalg.inv(M)
        out = np.setdiff1d(pool, chosen)
        if not len(out):
            break
        Xx, Xy = X[out], X[chosen]
        dx = np.einsum("cni,nij,cnj->cn", Xx, Minv, Xx)  # (c, n)
        dy = np.einsum("kni,nij,knj->kn", Xy, Minv, Xy)  # (k, n)
        dxy = np.einsum("cni,nij,knj->ckn", Xx, Minv, Xy)  # (c, k, n)
        ratio = (1 + dx[:, None, :]) * (1 - dy[None, :, :]) + dxy**2
        score = np.sum(np.log(np.maximum(ratio, 1e-300)), axis=2)
        c, j = np.unravel_index(int(np.argmax(score)), score.shape)
        if score[c, j] <= 1e-9:
            break
        chosen[j] = out[c]
    return chosen
