"""The named extension: its description with standard errors, and simulations of the data set
under a model (the side-by-side figures)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from metrology.core.effects import ExtendedModel
from metrology.core.observations import Observations
from metrology.diagnosis.fit import Fit, FitData, FitOptions, fit, fit_any
from metrology.diagnosis.heldout import Problem, kfold
from metrology.diagnosis.results import Size

__all__ = ["describe_named", "size_of", "simulated_figures", "POSE_FLOOR_REPS"]


#: simulated noise-only copies used to measure the noise floor of the per-pose estimates
POSE_FLOOR_REPS = 8


def _free_offset(f: Fit, which: int) -> int:
    """Index of component ``which``'s first parameter in ``f.extra_cov`` / ``f.corr_base``."""
    return sum(c.n_params for c in f.components[:which] if not c.per_pose)


def size_of(f: Fit, which: int, cov, d0) -> Size | None:
    """The size of component ``which`` of ``f`` in its family's unit, with a standard error
    (delta method on the fit's covariance): a :class:`~metrology.diagnosis.results.Size` (no
    model spread: :func:`with_model_spread` adds it), or None where the family has none (the
    registry entry's :meth:`~metrology.core.effects.Component.size`). cov : Covariates;
    d0 : (p, n) float, mm, the base readings."""
    comp = f.components[which]
    if comp.per_pose:
        return None
    k0 = _free_offset(f, which)
    s = comp.size(f.extra_cov[k0:k0 + comp.n_params, k0:k0 + comp.n_params], d0, cov)
    return None if s is None else Size(**s)


def describe_named(f: Fit, problem: Problem, rng, which: int = 0, theta_ref=None):
    """The public description of component ``which`` of ``f`` (default its first), a fit of
    ``problem``: parameters with standard errors and their largest correlations with the base
    parameters; for a pose error the noise-corrected sigma (parametric bootstrap, ``rng``; for a
    rigid one, of the fit that holds the geometry at ``theta_ref``), for outliers the flagged
    readings."""
    nominal, obs, cov, sigma = problem.ds.layout, problem.ds.obs, problem.b.cov, problem.b.sigma
    comp = f.components[which]
    d = comp.describe()
    if comp.per_pose:
        # sigma of the pose error along the normal: the spread of the per-pose estimates less
        # the spread that reading noise alone puts in them (through the per-pose fit and the
        # base parameters it trades with), measured on noise-only simulations of these poses
        m = comp.per_pose_columns
        fv, held = f, comp
        if comp.tilts and theta_ref is not None:
            # the per-pose values of the fit that holds the geometry at ``theta_ref`` (the base
            # calibration), as the member was scored: freed, the geometry moves along what one
            # reading a pose leaves weak, and the values take it up
            comps = tuple(replace(c, values=None, stderr=None, **({"hold": True} if k == which else {}))
                          for k, c in enumerate(f.components))
            fv = fit_any(FitData(nominal, obs, cov, sigma), comps, theta_ref, "lsq")
            held = fv.components[which]
        e = np.asarray(held.values).reshape(-1, m)[:, 0]
        model = replace(fv.model(nominal), components=())
        d_model = model.predict(obs.normal, obs.offset, cov)

        def estimate(e_sim):
            """sigma-hat of noise-only copies (the floor) or copies with per-pose errors ``e_sim``."""
            vals = []
            for _ in range(POSE_FLOOR_REPS):
                dn = d_model + rng.normal(0.0, 1.0, d_model.shape) * sigma[None, :]
                if e_sim is not None:
                    dn = dn + rng.normal(0.0, e_sim, len(dn))[:, None] * cov.inv_nu
                dn = np.where(np.isfinite(obs.d), dn, np.nan)
                fn = fit(FitData(nominal, Observations(obs.normal, obs.offset, dn), cov, sigma), [replace(held, values=None)],
                         theta0=fv.theta, options=FitOptions(solver="gn"))
                vals.append(np.var(np.asarray(fn.components[0].values).reshape(-1, m)[:, 0], ddof=1))
            return np.array(vals)

        v_floor = float(np.mean(estimate(None)))
        sig_raw = np.sqrt(max(float(np.var(e, ddof=1)) - v_floor, 0.0))
        # parametric bootstrap: the spread of the per-pose estimates also takes up weakly
        # identified base-parameter combinations; re-estimate on copies with pose errors of the
        # estimated size, correct the bias and take their scatter as the standard error
        boot = np.sqrt(np.maximum(estimate(sig_raw) - v_floor, 0.0))
        sig_e = max(sig_raw - (float(np.mean(boot)) - sig_raw), 0.0)
        d["params"] = {"sigma_mm": {"value": sig_e, "unit": "mm", "stderr": float(np.std(boot, ddof=1))},
                       "noise_floor_mm": {"value": float(np.sqrt(v_floor)), "unit": "mm", "stderr": None}}
        d["per_pose_mm"] = e.tolist()
        if comp.tilts:  # the two tilts a pose (mm at RADIUS_MM), raw spread: what a rigid error adds
            t = np.asarray(held.values).reshape(-1, m)[:, 1:]
            d["params"]["tilt_sigma_rad"] = {"value": float(np.std(t, ddof=1) / comp.RADIUS_MM), "unit": "rad",
                                             "stderr": None}
    q0 = _free_offset(f, which)
    d["base_correlation"] = [] if comp.per_pose else [
        {"param": comp.param_names[q], "max_abs_corr": float(f.corr_base[q0 + q]), "with": f.corr_with[q0 + q]}
        for q in range(comp.n_params)]
    return d


