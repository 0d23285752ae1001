"""Tests of metrology.panel.brep: the exact B-rep reference of a STEP panel (skipped without OCP)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from metrology.core.normals import angle_between
from metrology.io.data import DATA_DIR
from metrology.panel.points import DrillPoints
from metrology.panel.run import run_normals
from metrology.panel.surfaces import ParametricSurface

from .helpers import LAYOUTS

pytest.importorskip("OCP")
pytest.importorskip("cascadio")


def test_brep_normal_is_the_exact_cylinder_normal():
    """panel_cyl800.step is an exact cylinder of radius 800 mm: the B-rep's normal at points
    on it is the analytic one to 1e-6 deg (no tessellation enters)."""
    from metrology.panel.brep import BRepSurface
    from metrology.panel.mesh import load_panel

    panel = load_panel(DATA_DIR / "panel_cyl800.step")
    assert isinstance(panel.surface, BRepSurface)
    surf = ParametricSurface("cylinder", 800.0)
    rng = np.random.default_rng(4)
    xy = rng.uniform(-99.0, 99.0, (200, 2))
    pts = np.column_stack([xy, surf.height(xy[:, 0], xy[:, 1])])
    n = panel.surface.normal(pts)
    n *= np.sign(np.sum(n * surf.normal(pts), axis=1))[:, None]
    assert np.degrees(np.max(angle_between(n, surf.normal(pts), oriented=True))) < 1e-6


def test_brep_second_fundamental_form_is_the_exact_cylinders():
    """On panel_cyl800.step (convex, axis along y, R 800 mm) the face's second fundamental form
    along the outward normal is ``-c c^T / R`` (``c`` the circumferential direction): the surface
    bends away from the outside by 1/R across the axis and not at all along it."""
    from metrology.panel.brep import BRepSurface

    brep = BRepSurface(DATA_DIR / "panel_cyl800.step")
    surf = ParametricSurface("cylinder", 800.0)
    xy = np.random.default_rng(5).uniform(-99.0, 99.0, (50, 2))
    pts = np.column_stack([xy, surf.height(xy[:, 0], xy[:, 1])])
    n, hess = brep.local_surface(pts)
    s = np.sign(np.sum(n * surf.normal(pts), axis=1))
    n, hess = n * s[:, None], hess * s[:, None, None]
    c = np.cross(n, [0.0, 1.0, 0.0])
    c /= np.linalg.norm(c, axis=1, keepdims=True)
    np.testing.assert_allclose(hess, -np.einsum("mi,mj->mij", c, c) / 800.0, atol=1e-9)
    off, _ = brep.local_surface([[500.0, 0.0, 0.0]])
    assert np.isnan(off).all()  # a point off every face: no surface there


def test_run_on_a_step_panel_uses_the_brep_reference():
    from metrology.panel.mesh import load_panel

    panel = load_panel(DATA_DIR / "panel_cyl800.step")
    surf = ParametricSurface("cylinder", 800.0)
    rng = np.random.default_rng(1)
    xy = rng.uniform(-40.0, 40.0, (30, 2))
    pts = np.column_stack([xy, surf.height(xy[:, 0], xy[:, 1])])
    drill = DrillPoints(pts, np.full_like(pts, np.nan), tuple(map(str, range(30))))
    run = run_normals(panel, LAYOUTS["table2"], drill, rng, tilt=math.radians(2), noise=0.0, loop=False)
    assert run.info["reference_normal"].startswith("B-rep")
    ok = run.status == "ok"
    assert ok.sum() == 30
    # the reference is the exact cylinder normal, outward like the mesh (the drilling points
    # are snapped onto the 1 um tessellation, whose nearest B-rep point is ~2e-5 mm aside:
    # 1.4e-6 deg on R 800; the direct test above is at 1e-6 deg)
    assert np.degrees(np.max(angle_between(run.n_ref[ok], surf.normal(run.points[ok]), oriented=True))) < 1e-5
