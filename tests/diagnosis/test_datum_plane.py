"""The datum's own uncertainty in the diagnosis' null (issue 40): a hand-probe scan's plane, off the
true datum within its stated uncertainty, is no cause; a plane off far beyond it is the datum's.

Data from the independent forward simulator (a null case, its datum given as a hand-probe scan:
:func:`metrology.sim.forward.surface.sample_hand_scan`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from metrology.calibration.datum_prior import plane_prior
from metrology.calibration.sanity import load_checked
from metrology.core.plane import Plane, plane_basis
from metrology.diagnosis import diagnose
from metrology.sim.forward import draw_case, write_case


@pytest.fixture(scope="module")
def hand_null(tmp_path_factory):
    """A null (nothing wrong) on 40 poses of a 3-sensor head whose datum is a hand-probe scan; on
    this seed the scan's plane alone made ``pose_error`` (confidence high) before issue 40."""
    case = draw_case(np.random.default_rng([40, 1]), "none", scan="hand", n_poses=40, n_sensors=3)
    paths = write_case(case, tmp_path_factory.mktemp("hand_null"))
    return load_checked(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"])


def _tilted(ds, k):
    """``ds`` with its plane tilted by ``k`` of the scan's stated 1-sigma tilts, about the scan's centroid."""
    s = float(np.sqrt(plane_prior(ds.plane.normal, ds.plane_cov)[0, 0]))
    n = ds.plane.normal + k * s * plane_basis(ds.plane.normal)[0]
    n = n / np.linalg.norm(n)
    return replace(ds, plane=Plane(n, -n @ ds.datum_points.mean(axis=0)))


def test_a_plane_within_its_uncertainty_is_no_cause(hand_null):
    assert hand_null.plane_cov is not None  # the cloud's robust fit keeps its covariance
    d = diagnose(hand_null, sim_reps=1).to_dict()
    assert d["cause"] == "none", d["summary"]
    assert d["datum_plane"]["covariance_given"] and not d["datum_plane"]["off"]
    # the same data with the plane taken as exact: the scan's tilt is read as the tracker's
    exact = diagnose(replace(hand_null, plane_cov=None), sim_reps=1).to_dict()
    assert exact["cause"] == "pose_error"
    assert exact["datum_plane"] == {"covariance_given": False, "note": exact["datum_plane"]["note"]}


def test_a_plane_off_beyond_its_uncertainty_is_the_datums(hand_null):
    d = diagnose(_tilted(hand_null, 8.0), sim_reps=1).to_dict()
    named = [c["cause"] for c in d["causes"]]
    assert d["cause"] == "datum_tilt" and "pose_error" not in named, d["summary"]
    assert d["datum_plane"]["off"] and d["datum_plane"]["p"] < 1e-3
    # the correction recovers the tilt put in (8 sigma about e1), within 2 of the scan's sigmas
    s = d["datum_plane"]["prior_stderr"]["tilt_urad"][0]
    assert abs(-d["datum_plane"]["correction"]["tilt_urad"][0] - 8.0 * s) < 2.5 * s
