"""The open search: where the catalogue does not explain the residuals, their dependence on the run's
variables, found, fitted and measured (issue 54).

When the verdict leaves the residuals inconsistent with the noise (``unexplained``, or ``partial``:
:func:`~metrology.diagnosis.rules.search_tried`), every term of the vocabulary
(:mod:`metrology.diagnosis.vocabulary`) is scored on every sensor against the residuals of the
model the verdict judged, as the catalogue's candidates are (the rules are in
:mod:`metrology.diagnosis.rules`, 19-21):

- in sample, the F-test of the term's columns fitted with the sensor's base parameters (its
  Jacobian at the calibration, so the term is fitted jointly with them, to first order), at
  ``ALPHA_CANDIDATES`` split over the sensors, the variables and each variable's terms (a
  weighted Bonferroni, :func:`multiplicity`: the search's multiplicity);
- held out, the same k-fold by pose (interleaved folds): on each fold the base parameters and the
  term are fitted to the other poses and predict the held-out readings; the per-pose chi-square
  gain is tested one-sided and paired at ``ALPHA_HELDOUT``.

Terms are added by forward selection (the passing term of the smallest in-sample p whose held-out
gain is significant; at most ``MAX_EMPIRICAL`` terms), refitted jointly with each sensor's base
parameters and reported as equations in units. The residuals' distribution is tested last, per
sensor: heavy tails (in sample the kurtosis test at the tails' own level, one test a sensor; held out
a contaminated normal against the normal, by the per-pose log-likelihood gain). The verdict keeps its cause (the family is unknown) and gains
:class:`Empirical`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from metrology.diagnosis import rules
from metrology.diagnosis.heldout import folds as fold_sets
from metrology.diagnosis.results import Decision, Param, Reason
from metrology.diagnosis.stats import paired_gain_p
from metrology.diagnosis.vocabulary import Term, terms_for

__all__ = ["EmpiricalTerm", "Empirical", "search", "multiplicity", "TRIES_PER_STEP", "MIN_READINGS"]

#: candidates passing in sample whose held-out test is tried at one step before the search stops
TRIES_PER_STEP = 5
#: the fewest readings of a sensor the search looks at
MIN_READINGS = 12


@dataclass(frozen=True)
class EmpiricalTerm:
    """One term the search found.

    sensor : str; key : str, the term (:class:`~metrology.diagnosis.vocabulary.Term`'s); variables :
    tuple of str, from :data:`~metrology.diagnosis.vocabulary.VARIABLES`; equation : str, in units;
    meaning : str; params : dict of str to Param, the coefficients (mm per unit of the column) with
    their standard errors, fitted jointly with the sensor's base parameters; size : Param, the
    term's peak-to-valley over the poses (mm; for ``tails`` the contaminated fraction); gain_chi2 :
    float, its held-out chi-square gain (for ``tails``, twice the held-out log-likelihood gain);
    p_heldout, p_insample : float (for ``tails`` the larger of the scatter's and the shape's p); step : int; plot : dict or None, what its partial-residual figure
    draws (``x (m,)`` the term's variable on the sensor's readings: the column of a line, the phase
    in rad of a periodic term, the fitted term of a shape; ``partial (m,)`` mm, the residual with the
    term added back; ``fit (m,)`` mm, the term; ``xlabel``), not in ``--json``.
    """

    sensor: str
    key: str
    variables: tuple
    equation: str
    meaning: str
    params: dict
    size: Param
    gain_chi2: float
    p_heldout: float
    p_insample: float
    step: int
    plot: dict | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict:
        return {"sensor": self.sensor, "term": self.key, "variables": list(self.variables), "equation": self.equation,
                "meaning": self.meaning, "params": {k: v.to_dict() for k, v in self.params.items()},
                "size": self.size.to_dict(), "heldout_gain_chi2": self.gain_chi2, "p_heldout": self.p_heldout,
                "p_insample": self.p_insample, "step": self.step}


@dataclass(frozen=True)
class Empirical:
    """The search's result: ``terms`` (EmpiricalTerm, in the order chosen), ``variables`` (every
    variable they name, in order), ``gain_chi2`` (their held-out chi-square gains summed),
    ``n_tried`` (the terms the in-sample level was split over), ``level`` (the level of a variable
with one term on one sensor: :func:`multiplicity`),
    ``reasons`` (rules 19-21 as they fired); ``heldout_rms_mm`` : (2,) float or None, mm, the
    k-fold held-out residual RMS on the sensors with a term other than ``tails``, without and with
    the terms (the base parameters refitted on each fold either way); ``fitted`` : (p, n) float or
    None, mm, the terms (other than ``tails``) fitted jointly with each sensor's base parameters, at
    every pose (0 on a sensor without a term, NaN where no reading): what the side-by-side simulation
    adds to the model; ``heldout`` : ``(without, with)`` (p, n) float each or None, mm, the k-fold
    held-out residuals on the sensors with a term (NaN elsewhere). Neither is in ``--json``."""

    terms: tuple = ()
    variables: tuple = ()
    gain_chi2: float = 0.0
    n_tried: int = 0
    level: float = 0.0
    reasons: tuple = field(default=(), repr=False)
    heldout_rms_mm: tuple | None = None
    fitted: np.ndarray | None = field(default=None, repr=False, compare=False)
    heldout: tuple | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict:
        out = {"terms": [t.to_dict() for t in self.terms], "variables": list(self.variables),
               "heldout_gain_chi2": self.gain_chi2, "terms_tried": self.n_tried, "level_insample": self.level}
        if self.heldout_rms_mm is not None:
            out.update(heldout_rms_without_mm=self.heldout_rms_mm[0], heldout_rms_with_mm=self.heldout_rms_mm[1])
        return out


class _Sensor:
    """One sensor's problem: its finite readings' rows, the base Jacobian ``X`` (and the terms taken),
    the residual ``r`` (mm) and the noise ``s`` (mm)."""

    def __init__(self, r, J, s, k):
        self.fin = np.isfinite(r) & np.all(np.isfinite(J), axis=1)
        self.r, self.s = np.where(self.fin, r, 0.0), float(s)
        self.X = J[self.fin]
        self.taken = []  # Terms
        p = len(r)
        self.folds = [np.intersect1d(f, np.flatnonzero(self.fin)) for f in fold_sets(p, k)]

    def design(self, extra=None):
        cols = [self.X] + [t.columns[self.fin] for t in self.taken] + ([] if extra is None else [extra[self.fin]])
        return np.column_stack(cols)

    def _reference(self):
        """The model without the term, held once per state: an orthonormal basis of its design
        ``(m, rank)``, the residual of the readings off it, its size and rank."""
        key = len(self.taken)
        if getattr(self, "_ref_key", None) != key:
            X0, y = self.design(), self.r[self.fin]
            U, sv, _ = np.linalg.svd(X0, full_matrices=False)
            Q = U[:, sv > 1e-10 * max(float(sv[0]), 1e-300)]
            e = y - Q @ (Q.T @ y)
            self._ref, self._ref_key = (Q, e, float(e @ e), float(sv[0])), key
        return self._ref

    def f_test(self, term: Term) -> float:
        """In-sample p of ``term`` given the base parameters and the terms taken (an F-test: the
        term's columns projected off the model without it)."""
        from scipy.special import fdtrc  # the F distribution's survival function (scipy.stats.f.sf's)

        Q, e, rss0, s0 = self._reference()
        C = term.columns[self.fin]
        Ct = C - Q @ (Q.T @ C)
        if Ct.shape[1] == 1:  # one column: its own direction
            nc = float(np.linalg.norm(Ct))
            U = Ct / nc if nc > 1e-10 * max(s0, float(np.linalg.norm(C)), 1e-300) else Ct[:, :0]
        else:
            U, sv, _ = np.linalg.svd(Ct, full_matrices=False)
            U = U[:, sv > 1e-10 * max(s0, float(np.linalg.norm(C)), 1e-300)]
        k = U.shape[1]
        rss1 = rss0 - float(np.sum((U.T @ e) ** 2))
        dof = len(e) - Q.shape[1] - k
        if k <= 0 or dof <= 0 or rss1 <= 0:
            return 1.0
        return float(fdtrc(k, dof, ((rss0 - rss1) / k) / (rss1 / dof)))

    def heldout(self, cols):
        """Per-pose held-out residuals ``(p,)`` mm (NaN off the sensor's readings) of the base parameters,
        the terms taken and ``cols`` (p, k) (None: without), each fold fitted on the other poses."""
        X = np.column_stack([self._full_X()] + [t.columns for t in self.taken] + ([] if cols is None else [cols]))
        out = np.full(len(self.r), np.nan)
        train_all = np.flatnonzero(self.fin)
        for test in self.folds:
            train = np.setdiff1d(train_all, test)
            beta = np.linalg.lstsq(X[train], self.r[train], rcond=1e-10)[0]
            out[test] = self.r[test] - X[test] @ beta
        return out

    def _full_X(self):
        full = np.zeros((len(self.r), self.X.shape[1]))
        full[self.fin] = self.X
        return full

    def gain(self, term: Term):
        """``(per-pose held-out chi-square gain (poses,), p)`` of ``term`` against the model without it."""
        e0, e1 = self.heldout(None), self.heldout(term.columns)
        d = ((e0**2 - e1**2) / self.s**2)[self.fin]
        return d, paired_gain_p(d)


def search(ds, cov, d0, residual, sigma, J, folds: int) -> Empirical:
    """The open search (see the module) on ``residual (p, n)`` mm, the residuals of the model the
    verdict judged (NaN where no reading, or a reading named gross); ``d0 (p, n)`` mm the base
    readings, ``J (p, n, q)`` the base model's Jacobian per sensor, ``sigma (n,)`` mm the stated noise."""
    names = ds.layout.names
    n = residual.shape[1]
    sens = [_Sensor(residual[:, i], J[:, i], sigma[i], folds) for i in range(n)]
    # a sensor with fewer readings than a fold's fit needs is not searched
    pool = {i: terms_for(ds.export, cov, d0, i, names, sens[i].fin) if sens[i].fin.sum() >= MIN_READINGS else []
            for i in range(n)}
    n_tried = sum(len(v) for v in pool.values())  # the tails are a family of their own (rule 21)
    share = multiplicity(pool)
    level = rules.ALPHA_CANDIDATES / max(min(share.values(), default=1), 1)  # a one-term variable's
    why, found = [], []
    scores = {i: {t.key: sens[i].f_test(t) for t in pool[i]} for i in range(n)}
    while rules.room_for_another_term(len(found)):
        ranked = sorted(((p * share[i, t.key], p, i, t) for i in range(n) for t in pool[i]
                         for p in (scores[i][t.key],) if rules.search_in_sample(p, share[i, t.key])),
                        key=lambda x: x[0])
        ranked = [x[1:] for x in ranked]
        step = len(found) + 1
        took = None
        for p_in, i, t in ranked[:TRIES_PER_STEP]:
            d, p_ho = sens[i].gain(t)
            held = rules.search_held_out(p_ho, float(np.sum(d)))
            why.append(Reason(20, "search_held_out", Decision.EMPIRICAL if held else Decision.EMPIRICAL_NOT_HELD,
                              (f"{names[i]}: {t.key}",), "p_heldout", p_ho, rules.ALPHA_HELDOUT, float(np.sum(d)), step))
            if held:
                took = (i, t, p_in, p_ho, float(np.sum(d)))
                break
        if took is None:
            why.append(Reason(19, "search_in_sample", Decision.NOTHING_SIGNIFICANT, (), "terms passing in sample",
                              len(ranked), level, step=step))
            break
        i, t, p_in, p_ho, g = took
        sens[i].taken.append(t)
        pool[i] = [u for u in pool[i] if u.key != t.key]
        scores[i] = {u.key: sens[i].f_test(u) for u in pool[i]}
        found.append((i, t, p_in, p_ho, g, step))
    terms = [_describe(sens[i], t, names[i], p_in, p_ho, g, step) for i, t, p_in, p_ho, g, step in found]
    terms += _tails(sens, names, n_tried, why, len(found))
    variables = tuple(dict.fromkeys(v for t in terms for v in t.variables))
    fitted, held = _fitted(sens) if found else (None, None)
    return Empirical(tuple(terms), variables, float(sum(t.gain_chi2 for t in terms)), n_tried, level, tuple(why),
                     _heldout_rms([sen for sen in sens if sen.taken]), fitted, held)


def _fitted(sens) -> tuple:
    """The terms taken on every sensor, fitted jointly with its base parameters ``(p, n)`` mm, and
    the held-out residuals ``(without, with)`` on the sensors with terms (NaN elsewhere)."""
    p, n = len(sens[0].r), len(sens)
    fitted = np.zeros((p, n))
    e0, e1 = np.full((p, n), np.nan), np.full((p, n), np.nan)
    for i, sen in enumerate(sens):
        fitted[~sen.fin, i] = np.nan
        if not sen.taken:
            continue
        X = sen.design()
        beta = np.linalg.lstsq(X, sen.r[sen.fin], rcond=1e-10)[0]
        k0 = sen.X.shape[1]
        T = np.column_stack([t.columns for t in sen.taken])
        fitted[:, i] = np.where(sen.fin, T @ beta[k0:], np.nan)
        e1[:, i] = sen.heldout(None)
        taken, sen.taken = sen.taken, []
        e0[:, i] = sen.heldout(None)
        sen.taken = taken
    return fitted, (e0, e1)


def multiplicity(pool) -> dict:
    """``(sensor, term key) -> m``: the in-sample level of a term is ``ALPHA_CANDIDATES / m`` (rule 19),
    the level split equally over the sensors searched, on each over the variables its terms follow
    (a term's ``variables``), and within a variable over its terms (a weighted Bonferroni: the
    weights sum to one, so the search's family-wise level is the catalogue's). A variable scanned
    over a thousand plane waves does not dilute the one line of another."""
    from collections import Counter

    live = {i: ts for i, ts in pool.items() if ts}
    out = {}
    for i, ts in live.items():
        groups = Counter(t.variables for t in ts)
        for t in ts:
            out[i, t.key] = len(live) * len(groups) * groups[t.variables]
    return out


def _heldout_rms(with_terms) -> tuple | None:
    """``(without, with)`` the k-fold held-out residual RMS (mm) over the sensors ``with_terms``."""
    if not with_terms:
        return None
    after = np.concatenate([sen.heldout(None)[sen.fin] for sen in with_terms])
    before = []
    for sen in with_terms:
        taken, sen.taken = sen.taken, []
        before.append(sen.heldout(None)[sen.fin])
        sen.taken = taken
    return float(np.sqrt(np.mean(np.concatenate(before) ** 2))), float(np.sqrt(np.mean(after**2)))


def _describe(sen: _Sensor, t: Term, name, p_in, p_ho, gain, step) -> EmpiricalTerm:
    """The term fitted jointly with the sensor's base parameters and the other terms taken, as an
    equation in units (um)."""
    X = sen.design()
    y = sen.r[sen.fin]
    beta, _, rank, _ = np.linalg.lstsq(X, y, rcond=1e-10)
    e = y - X @ beta
    s2 = float(e @ e) / max(len(y) - rank, 1)
    C = s2 * np.linalg.pinv(X.T @ X, rcond=1e-12, hermitian=True)
    k0 = X.shape[1] - sum(u.columns.shape[1] for u in sen.taken)
    for u in sen.taken:
        if u.key == t.key:
            break
        k0 += u.columns.shape[1]
    k = t.columns.shape[1]
    b, Cb = beta[k0:k0 + k], C[k0:k0 + k, k0:k0 + k]
    term = t.columns[sen.fin] @ b
    hi, lo = int(np.argmax(term)), int(np.argmin(term))
    g = t.columns[sen.fin][hi] - t.columns[sen.fin][lo]
    size = Param(float(term[hi] - term[lo]), "mm", float(np.sqrt(max(g @ Cb @ g, 0.0))))
    um = 1e3
    if t.kind == "line":
        per = "" if t.unit == "1" else f"/{t.unit}"
        eq = f"{name} reads {b[0] * um:+.3g} ± {np.sqrt(Cb[0, 0]) * um:.2g} um{per} x {t.expr}"
        params = {"c": Param(float(b[0]), "mm" + per, float(np.sqrt(Cb[0, 0])))}
        meaning = f"the reading depends on {', '.join(t.variables)}"
    elif t.kind == "periodic":
        A = float(np.hypot(*b))
        gA = b / max(A, 1e-300)
        se = float(np.sqrt(max(gA @ Cb @ gA, 0.0)))
        phase = float(np.arctan2(b[1], b[0]))
        eq = (f"{name} reads {A * um:.3g} ± {se * um:.2g} um x sin(2 pi {t.expr} / {t.period:.4g}"
              f"{' ' + t.period_unit if t.period_unit else ''} {phase:+.2f} rad)")
        params = {"amplitude": Param(A, "mm", se), "phase": Param(phase, "rad", None),
                  "period": Param(float(t.period), t.period_unit or "1", None)}
        meaning = f"a periodic error in {t.variables[0]}"
    else:
        eq = f"{name} reads {t.expr}, {size.value * um:.3g} ± {size.stderr * um:.2g} um peak-to-valley"
        params = {f"c{j}": Param(float(b[j]), "mm", float(np.sqrt(max(Cb[j, j], 0.0)))) for j in range(k)}
        meaning = f"the reading depends on {', '.join(t.variables)}"
    cols = t.columns[sen.fin]
    x, xlabel = ((cols[:, 0], t.expr) if t.kind == "line" else
                 (np.arctan2(cols[:, 0], cols[:, 1]), f"phase of 2 pi {t.expr} / {t.period:.4g} {t.period_unit} [rad]")
                 if t.kind == "periodic" else (term * um, f"the fitted term [um]: {t.expr}"))
    plot = {"x": x, "partial": e + term, "fit": term, "xlabel": xlabel}
    return EmpiricalTerm(name, t.key, t.variables, eq, meaning, params, size, gain, p_ho, p_in, step, plot)


def _mixture(z, core=None):
    """Maximum-likelihood contaminated normal of ``z`` (unit stated noise): ``(q, s1, s2)``, ``q`` the
    fraction of scale ``s2 > s1`` (EM from a robust start); ``core``: ``s1`` held there."""
    z2 = z**2
    s1 = float(core) if core is not None else max(float(1.4826 * np.median(np.abs(z))), 1e-6)
    s2, q = 3.0 * s1, 0.1
    for _ in range(200):
        a = (1 - q) * np.exp(-0.5 * z2 / s1**2) / s1
        b = q * np.exp(-0.5 * z2 / s2**2) / s2
        w = b / np.maximum(a + b, 1e-300)
        q = float(np.clip(np.mean(w), 1e-4, 0.9))
        if core is None:
            s1 = float(np.sqrt(max(np.sum((1 - w) * z2) / max(np.sum(1 - w), 1e-12), 1e-12)))
        s2 = float(np.sqrt(max(np.sum(w * z2) / max(np.sum(w), 1e-12), s1**2 * 1.0001)))
    return q, s1, s2


def _loglik(z, q, s1, s2):
    return np.log((1 - q) * np.exp(-0.5 * z**2 / s1**2) / s1 + q * np.exp(-0.5 * z**2 / s2**2) / s2)


def _tails(sens, names, n_tried, why, step0) -> list:
    """Rule 21: per sensor, the residuals' distribution (after the terms taken). In sample, their
    scatter beyond the stated noise (the chi-square of the residuals, at the tails' own level: one
    test a sensor) with a shape heavier than a normal's (the kurtosis test, one-sided, at
    ``ALPHA_HELDOUT``: noise merely understated is normal); held out, a contaminated normal whose core
    is the stated noise against a normal of the residuals' own scale, each fitted on the other
    folds, by the per-pose log-likelihood gain."""
    from scipy import stats

    out = []
    n_sens = sum(sen.fin.sum() >= MIN_READINGS for sen in sens)
    for i, sen in enumerate(sens):
        if sen.fin.sum() < MIN_READINGS:
            continue
        e = sen.heldout(None)  # held-out residuals: a tail is judged on readings its fit did not see
        fin = sen.fin & np.isfinite(e)
        y = sen.r[sen.fin]
        X = sen.design()
        beta, _, rank, _ = np.linalg.lstsq(X, y, rcond=1e-10)
        z = (y - X @ beta) / sen.s
        p_scatter = float(stats.chi2.sf(float(z @ z), max(len(z) - rank, 1)))
        p_shape = float(stats.kurtosistest(z, alternative="greater").pvalue) if len(z) >= 8 else 1.0
        p_in = max(p_scatter, p_shape)  # both tests pass: the larger is reported
        if not rules.search_tails_in_sample(p_scatter, n_sens, p_shape):
            continue
        q, s1, s2 = _mixture(z, core=1.0)
        d = np.full(len(sen.r), np.nan)
        for test in sen.folds:
            train = np.setdiff1d(np.flatnonzero(fin), test)
            zt = e[train] / sen.s
            qt, a1, a2 = _mixture(zt, core=1.0)
            st = float(np.sqrt(np.mean(zt**2)))
            zz = e[test] / sen.s
            d[test] = 2.0 * (_loglik(zz, qt, a1, a2) - _loglik(zz, 0.0, st, st))
        d = d[np.isfinite(d)]
        p_ho = paired_gain_p(d)
        g = float(np.sum(d))
        held = rules.search_held_out(p_ho, g)
        step = step0 + len(out) + 1
        why.append(Reason(21, "search_tails", Decision.EMPIRICAL if held else Decision.EMPIRICAL_NOT_HELD,
                          (f"{names[i]}: tails",), "p_heldout", p_ho, rules.ALPHA_HELDOUT, g, step))
        if not held:
            continue
        eq = (f"{names[i]}'s readings have heavy tails: {100 * q:.3g} % of them scatter {s2 / s1:.3g} times "
              f"the rest ({s1 * sen.s * 1e3:.3g} um)")
        out.append(EmpiricalTerm(names[i], "tails", ("tails",), eq, "the noise is not normal: a contaminated normal",
                                 {"fraction": Param(q, "1", None), "scale_ratio": Param(s2 / s1, "1", None),
                                  "sigma_core": Param(s1 * sen.s, "mm", None)},
                                 Param(q, "1", None), g, p_ho, p_in, step))
    return out
