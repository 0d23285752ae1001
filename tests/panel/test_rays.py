"""Tests of metrology.panel.rays: every engine behind RayCaster."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.panel.rays import RayCaster, available_engines

from .helpers import make_panel


def test_engines_agree_after_double_refinement():
    panel = make_panel("sphere", 300.0, half=60.0, spacing=2.0)
    rng = np.random.default_rng(5)
    o = np.column_stack([rng.uniform(-30, 30, (200, 2)), np.full(200, 100.0)])
    dirs = np.tile([0.0, 0.0, -1.0], (200, 1)) + rng.normal(0, 0.02, (200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    ts = {}
    for eng in available_engines():
        tri, t, _ = RayCaster(panel.mesh, eng).cast(o, dirs)
        assert np.all(tri >= 0)
        ts[eng] = t
    ref = ts["trimesh"]
    for eng, t in ts.items():
        assert np.max(np.abs(t - ref)) < 1e-9, eng


def test_unknown_engine_is_an_error():
    with pytest.raises(ValueError, match="engine must be"):
        RayCaster(make_panel("flat", half=10).mesh, "optix")


def test_closest_points_agree_between_engines():
    """The trimesh engine's closest points (its own r-tree, double precision) are Open3D's where the nearest
    triangle is not a tie: points off the centres of the faces."""
    panel = make_panel("sphere", 300.0, half=60.0, spacing=2.0)
    mesh = panel.mesh
    rng = np.random.default_rng(7)
    f = rng.choice(len(mesh.faces), 100, replace=False)
    pts = mesh.triangles_center[f] + mesh.face_normals[f] * rng.uniform(-0.5, 0.5, (100, 1))
    got = {eng: RayCaster(mesh, eng).closest(pts) for eng in available_engines()}
    tri, snapped = got["trimesh"]
    assert np.array_equal(tri, f)
    for eng, (t, s) in got.items():
        assert np.array_equal(t, tri), eng
        assert np.max(np.abs(s - snapped)) < 1e-9, eng
