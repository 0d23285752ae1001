"""Is a characteristic named really the sensor's own? The crosstalk check.

One sensor's reading shifted in proportion to *another* sensor's distance (light of one spot
seen by the next sensor, a shared supply) looks to the diagnosis like a gain error: the
stand-off moves every sensor's distance together (and an incidence bias, which the tilts that
move them apart also drive). It is not a catalogued cause, so it must not come out as ``scale``,
``nonlinearity`` or ``incidence``. For such a cause named on sensor ``i``, the term
``c d0_j`` (``j`` another sensor) is fitted in its place, with the same held-out test. If one
predicts held-out poses significantly better (Bonferroni over the other sensors), the cause is
not named: the effect follows another sensor's distance. If the two cannot be told apart, it is
not named either, and the verdict says why (:mod:`metrology.diagnosis.decide`).

Both are compared on the readings the selection judged the characteristic on: a held-out
reading beyond its sensor's training span tests how a curve with turns extrapolates, not
which term the data follow (:func:`~metrology.diagnosis.heldout.beyond_span`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.effects import Component
from metrology.diagnosis.fit import FitData
from metrology.diagnosis.heldout import beyond_span, kfold
from metrology.diagnosis.stats import paired_gain_p
from metrology.diagnosis import rules

__all__ = ["OtherReading", "CrosstalkCheck", "crosstalk_check"]


@dataclass(frozen=True)
class OtherReading(Component):
    """``c d0_j`` on sensor ``sensors[0]``: a shift in proportion to sensor ``source``'s distance
    (``c`` unitless). Not a catalogued cause (not in the registry): a check only."""

    source: int = 0

    name = "crosstalk"
    param_names = ("coupling",)
    param_units = ("1",)

    @property
    def label(self):
        src = self.names[self.source] if self.names else str(self.source)
        return super().label + f"<-{src}"

    def basis(self, d0, cov):
        out = np.zeros(d0.shape + (1,))
        out[:, list(self.sensors), 0] = d0[:, [self.source]]
        return out


@dataclass(frozen=True)
class CrosstalkCheck:
    """The crosstalk check of one characteristic (:func:`crosstalk_check`).

    better : str or None, the label of the crosstalk term (``crosstalk.L2<-L1``) that predicts
    held-out poses significantly better (rule 12; the smallest p of those that do), None where none
    does; p : float, its one-sided paired p-value (1.0 where none is better);
    indistinguishable : tuple of str, the labels of the crosstalk terms that predict as well
    (not significantly worse), in the order of the other sensors.
    """

    better: str | None = None
    p: float = 1.0
    indistinguishable: tuple = ()


def crosstalk_check(ds, b, given, named, folds) -> CrosstalkCheck:
    """Compare the characteristic ``named`` (a CandidateResult on one sensor, scored given the
    components ``given``) with crosstalk from each other sensor, held out (a :class:`CrosstalkCheck`).
    """
    nominal, obs = ds.layout, ds.obs
    i = named.component.sensors[0]
    others = [j for j in range(nominal.n) if j != i]
    better, p_best, tie = None, 1.0, []
    # the readings the selection judged a characteristic on (score_candidate): a held-out
    # reading beyond the training span tests the curve's extrapolation, where a P5 or a spline
    # diverges, and one such pose swamps the paired test either way
    excl = beyond_span(obs.d, folds) if named.component.uses_d0 else None
    ref = named.heldout.chi2_pose(b.sigma, [i], excl)
    for j in others:
        c = OtherReading((i,), names=nominal.names, source=j)
        ho = kfold(FitData(nominal, obs, b.cov, b.sigma), tuple(given) + (c,), folds, b.theta0)
        d = ref - ho.chi2_pose(b.sigma, [i], excl)  # > 0: crosstalk predicts better
        if np.allclose(d, 0):
            continue
        p_better, p_worse = paired_gain_p(d), paired_gain_p(-d)
        if rules.crosstalk_better(p_better, len(others)) and p_better < p_best:
            better, p_best = c.label, p_better
        elif rules.crosstalk_as_good(p_worse):
            tie.append(c.label)
    return CrosstalkCheck(better, p_best, tuple(tie))