def simulated_figures(problem: Problem, model: ExtendedModel, rng, reps, extra=None):
    """Simulation of ``problem``'s data set under ``model`` (plus ``extra (p, n)`` mm where given: the
    open search's empirical terms, :attr:`~metrology.diagnosis.search.Empirical.fitted`) plus the
    stated noise, analysed with the base model from its calibration: in-sample residual RMS per
    sensor (n,) mm and held-out normal deviation mean (rad; ``problem.folds``-fold), averaged over
    ``reps`` draws."""
    nominal, obs, cov, sigma = problem.ds.layout, problem.ds.obs, problem.b.cov, problem.b.sigma
    k, theta0 = problem.folds, problem.b.theta0
    d_model = model.predict(obs.normal, obs.offset, cov)
    if extra is not None:
        d_model = d_model + np.where(np.isfinite(extra), extra, 0.0)
    rms, ndev = [], []
    for _ in range(reps):
        d = d_model + rng.normal(0.0, 1.0, d_model.shape) * sigma[None, :]
        d = np.where(np.isfinite(obs.d), d, np.nan)
        o = Observations(obs.normal, obs.offset, d)
        b = fit_any(FitData(nominal, o, cov, sigma), (), theta0)
        rms.append(np.sqrt(np.nanmean(b.residual**2, axis=0)))
        ndev.append(np.nanmean(kfold(FitData(nominal, o, cov, sigma), (), k, theta0).normal_dev))
    return np.mean(rms, axis=0), float(np.mean(ndev)), float(np.std(ndev))


def with_model_spread(size: Size | None, chosen, scored, cov, d0) -> Size | None:
    """``size`` (of :func:`size_of`) with the spread of the family's other members added to its
    standard error: the members significant at the step where ``chosen`` was selected, on its
    sensors, that it does not predict held-out poses significantly better than (``alpha_order``).

    The data cannot choose between those members, and each gives its own size of the effect (a
    warm-cool drift as linear in temperature or as lagged, an S-curve as a gain or a spline):
    their largest difference from the size named is the model's share of the uncertainty,
    added in quadrature (``stderr``; the fit's own is ``stderr_fit``, the spread ``model_spread``).
    """
    from metrology.diagnosis.select import family_of, p_better
    from metrology.diagnosis import rules

    if size is None or size.stderr is None:
        return size
    spread = 0.0
    for m in scored:
        if m.label == chosen.label or not m.significant:
            continue
        if family_of(m.component) != family_of(chosen.component):
            continue
        if rules.better_held_out(p_better(chosen, m)):
            continue  # the named member predicts held-out poses better: not a rival
        s = size_of(m.fit, len(m.fit.components) - 1, cov, d0)
        if s is not None and s.meaning == size.meaning and np.isfinite(s.value):
            spread = max(spread, abs(abs(s.value) - abs(size.value)))
    return replace(size, stderr=float(np.hypot(size.stderr, spread)), stderr_fit=size.stderr, model_spread=spread)
