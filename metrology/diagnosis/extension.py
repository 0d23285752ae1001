"""The named extension: its description with standard errors, and simulations of the data set
under a model (the side-by-side figures)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from metrology.core.effects import ExtendedModel, Outliers, PoseError
from metrology.core.observations import Observations
from metrology.diagnosis.fit import Fit, fit, fit_any
from metrology.diagnosis.heldout import kfold

__all__ = ["describe_named", "simulated_figures", "dof_per_sensor", "POSE_FLOOR_REPS"]


#: simulated noise-only copies used to measure the noise floor of the per-pose estimates
POSE_FLOOR_REPS = 8


def describe_named(f: Fit, nominal, obs, cov, sigma, rng):
    """The public description of the named component of ``f`` (its first): parameters with
    standard errors and their largest correlations with the base parameters; for a pose error
    the noise-corrected sigma (parametric bootstrap, ``rng``), for outliers the flagged readings."""
    comp = f.components[0]
    d = comp.describe()
    if isinstance(comp, PoseError):
        # sigma of the pose error along the normal: the spread of the per-pose estimates less
        # the spread that reading noise alone puts in them (through the per-pose fit and the
        # base parameters it trades with), measured on noise-only simulations of these poses
        e = comp.values
        model = replace(f.model(nominal), components=())
        d_model = model.predict(obs.normal, obs.offset, cov)

        def estimate(e_sim):
            """sigma-hat of noise-only copies (the floor) or copies with per-pose errors ``e_sim``."""
            vals = []
            for _ in range(POSE_FLOOR_REPS):
                dn = d_model + rng.normal(0.0, 1.0, d_model.shape) * sigma[None, :]
                if e_sim is not None:
                    dn = dn + rng.normal(0.0, e_sim, len(dn))[:, None] * cov.inv_nu
                dn = np.where(np.isfinite(obs.d), dn, np.nan)
                fn = fit(nominal, Observations(obs.normal, obs.offset, dn), cov, sigma, [replace(comp, values=None)],
                         theta0=f.theta, solver="gn")
                vals.append(np.var(fn.components[0].values, ddof=1))
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
    if isinstance(comp, Outliers):
        d["flagged"] = [{"pose": int(pp), "sensor": comp.names[i], "gross_mm": float(v), "stderr": float(s)}
                        for (pp, i), v, s in zip(comp.cells, comp.values, comp.stderr)]
        d["params"] = {"count": {"value": len(comp.cells), "unit": "1", "stderr": None}}
    d["base_correlation"] = [{"param": comp.param_names[q], "max_abs_corr": float(c), "with": w}
                             for q, (c, w) in enumerate(zip(f.corr_base, f.corr_with))]
    return d


def simulated_figures(nominal, obs, cov, sigma, model: ExtendedModel, k, theta0, rng, reps, per_pose_sigma=None):
    """Simulation of this data set under ``model`` plus the stated noise, analysed with the
    base model: in-sample residual RMS per sensor (n,) mm and held-out normal deviation mean
    (rad), averaged over ``reps`` draws."""
    d_model = model.predict(obs.normal, obs.offset, cov)
    rms, ndev = [], []
    for _ in range(reps):
        d = d_model + rng.normal(0.0, 1.0, d_model.shape) * sigma[None, :]
        d = np.where(np.isfinite(obs.d), d, np.nan)
        o = Observations(obs.normal, obs.offset, d)
        b = fit_any(nominal, o, cov, sigma, (), theta0)
        rms.append(np.sqrt(np.nanmean(b.residual**2, axis=0)))
        ndev.append(np.nanmean(kfold(nominal, o, cov, sigma, (), k, theta0).normal_dev))
    return np.mean(rms, axis=0), float(np.mean(ndev)), float(np.std(ndev))


def dof_per_sensor(f: Fit, obs, n):
    cnt = np.isfinite(obs.d).sum(axis=0).astype(float)
    dof = cnt - 5
    for c in f.components:
        if c.sensors:
            for i in c.sensors:
                dof[i] -= c.n_params / len(c.sensors)
        else:
            dof -= (c.n_params - (3 if c.per_pose else len(c.constraint(c.values)[0]))) / n
    return dof

