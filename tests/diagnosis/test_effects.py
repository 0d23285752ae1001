"""The effect components and their registry."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.core.effects import Covariates, Drift, ExtendedModel, Outliers, Scale
from metrology.sim.synth import typical_layouts

from .helpers import all_components, small_case

def test_component_jacobians_against_finite_differences():
    ds, cov = small_case()
    d0 = ds.export.d
    for c in all_components(ds, cov):
        J = c.jacobian(c.values, d0, cov)
        h = 1e-6
        for k in range(min(c.n_params, 6)):
            v = c.values.copy()
            v[k] += h
            fd = (c.evaluate(v, d0, cov) - c.evaluate(c.values, d0, cov)) / h
            np.testing.assert_allclose(J[..., k], fd, atol=1e-6, err_msg=c.label)
        fd0 = (c.evaluate(c.values, d0 + 1e-5, cov) - c.evaluate(c.values, d0, cov)) / 1e-5
        np.testing.assert_allclose(c.d_dd0(c.values, d0, cov), fd0, atol=1e-6, err_msg=c.label)


def test_components_act_only_on_their_sensors():
    ds, cov = small_case()
    for c in all_components(ds, cov):
        f = c.evaluate(c.values, ds.export.d, cov)
        if c.sensors and not isinstance(c, Outliers):
            others = [i for i in range(4) if i not in c.sensors]
            assert np.all(f[:, others] == 0), c.label
            assert np.any(f[:, list(c.sensors)] != 0), c.label


def test_components_evaluate_the_same_on_a_subset_of_poses():
    """A held-out fold is a subset of poses: a term must not depend on which poses are given
    (a drift referenced to the subset's first pose would shift every held-out prediction)."""
    ds, cov = small_case()
    d0 = ds.export.d
    idx = np.arange(3, cov.n_poses, 4)
    for c in all_components(ds, cov):
        if c.per_pose or isinstance(c, Outliers):
            continue
        np.testing.assert_allclose(c.evaluate(c.values, d0[idx], cov.select(idx)), c.evaluate(c.values, d0, cov)[idx],
                                   atol=1e-12, err_msg=c.label)


def test_name_clash_raises():
    nominal, _ = typical_layouts()
    with pytest.raises(ValueError, match="clash"):
        ExtendedModel(nominal, [Scale((1,), names=nominal.names), Scale((1,), names=nominal.names)])
    ExtendedModel(nominal, [Scale((1,), names=nominal.names), Scale((2,), names=nominal.names)])


def test_drift_without_temperature_raises():
    ds, cov = small_case()
    cov2 = Covariates(cov.time_h, np.full(cov.n_poses, np.nan), cov.cos_inc, cov.inv_nu, cov.spot_st, cov.range_mm)
    with pytest.raises(ValueError, match="no temp"):
        Drift((0,), [1.0], variable="temp").evaluate([1.0], ds.export.d, cov2)


def test_lagged_temperature_is_the_first_order_lag_of_a_ramp():
    """Analytic truth: a ramp ``T = r t`` through ``tau dy/dt = T - y``, ``y(0) = 0``, is
    ``r (t - tau (1 - exp(-t / tau)))``, whatever the sampling."""
    from metrology.core.effects.base import lagged_temperature

    t = np.sort(np.random.default_rng(3).uniform(0.0, 2.0, 40))
    t[0] = 0.0
    T = 0.7 * t
    y = lagged_temperature(t, T, fractions=(0.1, 0.3))
    for j, f in enumerate((0.1, 0.3)):
        tau = f * (t[-1] - t[0])  # the fractions are of the run's duration
        np.testing.assert_allclose(y[:, j], 0.7 * (t - tau * (1 - np.exp(-t / tau))), atol=1e-12)
    assert lagged_temperature(t, np.full(40, 20.0)) is None  # no temperature change: no lag member


def test_beyond_span_marks_only_readings_outside_their_training_folds():
    from metrology.diagnosis.heldout import beyond_span, folds

    d = np.random.default_rng(4).uniform(30.0, 70.0, (23, 3))
    m = beyond_span(d, 5)
    for test in folds(23, 5):
        train = np.setdiff1d(np.arange(23), test)
        lo, hi = d[train].min(axis=0), d[train].max(axis=0)
        np.testing.assert_array_equal(m[test], (d[test] < lo) | (d[test] > hi))
    assert m[np.argmax(d[:, 0]), 0] and m[np.argmin(d[:, 0]), 0]  # the extremes are always beyond


# ---------------------------------------------------------------------------------------
# the extended fit


# ---------------------------------------------------------------------------------------
# the registry: one entry per effect, read by every consumer


def test_every_registry_entry_is_complete_and_read_by_its_consumers():
    from metrology.core.effects import CATALOGUE, REGISTRY, Component
    from metrology.diagnosis import ADVICE, candidates_for, structure
    from metrology.sim.synth import SETUP_EFFECTS, SIZE_MEANING

    ds, cov = small_case()
    keys = set(structure(np.zeros(ds.obs.d.shape), ds.obs.d, cov, ds.layout.names)) | {"temp_c"}
    assert tuple(REGISTRY) == CATALOGUE
    for name, cls in REGISTRY.items():
        assert issubclass(cls, Component) and cls.name == name
        assert cls.advice and ADVICE[name] == cls.advice
        assert cls.size_meaning and SIZE_MEANING[name] == cls.size_meaning
        assert (name in SETUP_EFFECTS) == cls.setup
        assert set(cls.key_params) <= set(cls((), names=ds.layout.names).param_names or cls.key_params)
    flags = np.zeros(ds.obs.d.shape, bool)
    flags[3, 1] = True
    cands = candidates_for(ds.layout, cov, flags)
    assert {c.name for c in cands} == set(CATALOGUE)
    for c in cands:
        assert c.plot_key in keys, (c.label, c.plot_key)


def test_a_new_registry_entry_becomes_a_candidate(monkeypatch):
    """Adding an effect is one class and one entry: the diagnosis' candidates pick it up."""
    from dataclasses import dataclass

    from metrology.core import effects
    from metrology.diagnosis import candidates_for

    @dataclass(frozen=True)
    class Offset2(effects.Component):
        name = "offset2"
        param_names = ("c_mm",)
        param_units = ("mm",)
        advice = "none"

        @classmethod
        def candidates_for_sensor(cls, i, names, cov):
            return [cls((i,), names=names)]

        def basis(self, d0, cov):
            return np.zeros(d0.shape + (1,))

    monkeypatch.setitem(effects.REGISTRY, "offset2", Offset2)
    ds, cov = small_case()
    labels = [c.label for c in candidates_for(ds.layout, cov)]
    assert [lab for lab in labels if lab.startswith("offset2")] == [f"offset2.{n}" for n in ds.layout.names]
