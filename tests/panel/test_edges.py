"""Tests of metrology.panel.edges: points whose head straddles a crease, a hole or the outline
are refused with the reason; grids keep the footprint on one smooth region (box, closed wing,
and trimesh's real plate with holes)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from metrology.core.normals import angle_between
from metrology.panel.edges import BOUNDARY, CREASE, HOLE, footprint_radius, panel_edges
from metrology.panel.mesh import Panel, load_panel
from metrology.panel.points import DrillPoints, grid_points
from metrology.panel.rays import RayCaster
from metrology.panel.run import run_normals

from .helpers import LAYOUTS

DATA = Path(__file__).resolve().parents[1] / "data" / "meshes"


def _box(extents=(200.0, 200.0, 100.0)):
    import trimesh

    return Panel(trimesh.creation.box(extents=extents), "box", [])


def _wing(chord=400.0, span=600.0, thickness=0.12, n=120):
    """A closed, straight wing: NACA 00xx section (sharp trailing edge) extruded along y,
    closed by flat end caps; x along the chord (leading edge at 0), z up."""
    import trimesh

    beta = np.linspace(0.0, math.pi, n)
    x = 0.5 * (1 - np.cos(beta))  # cosine spacing: fine at both edges
    yt = 5 * thickness * (0.2969 * np.sqrt(x) - 0.1260 * x - 0.3516 * x**2 + 0.2843 * x**3 - 0.1036 * x**4)
    yt[-1] = 0.0  # sharp trailing edge
    # the section's outline, counter-clockwise seen from +y: upper surface TE -> LE, lower LE -> TE
    px = np.r_[x[::-1], x[1:-1]] * chord
    pz = np.r_[yt[::-1], -yt[1:-1]] * chord
    k = len(px)
    ys = np.linspace(0.0, span, 31)
    V = np.array([[a, y, b] for y in ys for a, b in zip(px, pz)])
    F = []
    for j in range(len(ys) - 1):
        for i in range(k):
            a, b = j * k + i, j * k + (i + 1) % k
            F += [[a, b, b + k], [a, b + k, a + k]]
    c0 = len(V)
    V = np.vstack([V, [chord * 0.3, 0.0, 0.0], [chord * 0.3, span, 0.0]])
    top = (len(ys) - 1) * k
    for i in range(k):
        F += [[c0, (i + 1) % k, i], [c0 + 1, top + i, top + (i + 1) % k]]
    mesh = trimesh.Trimesh(V, np.array(F), process=True)
    trimesh.repair.fix_normals(mesh)
    return Panel(mesh, "wing", [])


def test_edges_of_a_box_and_a_wing():
    e = panel_edges(_box().mesh, 30.0)
    assert set(e.kind.tolist()) == {CREASE}  # closed: no outline, no hole
    assert np.allclose(np.degrees(e.angle), 90.0)
    w = _wing()
    ew = panel_edges(w.mesh, 30.0)
    assert set(ew.kind.tolist()) == {CREASE}
    # the creases are the trailing edge and the caps' outlines; the smooth leading edge is not one
    te = ew.segments[..., 0].min(axis=1) > 399.0
    inner = np.all((ew.segments[..., 1] > 1.0) & (ew.segments[..., 1] < 599.0), axis=1)
    assert np.any(te & inner) and np.all(np.degrees(ew.angle[te & inner]) > 150.0)
    assert np.all(te[inner])


def test_point_near_a_box_edge_is_refused_with_the_spot_and_the_crease():
    panel = _box()
    pts = np.array([[0.0, 0.0, 50.0], [92.0, 0.0, 50.0], [60.0, 0.0, 50.0]])
    drill = DrillPoints(pts, np.full_like(pts, np.nan), ("centre", "edge", "near"))
    run = run_normals(panel, LAYOUTS["table6"], drill, np.random.default_rng(0), tilt=0.0, noise=0.0, loop=False)
    assert run.status[0] == "ok" and run.err_plane[0] < 1e-9
    # 8 mm from the edge: Table 6's +x spots (L2, L3, at x + 22 mm) land on the side face
    assert run.status[1] == "spot_crease"
    assert run.detail[1].startswith("spot of L2, L3 on the other side of a 90 deg crease")
    # 40 mm from the edge: outside the spots' footprint (31.4 mm), measured; with a pressure
    # foot of 45 mm the edge is under the foot: refused
    assert 30.0 < run.info["footprint_mm"] < 35.0 and run.status[2] == "ok"
    big = run_normals(panel, LAYOUTS["table6"], drill, np.random.default_rng(0), tilt=0.0, noise=0.0, loop=False,
                      footprint_mm=45.0)
    assert big.status[2] == "footprint_crease" and big.detail[2] == "footprint crosses a 90 deg crease"


def test_grid_on_a_closed_wing_keeps_the_footprint_off_the_trailing_edge():
    panel = _wing()
    caster = RayCaster(panel.mesh, "auto")
    layout = LAYOUTS["table6"]
    foot = footprint_radius(layout, 35.0)
    drill, dropped = grid_points(panel, 20.0, caster, footprint_mm=foot, with_dropped=True)
    assert dropped > 0
    e = panel.edges()
    assert len(e.near(drill.points, foot)[0]) == 0
    run = run_normals(panel, layout, drill, np.random.default_rng(2), tilt=math.radians(2), noise=0.0,
                      standoff=35.0, caster=caster)
    ok = run.status == "ok"
    assert ok.sum() > 0.5 * len(ok)
    assert not np.any(np.isin(run.status, ["spot_crease", "footprint_crease"]))
    # on the leading edge (nose radius ~6 mm) the spots land where the surface has turned far
    # past the crease angle: no crease there, but no surface the head can measure either
    le = run.points[:, 0] < 1.0
    assert np.any(le) and np.all(run.status[le] == "spot_bend") and "turned" in run.detail[le][0]
    # no attitude loop is lost, and the final deviations are those of a smooth surface
    assert not np.any(run.loop["plane"]["lost"][ok])
    assert np.degrees(np.nanmax(run.loop["plane"]["final_dev"][ok])) < 2.0


def test_real_plate_with_holes():
    """trimesh's plate_holes.STL (8 x 12 in plate in mm, with holes): the refusals name the
    hole or the outline, and a grid leaves out every node whose footprint reaches one."""
    panel = load_panel(DATA / "trimesh_plate_holes.stl")
    e = panel.edges()
    assert set(np.unique(e.kind)) == {CREASE}  # a closed solid: its holes are bores, walls at 90 deg
    # as a panel (the top skin only): the bores become holes, the outline its boundary
    m = panel.mesh
    top = m.face_normals[:, 2] > 0.99
    z = m.triangles_center[:, 2]
    sub = m.submesh([np.flatnonzero(top & (z > z.max() - 1e-6))], append=True)
    skin = Panel(sub, "plate top", [])
    es = skin.edges()
    assert set(np.unique(es.kind)) == {BOUNDARY, HOLE}
    caster = RayCaster(skin.mesh, "auto")
    foot = footprint_radius(LAYOUTS["table6"], 35.0)
    drill, dropped = grid_points(skin, 10.0, caster, footprint_mm=foot, with_dropped=True)
    assert dropped > 0 and len(drill.points) > 0
    run = run_normals(skin, LAYOUTS["table6"], drill, np.random.default_rng(0), tilt=math.radians(1), noise=0.0,
                      standoff=35.0, caster=caster, loop=False)
    assert np.all(run.status == "ok")
    assert np.degrees(np.max(run.err_plane)) < 1e-6  # flat: exact
    # a point next to a hole: refused, naming the hole
    hole_pts = es.segments[es.kind == HOLE][:, 0]
    c = hole_pts.mean(axis=0)  # inside the loops' hull
    near_hole = hole_pts[np.argmin(np.linalg.norm(hole_pts - c, axis=1))]
    p = near_hole + np.array([0.0, 0.0, 0.0])
    # move 3 mm from the hole's edge onto the plate, away from the hole's own centre
    loop_pts = hole_pts[np.linalg.norm(hole_pts - near_hole, axis=1) < 60.0]
    away = p[:2] - loop_pts[:, :2].mean(axis=0)
    p[:2] += 3.0 * away / np.linalg.norm(away)
    d = DrillPoints(p[None], np.full((1, 3), np.nan), ("by the hole",))
    r = run_normals(skin, LAYOUTS["table6"], d, np.random.default_rng(0), tilt=0.0, noise=0.0, standoff=35.0,
                    caster=caster, loop=False)
    assert r.status[0] == "footprint_hole" and r.detail[0].startswith("footprint crosses a hole")


@pytest.mark.parametrize("bad", [-1.0, math.inf])
def test_bad_footprint_is_refused(bad):
    panel = _box()
    pts = np.array([[0.0, 0.0, 50.0]])
    with pytest.raises(ValueError, match="footprint radius must be"):
        run_normals(panel, LAYOUTS["table6"], DrillPoints(pts, np.full_like(pts, np.nan), ("a",)),
                    np.random.default_rng(0), footprint_mm=bad, loop=False)


def test_plate_reference_is_the_plane_next_to_its_fillets():
    """On plate_holes.STL the flat faces' long triangles reach the outline's tangent fillets:
    their reference is the plane's normal everywhere on them, not leaning to the fillet."""
    panel = load_panel(DATA / "trimesh_plate_holes.stl")
    m = panel.mesh
    flat = np.flatnonzero(np.abs(m.face_normals[:, 2]) > 1 - 1e-12)
    rng = np.random.default_rng(0)
    bary = rng.dirichlet(np.ones(3), len(flat))
    n, fac, chord = panel.reference_normal_at(flat, bary)
    assert np.max(angle_between(n, m.face_normals[flat], oriented=True)) < 1e-9
    # and it says so: no faceting uncertainty from the fillet facets it does not use (was 3.78 deg)
    assert np.all(fac == 0) and np.all(chord == 0)
    # while the fillets are smoothed: their reference is not their facets' own normals
    fil = np.flatnonzero((np.abs(m.face_normals[:, 2]) > 0.05) & (np.abs(m.face_normals[:, 2]) < 0.95))
    nf, fac, _ = panel.reference_normal_at(fil, np.full((len(fil), 3), 1 / 3))
    assert np.all(fac > 0)


