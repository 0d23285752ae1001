"""Tests of metrology.panel.surfaces: the analytic test surfaces."""

from __future__ import annotations

import math

import numpy as np

from metrology.core.normals import angle_between
from metrology.panel.surfaces import ParametricSurface


def test_analytic_normals_against_the_height_field():
    rng = np.random.default_rng(0)
    for kind, R in (("cylinder", 300.0), ("sphere", 800.0), ("saddle", 500.0), ("flat", math.inf)):
        s = ParametricSurface(kind, R)
        xy = rng.uniform(-100, 100, (50, 2))
        h = 1e-5
        gx = (s.height(xy[:, 0] + h, xy[:, 1]) - s.height(xy[:, 0] - h, xy[:, 1])) / (2 * h)
        gy = (s.height(xy[:, 0], xy[:, 1] + h) - s.height(xy[:, 0], xy[:, 1] - h)) / (2 * h)
        g = np.column_stack([-gx, -gy, np.ones(len(xy))])
        g /= np.linalg.norm(g, axis=1, keepdims=True)
        pts = np.column_stack([xy, s.height(xy[:, 0], xy[:, 1])])
        assert np.max(angle_between(s.normal(pts), g, oriented=True)) < 1e-8
