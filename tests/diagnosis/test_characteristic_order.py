"""The sensor characteristic's order is chosen by held-out error beyond the members every sensor
is scored with (``metrology.diagnosis.select.richer_spline``), on data of the independent
forward simulator.

A calibration table (a shape-preserving cubic through 7 knots over the range) of 0.16 mm is a
curve with several turns: the 4-knot spline follows it only to about the reading noise, its
sensor's residuals then fail the noise tests, and before the richer splines the diagnosis said
``unexplained`` although the family was right.
"""

from __future__ import annotations

import numpy as np

from metrology.jobs.diagnose import diagnose_files
from metrology.sim.forward import draw_case, write_case


def test_calibration_table_is_named_nonlinearity(tmp_path):
    case = draw_case(np.random.default_rng([12]), "nonlinearity", size=0.16, n_poses=80, n_sensors=3,
                     noise_mm=0.005)
    eff = case.effects[0]
    assert eff.shape["shape"] == "table" and len(eff.shape["knots_mm"]) == 7  # the draw this test is about
    paths = write_case(case, tmp_path)
    res = diagnose_files(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"]).to_dict()
    assert res["cause"] == "nonlinearity", res["summary"]
    assert res["sensors"] == list(eff.sensors)
    # the member that follows the table has more knots than the ones every sensor is scored with
    assert res["causes"][0]["label"].startswith(f"nonlinearity.{eff.sensors[0]}@spline")
