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


def test_hole_surfaces_on_a_step_come_from_its_brep_and_a_hole_off_its_faces_is_an_error():
    """panel_surfaces with a B-rep (panel_cyl800.step, convex R 800, axis y): each hole's shape
    operator is the exact cylinder's, ``c c^T / 800`` (the mesh path's sign: positive where the surface
    bends away from the head) and its source names the B-rep; a hole on the mesh but off every face of
    the B-rep (the mesh here reaches 120 mm, the STEP 100 mm) is the one-line error naming its row."""
    from metrology.measure.panel import HoleTable
    from metrology.panel.brep import BRepSurface
    from metrology.panel.holes import panel_surfaces
    from metrology.panel.mesh import Panel
    from metrology.sim.forward.panels import make_panel
    from tests.measure.panel_fixtures import panel_mesh

    cad = make_panel("cylinder", 800.0)
    panel = Panel(panel_mesh(cad, half_mm=120.0, step_mm=3.0), "cyl.stl", surface=BRepSurface(DATA_DIR / "panel_cyl800.step"))
    xy = np.random.default_rng(6).uniform(-30.0, 30.0, (20, 2))
    P = np.column_stack([xy, cad.height(xy[:, 0], xy[:, 1])])
    f = panel_surfaces(panel, HoleTable(tuple(map(str, range(20))), P, -cad.normal_at(P), "holes.csv"), 20.0)
    assert "B-rep (exact STEP faces)" in f["source"]
    c = np.cross(f["normal"], [0.0, 1.0, 0.0])
    c /= np.linalg.norm(c, axis=1, keepdims=True)
    np.testing.assert_allclose(f["shape"], np.einsum("mi,mj->mij", c, c) / 800.0, atol=1e-9)
    np.testing.assert_allclose(f["k"], np.tile([1 / 800.0, 0.0], (20, 1)), atol=1e-9)
    assert np.degrees(np.max(angle_between(f["normal"], cad.normal_at(P), oriented=True))) < 1e-6
    P[3] = [110.0, 0.0, float(cad.height(110.0, 0.0))]
    with pytest.raises(ValueError, match=r"holes.csv: line 5: hole 3 at .* is on no face of the panel cyl.stl's B-rep"):
        panel_surfaces(panel, HoleTable(tuple(map(str, range(20))), P, -cad.normal_at(P), "holes.csv"), 20.0)


def _step_cylinder(path, R, axis):
    """An exact cylinder of radius ``R`` as the forward simulator's (axis through ``(0, 0, -R)`` along ``axis``,
    400 mm long), written as a STEP B-rep by OpenCASCADE."""
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeCylinder
    from OCP.gp import gp_Ax2, gp_Dir, gp_Pnt
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer

    a = np.asarray(axis, float)
    shape = BRepPrimAPI_MakeCylinder(gp_Ax2(gp_Pnt(*(-200.0 * a + [0.0, 0.0, -R])), gp_Dir(*a)), R, 400.0).Shape()
    w = STEPControl_Writer()
    w.Transfer(shape, STEPControl_AsIs)
    w.Write(str(path))
    return path


