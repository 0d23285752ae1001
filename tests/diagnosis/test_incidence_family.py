"""The incidence family (issue 12): ``c tan^2(gamma)``, and ``incidence@4`` (``c2 tan^2 + c4 tan^4``)
only when an even curve steepens more than ``tan^2`` does, chosen by held-out error.

The readings come from the independent forward simulator (:mod:`metrology.sim.forward`: beams
cast at a datum, the bias a function of the true incidence angle), never from the component.
"""

from __future__ import annotations

import numpy as np
import pytest

from metrology.calibration.dataset import Dataset
from metrology.core.frames import quaternion_from_matrix
from metrology.core.plane import fit_plane_tls
from metrology.diagnosis.decide import diagnose
from metrology.io.export import TrackerExport
from metrology.sim.forward import IncidenceBias, draw_head, draw_poses, draw_surface, sample_cloud


@pytest.fixture(scope="module")
def scene():
    """A 3-sensor ring head (beams inclined 15-35 deg), 80 poses tilted up to 20 deg, 3 um noise."""
    rng = np.random.default_rng([12, 4])
    head = draw_head(rng, 3, noise_mm=0.003)
    surface, _ = draw_surface(rng)
    cloud = sample_cloud(surface, rng, 2000)
    R, T, hits = draw_poses(rng, surface, head.true.zero, head.true.direction, 80, tilt_max_rad=np.radians(20.0),
                            range_mm=(30.0, 70.0), z0_mm=head.z0_mm)
    noise = rng.normal(scale=0.003, size=hits.d.shape)
    return head, cloud, R, T, hits, noise


def _named(scene, bias):
    head, cloud, R, T, hits, noise = scene
    d = hits.d + noise
    d[:, 0] += bias(hits.incidence[:, 0])
    nan = np.full(len(R), np.nan)
    export = TrackerExport(tuple(f"P{k + 1:03d}" for k in range(len(R))), nan, nan, quaternion_from_matrix(R), T,
                           head.nominal.names, d)
    res = diagnose(Dataset(export, head.nominal, fit_plane_tls(cloud)[0], cloud)).to_dict()
    return [(c["label"], c["cause"], tuple(c["sensors"])) for c in res["causes"]], res["summary"]


def test_a_steep_even_curve_takes_the_tan4_member_and_a_tan2_curve_does_not(scene):
    amax = float(np.nanmax(scene[4].incidence[:, 0]))
    steep = IncidenceBias("even_poly", {"coeffs_mm": [0.0, 0.0, 0.08 / amax**6]})  # 0.08 mm at the largest angle
    causes, summary = _named(scene, steep)
    assert [c[1:] for c in causes] == [("incidence", ("L1",))] and causes[0][0] == "incidence.L1@4", summary
    c = 0.08 / np.tan(amax) ** 2
    causes, summary = _named(scene, lambda a: c * np.tan(a) ** 2)
    assert [c[1:] for c in causes] == [("incidence", ("L1",))] and causes[0][0] == "incidence.L1", summary
