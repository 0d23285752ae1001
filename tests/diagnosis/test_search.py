"""The open search beyond the catalogue (issue 54): effects no family describes, drawn from their
physics by :mod:`metrology.sim.forward.outside` (written before the search), are found on their
sensor, named by their variable from the vocabulary and fitted as an equation in units; the verdict
stays ``unexplained``. Data through the public file contract (``write_case`` -> ``diagnose_files``)."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.diagnosis import rules
from metrology.diagnosis.results import Confidence, Outcome
from metrology.diagnosis.vocabulary import VARIABLES, terms_for
from metrology.jobs.diagnose import diagnose_files
from metrology.report.diagnose import explain_text
from metrology.sim.forward import draw_case, draw_outside, write_case


def _diagnose(case, tmp_path):
    tmp_path.mkdir(parents=True, exist_ok=True)
    paths = write_case(case, tmp_path)
    return diagnose_files(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"])


@pytest.fixture(scope="module")
def backlash(tmp_path_factory):
    case = draw_outside(np.random.default_rng([54, 30]), "backlash", factor=3.0, n_poses=80)
    return case, _diagnose(case, tmp_path_factory.mktemp("backlash"))


def test_backlash_is_found_named_by_its_variable_and_measured(backlash):
    case, d = backlash
    eff = case.effects[0]
    assert d.cause == Outcome.UNEXPLAINED  # the family is unknown
    first = d.empirical.terms[0]
    assert first.sensor == eff.sensors[0] and first.variables == ("sign_delta_d",), d.summary
    assert first.p_heldout < rules.ALPHA_HELDOUT and first.p_insample < d.empirical.level
    # the coefficient is the drawn half-play, within 3 of its standard errors
    c = first.params["c"]
    assert abs(c.value - eff.shape["amplitude"]) < 3 * c.stderr
    assert "sign(delta_d)" in first.equation and first.equation.startswith(f"{eff.sensors[0]} reads ")
    assert first.equation in d.summary
    without, with_ = d.empirical.heldout_rms_mm  # the held-out gain in mm: the terms predict new poses
    assert with_ < without


def test_the_json_and_the_trail_carry_it(backlash):
    _, d = backlash
    D = d.to_dict()
    emp = D["empirical"]
    assert set(emp["variables"]) <= set(VARIABLES) and emp["terms"][0]["variables"] == ["sign_delta_d"]
    assert emp["terms_tried"] > 100 and emp["level_insample"] == pytest.approx(rules.ALPHA_CANDIDATES / emp["terms_tried"])
    taken = [r for r in D["reasons"] if r["rule"] == 20 and r["decided"] == "empirical term"]
    assert taken and taken[0]["concerns"][0].endswith("sign_delta_d")
    assert "rule 20 search_held_out" in explain_text(d)


def test_a_fringe_error_is_a_period_of_the_reading(tmp_path):
    case = draw_outside(np.random.default_rng([54, 31]), "fringe", factor=3.5, n_poses=100)
    eff = case.effects[0]
    d = _diagnose(case, tmp_path)
    first = d.empirical.terms[0]
    assert first.sensor == eff.sensors[0] and first.variables == ("d",), d.summary
    assert abs(first.params["period"].value - eff.shape["period_mm"]) < 0.1 * eff.shape["period_mm"]
    A = first.params["amplitude"]
    assert abs(A.value - abs(eff.shape["amplitude"])) < 3 * A.stderr + 0.1 * abs(eff.shape["amplitude"])


def test_a_null_is_not_searched(tmp_path):
    case = draw_case(np.random.default_rng([54, 32]), "none", n_poses=60)
    d = _diagnose(case, tmp_path)
    assert d.cause == Outcome.NONE and d.empirical is None and d.to_dict()["empirical"] is None


def test_the_search_runs_only_where_the_catalogue_does_not_explain():
    assert rules.search_tried(Outcome.UNEXPLAINED, Confidence.LOW)
    assert rules.search_tried("drift", Confidence.PARTIAL)
    assert not rules.search_tried("drift", Confidence.HIGH) and not rules.search_tried(Outcome.NONE, Confidence.MODERATE)
    assert rules.search_in_sample(0.009 / 1000, 1000) and not rules.search_in_sample(0.011 / 1000, 1000)


def test_every_term_names_variables_of_the_vocabulary():
    from metrology.calibration.sanity import load_checked
    from metrology.diagnosis.decide import base_analysis

    import tempfile

    case = draw_case(np.random.default_rng([54, 33]), "none", n_poses=40, n_sensors=3)
    with tempfile.TemporaryDirectory() as tmp:
        paths = write_case(case, tmp)
        ds = load_checked(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"])
    b = base_analysis(ds, 5)
    terms = terms_for(ds.export, b.cov, b.d0, 0, ds.layout.names, np.isfinite(ds.obs.d[:, 0]))
    assert len({t.key for t in terms}) == len(terms) > 100
    assert all(set(t.variables) <= set(VARIABLES) and t.columns.shape[0] == 40 for t in terms)
    kinds = {t.kind for t in terms}
    assert kinds == {"line", "periodic", "shape"}


def test_a_partial_residual_figure_per_term(backlash, tmp_path):
    from metrology.report.diagnose import plot_report

    _, d = backlash
    files = plot_report(d, tmp_path)
    assert any(f.endswith("residuals_empirical.png") for f in files)
    t = d.empirical.terms[0]
    # the partial residual against sign(delta_d): its two groups' means differ by twice the coefficient
    x, y = t.plot["x"], t.plot["partial"]
    step = float(np.mean(y[x > 0]) - np.mean(y[x < 0]))
    assert abs(step - 2 * t.params["c"].value) < 4 * t.params["c"].stderr
