"""Tests of metrology.panel.attitude: the attitude-adjustment loop (paper Eq. 22) under motion error."""

from __future__ import annotations

import math

import numpy as np
import pytest

from metrology.panel.attitude import MotionError
from metrology.panel.run import run_normals

from .helpers import LAYOUTS, drill, make_panel


@pytest.mark.parametrize("lname", sorted(LAYOUTS))
def test_attitude_loop_converges(lname):
    panel = make_panel("cylinder", 800.0)
    rng = np.random.default_rng(11)
    run = run_normals(panel, LAYOUTS[lname], drill(panel.surface, rng), rng, tilt=math.radians(5), noise=0.003,
                         tolerance=math.radians(0.5))
    lp = run.loop["plane"]
    assert np.all(lp["converged"])
    assert np.all(lp["iterations"] >= 1)  # 5 deg is out of tolerance: at least one adjustment
    assert np.all(lp["measured_dev"] < math.radians(0.5))
    assert np.all(lp["final_dev"] < math.radians(0.5))
    # Eq. 22 angles of the first adjustment are of the size of the initial tilt
    first = np.hypot(lp["theta"], lp["phi"])
    assert np.all(np.abs(first - run.initial_tilt) < math.radians(0.5))


def test_attitude_loop_without_motion_error_reaches_the_measured_normal():
    panel = make_panel("flat")
    rng = np.random.default_rng(4)
    run = run_normals(panel, LAYOUTS["table6"], drill(panel.surface, rng), rng, tilt=math.radians(4), noise=0.0,
                         tolerance=math.radians(0.01), motion=MotionError(0.0, 0.0, 0.0))
    for m in ("plane", "sphere"):
        assert np.all(run.loop[m]["iterations"] == 1)
        assert np.max(run.loop[m]["final_dev"]) < 1e-8
