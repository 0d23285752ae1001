"""The mesh's reference normal at sharp edges (issue 14, item 2): the face hit, smoothed
only within the crease angle; checked against exact normals computed here."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from metrology.core.normals import angle_between
from metrology.core.paper import table6_layouts
from metrology.panel.mesh import CREASE_ANGLE_DEG, Panel
from metrology.panel.points import DrillPoints
from metrology.panel.run import run_normals
from metrology.panel.surfaces import ParametricSurface, panel_mesh


def _samples(mesh, k, seed):
    pts, fi = trimesh.sample.sample_surface(mesh, k, seed=seed)
    bary = trimesh.triangles.points_to_barycentric(mesh.triangles[fi], pts)
    return pts, fi, bary


@pytest.mark.parametrize("sections", [6, 8, 10, 16, 32])
def test_faceted_cylinder_sides_within_the_faceting_angle(sections):
    mesh = trimesh.creation.cylinder(radius=1000.0, height=600.0, sections=sections)
    panel = Panel(mesh)
    pts, fi, bary = _samples(mesh, 3000, sections)
    side = np.abs(mesh.face_normals[fi][:, 2]) < 1e-9
    exact = pts[side] * [1.0, 1.0, 0.0]
    n, faceting, chord = panel.reference_normal_at(fi[side], bary[side])
    err = np.degrees(angle_between(n, exact, oriented=True))
    facet = 360.0 / sections
    assert err.max() < facet
    # the old reference, vertex normals averaged with the caps across the 90 deg rim, is worse
    old = np.degrees(angle_between(panel.vertex_normal_at(fi[side], bary[side]), exact, oriented=True))
    assert old.mean() > err.mean() + 1.0
    if facet < CREASE_ANGLE_DEG:  # smoothed: the stated uncertainty is the facet's half angle
        assert np.allclose(np.degrees(faceting), facet / 2, rtol=1e-6)
        assert np.all(chord > 0)
    else:  # every side edge is a crease: the face's own normal, no stated faceting
        assert np.all(faceting < 1e-12)
        assert np.max(angle_between(n, mesh.face_normals[fi[side]], oriented=True)) < 1e-12


def test_box_reference_is_the_face_normal():
    mesh = trimesh.creation.box(extents=(120.0, 80.0, 40.0))
    pts, fi, bary = _samples(mesh, 2000, 1)
    n, faceting, chord = Panel(mesh).reference_normal_at(fi, bary)
    assert np.max(angle_between(n, mesh.face_normals[fi], oriented=True)) < 1e-12
    assert np.all(faceting < 1e-12) and np.all(chord < 1e-9)


@pytest.mark.parametrize("kind, R", [("sphere", 500.0), ("cylinder", 300.0), ("saddle", 400.0)])
def test_smooth_mesh_reference_within_its_stated_uncertainty(kind, R):
    """Fine mesh of an analytic surface, read without the analytic: the reference error
    is within the uncertainty the reference states."""
    surf = ParametricSurface(kind, R)
    mesh = panel_mesh(surf, 100.0, 100.0, 5.0)
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces)  # forget the analytic vertex normals
    pts, fi, bary = _samples(mesh, 2000, 3)
    inner = np.all(np.abs(pts[:, :2]) < 90.0, axis=1)
    n, faceting, chord = Panel(mesh).reference_normal_at(fi[inner], bary[inner])
    err = angle_between(n, surf.normal(pts[inner]), oriented=True)
    assert np.all(err <= faceting + 1e-9)
    # and the stated uncertainty is of the order of the faceting, not a blanket
    assert np.median(faceting) < math.radians(1.0)
    assert np.max(chord) < 5.0**2 * 2 / (8 * R) * 4


def test_run_on_a_faceted_cylinder_reports_its_reference():
    mesh = trimesh.creation.cylinder(radius=1000.0, height=600.0, sections=16)
    # drilling points on the sides, approached along the inward radial direction
    pts, fi, _ = _samples(mesh, 400, 2)
    pts = pts[(np.abs(mesh.face_normals[fi][:, 2]) < 1e-9) & (np.abs(pts[:, 2]) < 150) & (pts[:, 0] > 700)][:12]
    drill = DrillPoints(pts, np.full_like(pts, np.nan), tuple(map(str, range(len(pts)))))
    rng = np.random.default_rng(0)
    run = run_normals(Panel(mesh), table6_layouts()[1], drill, rng, tilt=math.radians(1), noise=0.0, loop=False)
    assert "smoothed within 30 deg" in run.info["reference_normal"]
    fac = run.info["reference_faceting"]
    assert np.sum(run.status == "ok") >= 6
    assert fac["used"] and fac["angle_max_deg"] == pytest.approx(360 / 16 / 2)
    exact = run.points * [1.0, 1.0, 0.0]
    assert np.max(np.degrees(angle_between(run.n_ref, exact, oriented=True))) < 360 / 16
    # on a 16-gon the design is not known: the micro-plane sees the facet it stands on, the
    # reference is the smoothed cylinder; their difference is within the stated faceting
    ok = run.status == "ok"
    assert np.nanmax(np.degrees(run.err_plane[ok])) < 360 / 16