def test_a_tight_radius_on_a_step_takes_its_brep_beyond_second_order(tmp_path):
    """A STEP cylinder R 50 under a 25 mm footprint (issue 53): the local surface's heights over the footprint (the
    B-rep's second fundamental form, then the quartic and degrees 5-8 fitted to the faces' own points over the disc)
    are the forward simulator's cylinder's to 1 um (the quartic's term alone is 0.39 mm at 25 mm), and the height no
    term carries is stated (``u_height``, under 1 um). Before, the B-rep path kept the ray-cast cubic: no quartic, no
    remainder (0.39 mm off, ``u_height`` 0)."""
    from metrology.measure.panel import HoleTable
    from metrology.panel.brep import BRepSurface
    from metrology.panel.footprint import extra_exponents
    from metrology.panel.holes import panel_surfaces
    from metrology.panel.mesh import Panel
    from metrology.sim.forward.panels import make_panel
    from tests.measure.panel_fixtures import panel_mesh

    R = 50.0
    cad = make_panel("cylinder", R, axis=(1.0, 0.0, 0.0))
    step = _step_cylinder(tmp_path / "cyl50.step", R, (1.0, 0.0, 0.0))
    panel = Panel(panel_mesh(cad, half_mm=120.0, step_mm=2.0), "cyl50.stl", surface=BRepSurface(step))
    rng = np.random.default_rng(53)
    xy = np.column_stack([rng.uniform(-40.0, 40.0, 6), np.r_[0.0, 0.0, 0.0, rng.uniform(-8.0, 8.0, 3)]])  # 3 on a line
    P = np.column_stack([xy, cad.height(xy[:, 0], xy[:, 1])])
    f = panel_surfaces(panel, HoleTable(tuple(map(str, range(6))), P, -cad.normal_at(P), "holes.csv"), 25.0)
    assert f["higher"].shape == (6, 9 + len(extra_exponents()))
    assert np.all(f["u_height"] < 1e-3) and np.all(f["u_height"] > 0.0)
    n, E = f["normal"], f["frame"]  # toward the head; (m, 2, 3)
    exps = [(3, 0), (2, 1), (1, 2), (0, 3), (4, 0), (3, 1), (2, 2), (1, 3), (0, 4)] + extra_exponents()
    g = np.linspace(-25.0, 25.0, 21)
    s_, t_ = (a.ravel() for a in np.meshgrid(g, g))
    inside = np.hypot(s_, t_) <= 25.0
    s_, t_ = s_[inside], t_[inside]
    for i in range(6):
        Kt = np.einsum("ai,ij,bj->ab", E[i], f["shape"][i], E[i])  # the shape operator in (e1, e2)
        model = -0.5 * (Kt[0, 0] * s_ * s_ + 2 * Kt[0, 1] * s_ * t_ + Kt[1, 1] * t_ * t_)
        for c, (a, b) in zip(f["higher"][i], exps):
            model = model + c * s_ ** a * t_ ** b / (math.factorial(a) * math.factorial(b))
        origin = P[i] + s_[:, None] * E[i, 0] + t_[:, None] * E[i, 1] + 100.0 * n[i]
        true = 100.0 - cad.intersect(origin, np.broadcast_to(-n[i], origin.shape))  # the simulator's height along n
        assert np.max(np.abs(model - true)) < 1e-3, (i, np.max(np.abs(model - true)))


def test_a_step_footprint_past_the_crest_is_named_so(tmp_path):
    """R 20 under a 25 mm footprint (its disc 31 mm): the hole's problem names the crest, with the B-rep's own radius
    (before, the ray-cast curvature of the missing samples, 0: "runs off the panel's edge", the wrong cause)."""
    from metrology.measure.panel import HoleTable
    from metrology.panel.brep import BRepSurface
    from metrology.panel.holes import panel_surfaces
    from metrology.panel.mesh import Panel
    from metrology.sim.forward.panels import make_panel
    from tests.measure.panel_fixtures import panel_mesh

    cad = make_panel("cylinder", 20.0, axis=(1.0, 0.0, 0.0))
    panel = Panel(panel_mesh(cad, half_mm=120.0, step_mm=2.0), "cyl20.stl",
                  surface=BRepSurface(_step_cylinder(tmp_path / "cyl20.step", 20.0, (1.0, 0.0, 0.0))))
    P = np.array([[0.0, 0.0, 0.0], [30.0, 0.0, 0.0]])
    f = panel_surfaces(panel, HoleTable(("a", "b"), P, -cad.normal_at(P), "holes.csv"), 25.0)
    assert all("past the crest of the surface's radius 20 mm" in p for p in f["problem"]), list(f["problem"])