def test_near_finds_exactly_the_edges_within_the_radius_long_segments_included():
    """plate_holes.STL: outline segments up to 178 mm beside bores of 1.7 mm edges. The
    edges ``near`` returns are those a brute-force distance to every segment finds."""
    panel = load_panel(DATA / "trimesh_plate_holes.stl")
    edges = panel.edges()
    a, b = edges.segments[:, 0], edges.segments[:, 1]
    assert np.max(np.linalg.norm(b - a, axis=1)) > 50 * np.median(np.linalg.norm(b - a, axis=1))
    rng = np.random.default_rng(3)
    lo, hi = panel.mesh.bounds
    pts = rng.uniform(lo, hi, (300, 3))
    radius = rng.uniform(1.0, 40.0, len(pts))
    pt, edge, dist = edges.near(pts, radius)
    ab = b - a
    s = np.clip(np.einsum("mkj,kj->mk", pts[:, None, :] - a[None], ab) / np.sum(ab * ab, axis=1), 0, 1)
    d_all = np.linalg.norm(a[None] + s[..., None] * ab[None] - pts[:, None, :], axis=2)
    want = set(zip(*np.nonzero(d_all <= radius[:, None])))
    assert len(want) > 100
    assert set(zip(pt.tolist(), edge.tolist())) == {(int(i), int(j)) for i, j in want}
    np.testing.assert_allclose(dist, d_all[pt, edge], rtol=0, atol=1e-9)
