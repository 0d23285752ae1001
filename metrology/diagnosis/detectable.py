"""The detectable size of each family on the poses of a data set (the 95 % power of its test).

A ``none`` verdict says that no cause is above what the data can show; this module says how
large that is, per family and sensor, in the family's own size unit (the ``size`` that
``causes`` reports). For each family's simplest member scored at the first step, the size at
which its in-sample F-test, at the level it is run (``alpha_candidates`` split over the
candidates), is passed with probability 95 % (the noncentral F distribution), from the
member's covariance at the stated noise. This is the limit of detection in the ISO 11843 sense
(false negatives 5 %, false positives at the test's level), for a shape that is the member's
own; an effect of another shape in the family is detected at about this size when the member
follows it, later when it does not. For ``nonlinearity`` and ``incidence``, whose shapes vary
most, the size is instead that of the least favourable of a few shapes of the family, each
detected by the best of the family's members (below). The held-out test must also pass, so
this is a lower bound.

- ``scale``: peak-to-valley of the gain error over the readings' span (mm), large enough to be
  told from crosstalk too (a shift with another sensor's distance, which it must beat to be named);
- ``nonlinearity``: peak-to-valley, less its best straight line, of a characteristic over the
  readings' span (mm), for the least favourable of the Legendre shapes ``P2``, ``P3``, ``P4``
  there and the best of the family's members for each (:func:`family_detectable`);
- ``drift``: peak-to-valley over the run of a drift linear in time, or in temperature where
  that member is the more sensitive (mm);
- ``incidence``: the bias at the largest incidence angle seen (mm), for the least favourable of
  the even shapes ``a^2``, ``a^4``, ``a^6`` (``a`` the incidence angle; ``1 - cos a`` is close to
  the first) and the best of the family's members for each (:func:`family_detectable`): the
  family is any even bias, and one that grows slowly with the angle (``a^2``) changes least over
  the angles seen for its value at the largest, so the zero point takes most of it; the ``tan^2``
  member's own shape is among the easiest;
- ``plane_form``: peak-to-valley of the scanned form seen by the spots (mm; with a datum cloud);
- ``pose_error``: RMS change of a reading by a per-pose rigid error, its offset and tilts
  together, at the least favourable split between them (mm): with 3 sensors the power of the
  random-effect test (:mod:`metrology.diagnosis.posevar`), with more that of the offset and the
  offset-and-tilts members' F-tests;
- ``outliers``: one gross reading (mm; the flagging threshold plus 1.645 sigma).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from metrology.core.effects import REGISTRY, Component, Outliers
from metrology.diagnosis.extension import _free_offset, size_of
from metrology.diagnosis.posevar import base_jacobian
from metrology.diagnosis import rules
from metrology.diagnosis.thresholds import THRESHOLDS

__all__ = ["Detectable", "detectable_sizes", "noncentrality_95", "family_detectable"]

#: the power at which a size is called detectable
POWER = 0.95


@dataclass(frozen=True)
class Detectable:
    """The size of one family detectable at 95 % power on these poses (:func:`detectable_sizes`).

    meaning : str, what the size measures (the family's ``detectable_meaning``);
    sensors : dict, where -> float or None, in the family's size unit (mm): ``where`` a sensor's
    name, the member's sensors joined by ``", "``, or ``"all"`` for a family of the set-up;
    ``inf`` where some shape of the family is seen by no member;
    member : dict, the same keys -> str, the label of the member sized there (``+``-joined where
    the best of several members sizes it; ``{}`` for outliers, sized by the flagging threshold).
    """

    meaning: str
    sensors: dict = field(default_factory=dict)
    member: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """The ``--json``'s entry: ``{"sensors", "member", "meaning"}``."""
        return {"sensors": dict(self.sensors), "member": dict(self.member), "meaning": self.meaning}


def noncentrality_95(k: int, dof: int, alpha: float) -> float:
    """The noncentrality ``lambda`` at which an F(k, dof) test at level ``alpha`` has 95 % power."""
    from scipy import optimize, stats

    dof = max(int(dof), 1)
    crit = float(stats.f.isf(alpha, k, dof))

    def power(lam):
        return float(stats.ncf.sf(crit, k, dof, lam)) - POWER

    hi = 10.0
    while power(hi) < 0:
        hi *= 2.0
    return float(optimize.brentq(power, 0.0, hi))


def _known_noise_cov(f, which):
    """The component's parameter covariance at the stated noise (the fit scales by chi2/dof)."""
    k0 = _free_offset(f, which)
    n = f.components[which].n_params
    s2 = f.chi2 / max(f.dof, 1)
    return f.extra_cov[k0:k0 + n, k0:k0 + n] / max(s2, 1e-300)


def _size_along(c, v, cov, d0):
    """(size of the member's shape ``v`` (its parameters), v^T C^-1 v) for a scored candidate."""
    f = c.fit
    which = len(f.components) - 1  # the candidate is last (given causes first)
    comp = f.components[which]
    C = _known_noise_cov(f, which)
    v = np.asarray(v, float)
    f_v = replace(f, components=f.components[:which] + (replace(comp, values=v),))
    s = size_of(f_v, which, cov, d0)
    if s is None or not np.isfinite(s.value) or s.value <= 0:
        return None
    info = float(v @ np.linalg.pinv(C, rcond=1e-12, hermitian=True) @ v)
    return abs(s.value), info


def _scale_against_crosstalk(b, ds, J, i) -> float:
    """``|d0_i|`` left once the sensor's five base columns ``J[:, i]`` and the most collinear
    other sensor's distance ``d0_j`` (crosstalk, which ``scale`` must beat to be named) are
    projected out (mm)."""
    nominal, obs = ds.layout, ds.obs
    rows = np.isfinite(obs.d[:, i])
    x = b.d0[rows, i]
    worst = np.inf
    for j in range(nominal.n):
        if j == i:
            continue
        A = np.column_stack([J[rows, i, :], b.d0[rows, j]])
        r = x - A @ np.linalg.lstsq(A, x, rcond=None)[0]
        worst = min(worst, float(np.linalg.norm(r)))
    return worst


def family_detectable(shapes, members, J_i, sigma_i, alpha) -> float:
    """The size at which every shape of a family is detected at 95 % power by one of its members.

    shapes : list of (p,) float, the family's shapes on one sensor's readings, each of size 1 in
    the family's unit (NaN where the reading is blank); members : list of ``(B, k, dof)``,
    ``B (p, m)`` a member's columns on that sensor (mm per unit parameter), ``k`` and ``dof`` its
    F-test's degrees of freedom (its free parameters; the residual's); J_i : (p, 5) float, mm
    per unit parameter, the sensor's base Jacobian (the geometry the fit frees beside the
    member); sigma_i : float, mm, the stated noise. A member's noncentrality for a
    shape is what it explains of the shape once the base geometry has taken its part (whitened);
    a shape is detected at the smallest size any member detects it at; the family at the largest
    such size over its shapes (inf where a shape is invisible to every member).
    """
    lam95 = [noncentrality_95(max(int(k), 1), dof, alpha) for _, k, dof in members]  # per member, once
    worst = 0.0
    for s in shapes:
        rows = np.isfinite(s)
        X0 = J_i[rows] / sigma_i
        y = s[rows] / sigma_i
        r0 = y - X0 @ np.linalg.lstsq(X0, y, rcond=None)[0]
        best = np.inf
        for (B, _, _), l95 in zip(members, lam95):
            X1 = np.column_stack([X0, B[rows] / sigma_i])
            r1 = y - X1 @ np.linalg.lstsq(X1, y, rcond=None)[0]
            lam1 = float(r0 @ r0 - r1 @ r1)  # the noncentrality of a unit size
            if lam1 > 1e-12 * float(y @ y):  # (not round-off of a shape the base takes whole)
                best = min(best, float(np.sqrt(l95 / lam1)))
        worst = max(worst, best)
    return worst


def _worst_shape(cause, members, b, ds, J, alpha) -> float:
    """:func:`family_detectable` for a family on one sensor (``members`` its scored candidates
    there; ``J`` the base Jacobian (p, n, 5)) over the family's shapes (the registry entry's
    :meth:`~metrology.core.effects.Component.detectable_shapes`)."""
    i = members[0].component.sensors[0]
    shapes = members[0].component.detectable_shapes(b.d0[:, i], b.cov.cos_inc[:, i], np.isfinite(ds.obs.d[:, i]))
    if not shapes:
        return np.inf
    J_i = J[:, i, :]
    cols = [(c.component.basis(b.d0, b.cov)[:, i, :], c.n_params, c.fit.dof) for c in members]
    return family_detectable(shapes, cols, J_i, float(b.sigma[i]), alpha)


def detectable_sizes(scored, b, n_obs, ds) -> dict[str, Detectable]:
    """Per family and sensor, the size detectable at 95 % power on these poses (see the module).

    scored : the first step's CandidateResults; b : the BaseAnalysis; n_obs : (n,) int, finite
    readings per sensor; ds : the Dataset (the readings, poses and layout). Returns family ->
    :class:`Detectable`, in the order the families are first met.
    """
    from scipy import stats

    n_cand = max(len(scored), 1)
    alpha = THRESHOLDS["alpha_candidates"] / n_cand
    out: dict[str, Detectable] = {}
    J = None  # the base Jacobian, computed once when the scale or a family's shapes need it
    worst_of = {}  # (family, sensors) -> its members, for the families sized by their worst shape
    for c in scored:
        if type(c.component).detectable_size is not Component.detectable_size and c.component.sensors:
            # the registry entry says what its test detects (a located effect: over its positions)
            if J is None:
                J = base_jacobian(b, ds)
            i = c.component.sensors[0]
            det = c.component.detectable_size(J[:, i, :], b.cov, np.isfinite(ds.obs.d[:, i]), float(b.sigma[i]), alpha)
            if det is not None:
                fam = out.setdefault(c.cause, Detectable(c.component.detectable_meaning))
                fam.sensors[c.sensors[0]] = float(det)
                fam.member[c.sensors[0]] = c.label
            continue
        if c.component.worst_shape:
            # any shape of the family, not the simplest member's alone, by the best of its
            # members (sized below, once its members are all known); listed where its simplest
            # member (the one with a reported direction) comes, as every other family is
            key = ", ".join(c.sensors)
            worst_of.setdefault((c.cause, key), []).append(c)
            if c.component.detectable_direction() is not None:
                out.setdefault(c.cause, Detectable(c.component.detectable_meaning)).sensors[key] = None
            continue
        v = c.component.detectable_direction()
        if v is not None:
            got = _size_along(c, v, b.cov, b.d0)
            if got is None:
                continue
            size_v, info = got
            if info <= 0:
                continue
            k = max(int(c.n_params), 1)
            lam = noncentrality_95(k, c.fit.dof, alpha)
            det = size_v * float(np.sqrt(lam / info))
            if "crosstalk" in c.component.confused_with and ds.layout.n > 1:
                # named only where it beats crosstalk (metrology.diagnosis.crosstalk): the gain's
                # part that no other sensor's distance carries
                i = c.component.sensors[0]
                lo, hi = b.cov.d_span[i] if b.cov.d_span is not None else b.cov.range_mm[i]
                if J is None:
                    J = base_jacobian(b, ds)
                r = _scale_against_crosstalk(b, ds, J, i)
                det = max(det, float(np.sqrt(lam)) * float(b.sigma[i]) * float(hi - lo) / max(r, 1e-300))
        else:
            continue
        fam = out.setdefault(c.cause, Detectable(c.component.detectable_meaning))
        key = ", ".join(c.sensors) if c.sensors and not c.component.setup else "all"
        if key not in fam.sensors or det < fam.sensors[key]:
            fam.sensors[key] = det
            fam.member[key] = c.label
    if worst_of and J is None:
        J = base_jacobian(b, ds)
    for cause in [k for k in out if REGISTRY[k].worst_shape]:
        for key in out[cause].sensors:
            members = worst_of[(cause, key)]
            out[cause].sensors[key] = _worst_shape(cause, members, b, ds, J, alpha)
            out[cause].member[key] = "+".join(c.label for c in members)
    pose = [c for c in scored if c.component.per_pose]
    if pose:
        # the RMS change of a reading by a rigid pose error, whatever its split between offset and
        # tilts: with 3 sensors by the random-effect test that names it (metrology.diagnosis.posevar),
        # with more by the members' F-tests
        from metrology.diagnosis.posevar import detectable_rms

        if any(c.component.per_pose_columns > 1 for c in pose):  # (detectable_rms_fixed, below)
            det = detectable_rms_fixed(ds, b, [(int(c.component.per_pose_columns > 1), c.n_params, c.fit.dof)
                                                for c in pose], alpha)
        else:
            det = detectable_rms(ds, b, THRESHOLDS["alpha_candidates"] / (n_cand + 1))
        out["pose_error"] = Detectable(pose[0].component.detectable_meaning, {"all": det},
                                       {"all": "+".join(c.label for c in pose)})
    # a gross reading: the flagging threshold (family-wise over the readings) plus 1.645 sigma
    m = int(np.sum(n_obs))
    t = float(stats.norm.isf(rules.gross_level(max(m, 1))))
    out["outliers"] = Detectable(Outliers.detectable_meaning, {name: float((t + stats.norm.isf(1 - POWER)) * s)
                                                                for name, s in zip(b.calibrated.names, b.sigma)})
    return out


def detectable_rms_fixed(ds, b, members, alpha, power=0.95, splits=5) -> float:
    """As :func:`metrology.diagnosis.posevar.detectable_rms` for the members fitted pose by pose (4 sensors or more):
    ``members`` a list of ``(columns, k, dof)``, ``columns`` 0 for the offset alone or 1 for
    the offset and two tilts, ``k``, ``dof`` its F-test's degrees of freedom. A pose error is
    detected when one member's F-test passes; its noncentrality is the expected whitened energy
    of the pose error that the base fit does not absorb, within the member's columns."""
    from metrology.diagnosis.posevar import _projections, pose_columns

    ok = np.isfinite(ds.obs.d)
    A_mm = pose_columns(ds, b)
    A = np.where(ok[..., None], A_mm / b.sigma[None, :, None], 0.0)
    D, Wa, Wb, _ = _projections(ds, b, (), ok, A)
    A2 = np.where(ok[..., None], A_mm, np.nan) ** 2
    per = np.array([np.nanmean(A2[..., 0]), np.nanmean(A2[..., 1] + A2[..., 2])])
    lam_per = []  # per member: the noncentrality per unit offset and tilt variance
    for cols, k, dof in members:
        B = A[..., :1] if cols == 0 else A
        Pm = np.einsum("pim,pmk,pjk->pij", B, np.linalg.pinv(np.einsum("pnm,pnk->pmk", B, B), hermitian=True), B)
        lam_per.append((np.array([np.einsum("pij,pji->", Pm, Wa), np.einsum("pij,pji->", Pm, Wb)]),
                        noncentrality_95(max(int(k), 1), dof, alpha)))
    worst = 0.0
    for share in np.linspace(0.0, 1.0, splits):
        v = np.array([share / per[0], (1 - share) / per[1]])  # variances per unit mean-square
        rms = min(np.sqrt(l95 / max(float(lam @ v), 1e-300)) for lam, l95 in lam_per)
        worst = max(worst, float(rms))
    return worst
