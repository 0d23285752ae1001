"""The sensor characteristic on data of the independent forward simulator: its order chosen by
held-out error beyond the members every sensor is scored with
(``metrology.diagnosis.select.richer_spline``), and every held-out comparison of a curve made on
the readings inside its training span (the crosstalk check, the drop-one test).

The datum is passed as the plane fitted to the simulator's scan, without the scan itself (as
``--plane plane.json``): the scan's surface fit is most of a case's time and no part of these
tests.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from metrology.jobs.calibrate import load_checked
from metrology.sim.forward import draw_case, write_case


def _dataset(case, tmp_path):
    paths = write_case(case, tmp_path)
    ds = load_checked(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"], "wxyz", "mm", None,
                      lambda *a: None)
    return replace(ds, datum_points=None)


def test_calibration_table_is_named_nonlinearity(tmp_path):
    # a calibration table (a shape-preserving cubic through 7 knots) of 0.16 mm: the 4-knot
    # spline follows it only to about the reading noise, and its sensor's residuals then failed
    # the noise tests (`unexplained`, although the family was right)
    from metrology.diagnosis.decide import diagnose

    case = draw_case(np.random.default_rng([12]), "nonlinearity", size=0.16, n_poses=80, n_sensors=3,
                     noise_mm=0.005)
    eff = case.effects[0]
    assert eff.shape["shape"] == "table" and len(eff.shape["knots_mm"]) == 7  # the draw this test is about
    res = diagnose(_dataset(case, tmp_path), sim_reps=1).to_dict()
    assert res["cause"] == "nonlinearity", res["summary"]
    assert res["sensors"] == list(eff.sensors)
    # the member that follows the table has more knots than those every sensor is scored with
    assert res["causes"][0]["label"].startswith(f"nonlinearity.{eff.sensors[0]}@spline")


def test_crosstalk_check_judges_the_curve_inside_its_span(tmp_path):
    # a 0.08 mm tanh characteristic on L2 at 50 poses (the blind study's seed-40 draw 10): its
    # P5 member extrapolates at the ends of the span; compared there, crosstalk from L4 "could
    # not be told" from it and the sensor's own characteristic was not named
    from metrology.core.effects import Nonlinearity
    from metrology.diagnosis.candidates import score_candidate
    from metrology.diagnosis.crosstalk import crosstalk_check
    from metrology.diagnosis.decide import base_analysis

    case = draw_case(np.random.default_rng([40, 1, 2, 10]), "nonlinearity")
    assert case.family == "nonlinearity" and case.effects[0].shape["shape"] == "tanh"
    ds = _dataset(case, tmp_path)
    b = base_analysis(ds, 5)
    i = list(ds.layout.names).index(case.effects[0].sensors[0])
    c = Nonlinearity((i,), names=ds.layout.names, with_gain=True, order=5)
    none = np.zeros(ds.obs.d.shape, bool)
    s = score_candidate(c, ds.layout, ds.obs, b.cov, b.sigma, b.fit, b.heldout, none, 1.0, 5, b.theta0, 1)
    assert s.significant
    check = crosstalk_check(ds, b, (), s, 5)
    assert check["better"] is None and check["indistinguishable"] == [], check
