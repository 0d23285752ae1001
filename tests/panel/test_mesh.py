"""Tests of metrology.panel.mesh: loading panels, units, winding, the analytic surface header, the plane."""

from __future__ import annotations

import math

import numpy as np
import pytest

from metrology.core.normals import angle_between
from metrology.io.data import DATA_DIR
from metrology.core.model import direction_basis
from metrology.panel.mesh import load_panel, panel_plane, plane_axes
from metrology.panel.points import snap_points
from metrology.panel.rays import RayCaster
from metrology.panel.surfaces import ParametricSurface, panel_mesh, write_binary_stl


def test_panel_in_metres_warns(tmp_path):
    surf = ParametricSurface("flat")
    mesh = panel_mesh(surf, 0.2, 0.2, 0.05)
    path = tmp_path / "m.stl"
    write_binary_stl(mesh, path)
    assert any("in m or inch" in w for w in load_panel(path).warnings)


def test_inconsistent_winding_is_repaired(tmp_path):
    mesh = panel_mesh(ParametricSurface("flat"), 50, 50, 10)
    mesh.faces[::3] = mesh.faces[::3, ::-1]
    path = tmp_path / "w.stl"
    write_binary_stl(mesh, path)
    p = load_panel(path)
    assert p.mesh.is_winding_consistent
    assert any("repaired" in w for w in p.warnings)


@pytest.mark.parametrize("ext", ["stl", "obj", "ply", "glb"])
def test_load_panel_formats(tmp_path, ext):
    mesh = panel_mesh(ParametricSurface("sphere", 300.0), 40, 40, 4)
    path = tmp_path / f"p.{ext}"
    # glTF is in metres by specification (trimesh reads its units as such): written in m,
    # read back in mm; STL, OBJ and PLY carry no unit and are taken as mm
    mesh.copy().apply_scale(1e-3 if ext == "glb" else 1.0).export(path)
    p = load_panel(path)
    assert len(p.mesh.faces) == len(mesh.faces)
    assert np.allclose(np.sort(p.mesh.vertices, axis=0), np.sort(mesh.vertices, axis=0), atol=1e-5)


def test_generated_stl_carries_its_analytic_surface(tmp_path):
    surf = ParametricSurface("saddle", 800.0)
    path = tmp_path / "s.stl"
    write_binary_stl(panel_mesh(surf, 30, 30, 3), path, surf.tag)
    assert load_panel(path).surface == surf


def test_step_panel_loads_in_mm():
    pytest.importorskip("cascadio")
    p = load_panel(DATA_DIR / "panel_cyl800.step")
    assert np.allclose(p.mesh.bounds[:, :2], [[-100, -100], [100, 100]], atol=1e-3)
    surf = ParametricSurface("cylinder", 800.0)
    # within the 1 um chord tolerance of the tessellation
    assert np.max(np.abs(p.mesh.vertices[:, 2] - surf.height(p.mesh.vertices[:, 0], p.mesh.vertices[:, 1]))) < 1e-3
    c = RayCaster(p.mesh)
    pts, _, n, _, _ = snap_points(p, c, np.array([[0.0, 0.0, 0.0], [50.0, 20.0, -1.5]]))
    assert np.max(angle_between(n, surf.normal(pts), oriented=True)) < math.radians(0.01)


def test_panel_plane_of_a_tilted_flat_panel():
    """A flat panel turned by a known rotation: the plane's normal is the turned z axis, and
    its in-plane axes are those of core.model.direction_basis (to rounding)."""
    from scipy.spatial.transform import Rotation

    mesh = panel_mesh(ParametricSurface("flat"), 40, 30, 5)
    R = Rotation.from_euler("xyz", [0.3, -0.2, 0.1]).as_matrix()
    mesh.apply_transform(np.block([[R, np.array([[5.0], [-3.0], [2.0]])], [np.zeros((1, 3)), np.ones((1, 1))]]))
    centre, B = panel_plane(mesh)
    assert np.allclose(centre, [5.0, -3.0, 2.0], atol=1e-9)
    assert angle_between(B[2], R[:, 2], oriented=True) < 1e-9
    assert np.allclose(B @ B.T, np.eye(3), atol=1e-12)
    assert np.allclose(np.vstack(plane_axes(B[2])), direction_basis(B[2][None])[0], atol=1e-12)


def test_units_declared_assumed_and_overridden(tmp_path):
    """STEP declares its unit (trimesh's AP203 file is in inches, panel_cyl800.step in mm);
    an STL declares none (mm assumed); --units rescales; a unit tag in the name declares."""
    from pathlib import Path

    from metrology.panel.mesh import _step_unit

    real = Path(__file__).resolve().parents[1] / "data" / "meshes"
    assert _step_unit(real / "trimesh_base_interface_AP203.step") == "in"
    assert _step_unit(DATA_DIR / "panel_cyl800.step") == "mm"
    mesh = panel_mesh(ParametricSurface("flat"), 0.2, 0.2, 0.05)  # 0.4 m across, written in m
    path = tmp_path / "skin.stl"
    write_binary_stl(mesh, path)
    p = load_panel(path)
    assert p.units == "mm (assumed: a .stl file carries no units)" and any("as m: 565.7 mm" in w for w in p.warnings)
    q = load_panel(path, units="m")
    assert np.allclose(q.mesh.extents[:2], [400.0, 400.0]) and not q.warnings
    assert q.units == "m (--units; the file declares none)"
    tagged = tmp_path / "skin.unitsm.stl"
    write_binary_stl(mesh, tagged)
    assert np.allclose(load_panel(tagged).mesh.extents[:2], [400.0, 400.0])
    with pytest.raises(ValueError, match="units must be one of mm, cm, m, in, got 'ft'"):
        load_panel(path, units="ft")
