"""The catalogue against the open search: which explains a named cause's residual (rule 22).

A catalogued cause of one sensor is a curve in that sensor's variables (``drift`` in time and
temperature, ``nonlinearity`` in its distance, ...). An effect outside the catalogue that follows
a variable those curves can bend to (a zero that follows the temperature's rate: ``T - T_lag`` is
close to ``tau dT/dt``; a square of the neighbour's distance, which the stand-off moves with this
sensor's) is then taken by the catalogue first, and the open search never sees it. So for each
cause named on one sensor the vocabulary's terms (:mod:`metrology.diagnosis.vocabulary`) compete
for the same residual, the base model's on that sensor: the terms that pass in sample at the
search's level (rule 19, its multiplicity as the search's) are fitted *in place of* the cause,
with the base parameters, on the same k-fold by pose, and the per-pose held-out chi-squares are
compared paired. Where a term predicts significantly better (rule 22), the cause is not named:
the verdict becomes ``unexplained`` and the open search runs on the base residuals. A term that
with fewer coefficients than the cause predicts better, but not significantly, leaves the cause named, its confidence ``ambiguous`` (from
``high`` or ``moderate``), the term said beside it and the search run on the base residuals (as crosstalk's tie, rule 12: the catalogue is the prior, its families
the common causes, but the data do not tell them apart).

Both are compared on the readings the selection judges a characteristic on (a held-out reading
beyond its sensor's training span tests extrapolation, as :mod:`metrology.diagnosis.crosstalk`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from metrology.diagnosis import rules
from metrology.diagnosis.heldout import beyond_span
from metrology.diagnosis.results import Confidence, Decision, Outcome, Reason
from metrology.diagnosis.stats import paired_gain_p

__all__ = ["RivalTerm", "empirical_rivals", "TRIES"]

#: the terms (smallest in-sample p first, passing rule 19's level) compared with each cause
TRIES = 5
#: the vocabulary's variables the curves of a catalogued family are made of (a drift's, in time or in
#: temperature, are the run's clock as well: a warm-up moves both): a term of none of them is of
#: another family (rule 22's ``empirical_indistinguishable``)
OWN_VARIABLES = {"scale": ("d",), "nonlinearity": ("d",), "incidence": ("incidence",),
                 "drift": ("time", "pose_index", "temperature"), "shift": ("time", "pose_index"),
                 "plane_form": ("spot",)}


@dataclass(frozen=True)
class RivalTerm:
    """A term of the vocabulary that predicts a named cause's residual better held out.

    cause : str, the cause's label; sensor : str; term : str, the term's key; p : float, the
    one-sided paired p that the term predicts held-out poses better than the cause; gain : float,
    the per-pose held-out chi-square difference summed (> 0: the term better); rule : str, the rule
    that tied it (``empirical_as_good`` or ``empirical_indistinguishable``; a term found better, the
    first's name is unused)."""

    cause: str
    sensor: str
    term: str
    p: float
    gain: float
    rule: str = "empirical_as_good"


def _cause_columns(component, d0, cov, i):
    """The cause's columns on sensor ``i`` ``(p, k)`` (every catalogued term is linear in its values)."""
    B = np.asarray(component.basis(d0, cov), float)[:, i, :]
    return np.where(np.isfinite(B), B, 0.0)


def _collinearity(term, cause, fin) -> float:
    """The multiple correlation of the term's columns ``(p, k)`` on the cause's ``(p, k_c)`` and a
    constant, over the readings ``fin (p,)`` (the smallest over the term's columns; 0 where either is
    constant): 1 where the cause's curve reproduces the term's (rule 22's ``empirical_collinear``)."""
    X = np.column_stack([np.ones(int(fin.sum())), np.asarray(cause, float)[fin]])
    out = 1.0
    for y in np.asarray(term, float)[fin].T:
        yc = y - y.mean()
        ss = float(yc @ yc)
        if not ss > 0:
            return 0.0
        res = y - X @ np.linalg.lstsq(X, y, rcond=None)[0]
        out = min(out, float(np.sqrt(max(0.0, 1.0 - float(res @ res) / ss))))
    return out


def empirical_rivals(ds, b, v, chosen, gross, folds) -> tuple:
    """``(v, rivals)``: the judgement ``v`` with rule 22 applied to the causes it names (``chosen``
    the selection's CandidateResults), ``rivals`` the RivalTerms found. A sole cause beaten: the
    verdict ``unexplained`` (confidence ``low``); one of several: confidence ``ambiguous``."""
    from metrology.core.effects import REGISTRY
    from metrology.core.model import jacobian_raw
    from metrology.diagnosis.fit import geometry
    from metrology.diagnosis.search import MIN_READINGS, _Sensor, multiplicity
    from metrology.diagnosis.vocabulary import VARIABLES, Term, terms_for

    if v.outcome != Outcome.NAMED:
        return v, ()
    names = ds.layout.names
    n = len(names)
    named = {c.label for c in v.causes}
    cands = [s for s in chosen if s.label in named and len(s.component.sensors) == 1
             and not s.component.per_pose and not REGISTRY[s.component.name].setup]
    if not cands:
        return v, ()
    zero, u = geometry(ds.layout, b.fit.theta)
    J = jacobian_raw(zero, u, ds.obs.normal, ds.obs.offset)
    resid = np.where(gross, np.nan, b.fit.residual)
    excl_all = beyond_span(ds.obs.d, folds)
    found, ties, why = [], [], []
    for s in cands:
        i = s.component.sensors[0]
        r = resid[:, i].copy()
        if s.component.uses_d0:
            r[excl_all[:, i]] = np.nan
        sen = _Sensor(r, J[:, i], b.sigma[i], folds)
        if sen.fin.sum() < MIN_READINGS:
            continue
        pool = terms_for(ds.export, b.cov, b.d0, i, names, sen.fin)
        # the search's multiplicity (its terms on every sensor: this sensor's, n times)
        share = {key: m * n for (_, key), m in multiplicity({i: pool}).items()}
        scored = sorted((p * share[t.key], t.key, t) for t in pool for p in (sen.f_test(t),)
                        if rules.search_in_sample(p, share[t.key]))
        if not scored:
            continue
        cause = Term("cause", (), _cause_columns(s.component, b.d0, b.cov, i), "shape", s.label)
        own = set(OWN_VARIABLES.get(s.component.name, VARIABLES))  # a family not listed: every variable its own
        others = {x for c in chosen if c.label in named and c.label != s.label
                  for x in OWN_VARIABLES.get(c.component.name, ())}
        tries = [x for x in scored if not rules.rival_of_another_cause(x[2].variables, others)][:TRIES]
        if not tries:
            continue
        e_c = sen.heldout(cause.columns)
        best = tie = None
        tie_corr = float('nan')
        for _, _, t in tries:
            e_t = sen.heldout(t.columns)
            d = ((e_c**2 - e_t**2) / sen.s**2)[sen.fin]
            p, g = paired_gain_p(d), float(np.sum(d))
            if rules.empirical_better(p, len(tries)) and (best is None or p < best.p):
                best = RivalTerm(s.label, names[i], t.key, p, g)
            elif tie is None and rules.empirical_as_good(g, paired_gain_p(-d), t.columns.shape[1], cause.columns.shape[1]):
                tie = RivalTerm(s.label, names[i], t.key, p, g)
            elif tie is None and rules.empirical_indistinguishable(g, t.columns.shape[1], cause.columns.shape[1],
                                                                   bool(own & set(t.variables))):
                tie = RivalTerm(s.label, names[i], t.key, p, g, "empirical_indistinguishable")
            elif tie is None and rules.empirical_collinear(corr := _collinearity(t.columns, cause.columns, sen.fin),
                                                           t.columns.shape[1], cause.columns.shape[1],
                                                           bool(own & set(t.variables))):
                tie = RivalTerm(s.label, names[i], t.key, p, g, "empirical_collinear")
                tie_corr = corr
        if best is not None:
            found.append(best)
            why.append(Reason(22, "empirical_better", Decision.EMPIRICAL_BETTER, (s.label, f"{best.sensor}: {best.term}"),
                              "p_better", best.p, rules.ALPHA_HELDOUT / len(tries), best.gain))
        elif tie is not None:
            ties.append(tie)
            collinear = tie.rule == "empirical_collinear"  # its statistic the correlation, at rule 15's level
            why.append(Reason(22, tie.rule, Decision.EMPIRICAL_TIE, (s.label, f"{tie.sensor}: {tie.term}"),
                              "correlation" if collinear else "p_better", tie_corr if collinear else tie.p,
                              rules.CORR_CONFOUND if collinear else rules.ALPHA_HELDOUT / len(tries), tie.gain))
    if not found:
        if not ties:
            return v, ()
        lowered = Confidence.AMBIGUOUS if v.confidence in (Confidence.HIGH, Confidence.MODERATE) else v.confidence
        return replace(v, confidence=lowered, reasons=v.reasons + tuple(why)), ()
    if len(v.causes) == 1:
        v = replace(v, cause=Outcome.UNEXPLAINED, confidence=Confidence.LOW, sensors=[], causes=(), named=None,
                    reasons=v.reasons + tuple(why))
    else:
        v = replace(v, confidence=Confidence.AMBIGUOUS, reasons=v.reasons + tuple(why))
    return v, tuple(found)
