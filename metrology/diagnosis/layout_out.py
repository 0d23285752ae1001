"""What a diagnosis names goes into the head's layout: ``metro diagnose --out extended.toml``.

The causes named that are properties of the head (a sensor's gain, incidence response,
characteristic, temperature coefficient of its zero: :data:`metrology.core.effects.terms.HEAD_TERMS`)
are refitted with the sensors' five parameters, jointly, on the whole run
(:func:`metrology.calibration.terms.fit_with_terms`), and written as a calibrated layout with
``[sensors.effects.*]`` terms and the joint covariance. The causes of the set-up and of this run's
time are not written; :class:`ExtendedLayout` says which went in, which did not and why
(:func:`metrology.core.effects.terms.why_not_a_head_term`).

A layout that already carries terms (``diagnose --layout extended.toml``) is diagnosed on the
readings with its terms removed (:func:`terms_removed`): what it explains is not named again,
and ``--out`` refits its terms together with any new one.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

__all__ = ["ExtendedLayout", "extend_layout", "terms_removed"]


@dataclass(frozen=True)
class ExtendedLayout:
    """The layout ``diagnose --out`` writes.

    layout : SensorLayout, calibrated, with the head terms (``effects``) and the joint covariance;
    written : tuple of str, the terms' labels; not_written : tuple of (label, why);
    carried : tuple of str, the terms the input layout had (refitted with the new ones);
    fit : TermFit or None (no term)
    """

    layout: object
    written: tuple
    not_written: tuple
    carried: tuple = ()
    fit: object = None

    def to_dict(self) -> dict:
        return {"terms_written": list(self.written), "written": bool(self.written),
                "carried_from_layout": list(self.carried),
                "not_written": [{"label": lab, "why": why} for lab, why in self.not_written],
                "terms": [] if self.fit is None else self.fit.to_dict()}

    def words(self) -> str:
        """What went into the layout and what did not, in a few lines."""
        lines = []
        if self.written:
            lines.append("layout: head terms written with the sensors' parameters and their joint covariance: "
                         + ", ".join(self.written))
        else:
            lines.append("layout: no head term named; the sensors' calibration written without terms")
        lines += [f"  not written: {lab}: {why}" for lab, why in self.not_written]
        return "\n".join(lines)


def _base_covariates(ds):
    """The base calibration of ``ds`` and the covariates of its poses there."""
    from metrology.calibration.estimators import calibrate
    from metrology.calibration.terms import dataset_covariates

    cal = calibrate(ds.layout, ds.obs, "lsq")
    return cal, dataset_covariates(cal.layout, ds.obs, ds.export, ds.plane, ds.datum_points)


def terms_removed(ds):
    """``ds`` (a Dataset whose layout carries terms) with its readings corrected by them and its layout
    without them: the data the simple model should explain if the terms are all the head has."""
    from metrology.calibration.terms import corrected_obs

    from metrology.calibration.terms import dataset_covariates

    terms = ds.layout.effects
    plain = replace(ds, layout=replace(ds.layout, effects=None))
    cov = dataset_covariates(ds.layout, ds.obs, ds.export, ds.plane, ds.datum_points)  # at the layout's geometry
    d = corrected_obs(terms, ds.obs, cov).d
    return replace(plain, export=replace(ds.export, d=d))


def _component(cause, names, cov, d):
    """The registry member of ``cause`` (a named :class:`Cause`) to refit, matched by its label; None
    when the catalogue has no member of that label on that sensor."""
    from metrology.core.effects import REGISTRY

    cls = REGISTRY.get(cause.cause)
    if cls is None or len(cause.sensors) != 1:
        return None
    i = names.index(cause.sensors[0])
    cands = list(cls.candidates_for_sensor(i, names, cov))
    if cause.cause == "nonlinearity":
        di = np.sort(d[np.isfinite(d[:, i]), i])
        for c in list(cands):
            if c.order == 0:
                for k in c.SPLINE_LADDER:
                    cands += c.richer(k, di, c.span)
    for c in cands:
        if c.label == cause.label:
            return c
    return None


def extend_layout(ds, diag, carried=None) -> ExtendedLayout:
    """The layout of ``ds``'s sensors refitted with the head terms ``diag`` names and the ``carried``
    ones (the input layout's HeadTerms, or None), jointly (module docstring)."""
    from metrology.calibration.terms import fit_with_terms
    from metrology.calibration.fitted import _finish
    from metrology.core.effects.terms import NOT_HEAD, is_head_term, why_not_a_head_term
    from metrology.core.model import chart_cov_recentred

    nominal = replace(ds.layout, effects=None)
    cal, cov = _base_covariates(replace(ds, layout=nominal))
    names = nominal.names
    comps = list(carried.components if carried else ())  # their values the start, their stderr kept
    have = {c.label for c in comps}
    not_written = []
    for cause in diag.causes:
        comp = _component(cause, names, cov, ds.export.d)
        if comp is None:
            why = NOT_HEAD.get(cause.cause, f"{cause.cause} is not a property of one sensor of the head")
            not_written.append((cause.label, why))
        elif not is_head_term(comp):
            not_written.append((cause.label, why_not_a_head_term(comp)))
        elif comp.label in have or any(c.name == comp.name and c.sensors == comp.sensors for c in comps):
            not_written.append((cause.label, "the layout has a term of this family on this sensor already"))
        else:
            comps.append(comp)
            have.add(comp.label)
    if not comps:
        return ExtendedLayout(cal.layout, (), tuple(not_written))
    theta, C, sig, fit = fit_with_terms(nominal, ds.obs, cov, comps, prior=carried, theta0=cal.theta)
    n = nominal.n
    blocks = np.stack([C[5 * i:5 * i + 5, 5 * i:5 * i + 5] for i in range(n)])
    out = _finish("lsq", nominal, ds.obs, theta, blocks, sig).layout
    base = chart_cov_recentred(nominal.direction, theta[:, 3:], C[:5 * n, :5 * n])
    layout = replace(out, covariance=0.5 * (base + base.T), effects=fit.terms)
    new = tuple(c.label for c in fit.terms.components)
    return ExtendedLayout(layout, new, tuple(not_written), tuple(c.label for c in carried.components) if carried else (),
                          fit)
