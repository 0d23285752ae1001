"""Real panels in the hole-log simulator: height-field and mesh panels, generated panels with their
hole tables, panels off their CAD, the pluggable controller, the commanded pose in the log."""

import math

import numpy as np
import pytest

from metrology.io.data import data_path
from metrology.io.layout import load_layout
from metrology.sim.forward.head import perturb_layout
from metrology.sim.forward.holes import HoleTable, check_table, read_hole_table
from metrology.sim.forward.log import BLOCK_HOLES, MicroPlane, rotation_vector, simulate_cell, simulate_log
from metrology.sim.forward.log_spec import HoleChunk, LogSpec
from metrology.sim.forward.meshes import MeshPanel, generated_holes, load_sim_panel, panel_mesh
from metrology.sim.forward.panels import make_panel
from metrology.sim.forward.shapes import GENERATED, OffCadPanel, generated_panel, parse_off_cad

TABLE6 = load_layout(data_path("measured", "nominal.toml"))
PANELS = data_path("panels")


def table_of(panel, **kw):
    ids, P, f = generated_holes(panel, **kw)
    return HoleTable("<generated>", tuple(ids), P, f)


def one(spec, holes, seed=0):
    return HoleChunk.concat(simulate_cell(spec, seed, 0, holes))


# ---------------------------------------------------------------- surfaces
@pytest.mark.parametrize("name", list(GENERATED))
def test_ray_cast_hits_on_the_mesh_equal_the_analytic_surface_within_its_chordal_error(name):
    panel = generated_panel(name)
    spacing = 10.0
    mesh = MeshPanel(*panel_mesh(panel, panel.half_mm, spacing))
    rng = np.random.default_rng(1)
    e = np.c_[rng.uniform(-90, 90, (2000, 2)), np.full(2000, 80.0)]
    u = rng.normal(size=(2000, 3)) * [0.15, 0.15, 0] + [0, 0, -1]
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    t_exact, t_mesh = panel.intersect(e, u), mesh.intersect(e, u)
    on = np.isfinite(t_exact)
    assert np.array_equal(on, np.isfinite(t_mesh)) and on.mean() > 0.98  # both miss beyond the panel's edge
    e, u, t_exact, t_mesh = e[on], u[on], t_exact[on], t_mesh[on]
    # chordal error of a cell: (its diagonal)^2 * kappa_max / 8, along a ray at most 1 / cos(tilt) of it
    kappa = np.max(np.abs(np.linalg.eigvalsh(panel.shape_at(np.zeros((1, 3)))))) * 1.1
    chord = 2 * spacing ** 2 * kappa / 8
    err = np.abs(t_exact - t_mesh)
    assert err.max() < chord / np.min(-u[:, 2]) and err.max() > 0.05 * chord  # faceted, within its chord
    # the exact hit lies on the analytic surface
    hit = e + t_exact[:, None] * u
    assert np.max(np.abs(hit[:, 2] - panel.height(hit[:, 0], hit[:, 1]))) < 1e-9
    # the mesh's smooth normal and its quadric's curvature follow the surface's
    assert np.degrees(np.arccos(np.clip(np.sum(mesh.normal_at(hit) * panel.normal_at(hit), 1), -1, 1))).max() < np.degrees(
        0.5 * spacing * kappa)  # within half a facet's turn (the edge's vertex normals lean most)
    S, Sm = panel.shape_at(np.zeros((1, 3)))[0], mesh.shape_at(np.zeros((1, 3)))[0]
    assert np.abs(S - Sm).max() < 0.02 * kappa


def test_shape_operators_have_the_contracts_signs():
    origin = np.zeros((1, 3))
    assert np.allclose(make_panel("sphere", 500.0).shape_at(origin)[0], np.diag([1, 1, 0]) / 500, rtol=1e-5)
    barrel = generated_panel("barrel").shape_at(origin)[0]
    assert np.allclose(barrel, np.diag([-1 / 2000, 0, 0]), atol=1e-9)  # concave: drilled from inside
    nacelle = np.sort(np.linalg.eigvalsh(generated_panel("nacelle").shape_at(origin)[0]))
    assert np.allclose(nacelle, [0, 1 / 1200, 1 / 400], atol=1e-8)  # the lip's R 400 and R 1200
    saddle = np.sort(np.linalg.eigvalsh(generated_panel("saddle").shape_at(origin)[0]))
    assert np.allclose(saddle, [-1 / 800, 0, 1 / 800], atol=1e-8)
    az = math.radians(30)
    cyl = make_panel("cylinder", 1000.0, (math.cos(az), math.sin(az), 0)).shape_at(origin)[0]
    across = np.array([-math.sin(az), math.cos(az), 0])
    assert np.allclose(cyl, np.outer(across, across) / 1000, atol=1e-8)


def test_sphere_as_a_height_field_matches_its_closed_form():
    sphere = make_panel("sphere", 500.0)
    as_height = OffCadPanel(sphere, "shift", 0.0, shift_mm=(0.0, 0.0, 0.0))
    rng = np.random.default_rng(2)
    e = np.c_[rng.uniform(-100, 100, (500, 2)), np.full(500, 60.0)]
    u = np.array([0.1, 0.05, -1.0]) / np.linalg.norm([0.1, 0.05, -1.0])
    assert np.allclose(as_height.intersect(e, u), sphere.intersect(e, u), atol=1e-9)
    hit = e + sphere.intersect(e, u)[:, None] * u
    assert np.allclose(as_height.normal_at(hit), sphere.normal_at(hit), atol=1e-9)


# ---------------------------------------------------------------- generated panels and their tables
@pytest.mark.parametrize("name", list(GENERATED))
def test_a_bundled_panels_hole_table_lies_on_it_with_feeds_into_it(name):
    truth, cad = load_sim_panel(PANELS / f"{name}.stl")
    assert truth is cad and truth.kind == name  # the smooth surface the mesh was made from
    table = read_hole_table(PANELS / f"{name}.holes.csv")
    assert table.m == 25 and len(set(table.ids)) == 25
    z = truth.height(table.points[:, 0], table.points[:, 1])
    assert np.abs(z - table.points[:, 2]).max() < 1e-6  # 6 decimals in the file
    n = truth.normal_at(table.points)
    assert np.degrees(np.arccos(np.clip(-np.sum(n * table.feed, 1), -1, 1))).max() < 1e-4  # feed = -normal
    check_table(table, truth)
    # the STL is the faceted CAD: the table's points lie on it within its chordal error
    mesh = MeshPanel(*panel_mesh(truth, truth.half_mm, 10.0))
    check_table(table, mesh)


def test_the_barrel_is_concave_and_drilled_from_inside():
    barrel = generated_panel("barrel")
    assert barrel.height(np.array([100.0]), np.array([0.0]))[0] > 0  # rises toward the head away from the crest
    ids, P, f = generated_holes(barrel)
    assert np.all(f[:, 2] < 0)


# ---------------------------------------------------------------- drilling a table
def test_holes_are_drilled_at_the_table_cycled_with_unique_ids_and_the_commanded_pose():
    panel = generated_panel("wing")
    table = table_of(panel)
    spec = LogSpec(TABLE6, TABLE6, panel, noise_mm=0.0, resolution_mm=0.0, table=table)
    chunks = list(simulate_log(spec, 0, 60, cells=2))
    ids = np.concatenate([c.hole_ids() for c in chunks])
    assert len(set(ids)) == 60 and list(ids[:2]) == ["H0001", "H0002"] and ids[25] == "H0001#2"
    assert list(ids[50:52]) == ["H0001#3", "H0002#3"]  # the second cell goes on where the first stopped
    c = chunks[0]
    assert np.array_equal(c.panel[:26], [0] * 25 + [1])
    assert np.allclose(c.nominal[:25], table.points)
    # the commanded pose: the tool axis along the table's feed, through its point at the stand-off
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(c.pose_rotvec).as_matrix()
    assert np.allclose(R[:25, :, 2] * spec.axis_sign, table.feed, atol=1e-12)
    assert np.allclose(c.pose_origin[:25] + spec.standoff_distance_mm * table.feed, table.points, atol=1e-9)
    # the truth: noise-free, the cell's plane on a curved panel leaves a small error; on its CAD the
    # panel's offset is nil and the drilled point is the nominal one
    assert np.all(np.abs(c.cad_offset) < 1e-5) and np.all(np.degrees(c.cad_angle) < 1e-3)
    assert np.all(np.linalg.norm(c.drill_point - c.nominal, axis=1) < 0.05)
    assert np.all(c.true_after < c.true_angle)


@pytest.mark.parametrize("off", [None, "dent:0.2@10,-5", "shift:0.3,-0.2,0.5"])
def test_readings_lie_on_the_true_panel_seen_from_the_logged_pose(off):
    """No robot error: the head is at its commanded (logged) pose; each reading put on its beam and taken
    into the panel frame with the logged pose lies on the true panel."""
    from scipy.spatial.transform import Rotation

    cad = generated_panel("nacelle")
    truth = cad if off is None else parse_off_cad(off, cad)
    spec = LogSpec(TABLE6, TABLE6, truth, cad_panel=None if off is None else cad, noise_mm=0.0, resolution_mm=0.0,
                   angle_rad=(0.0, 0.0), spin_rad=math.radians(20), table=table_of(cad))
    c = one(spec, 25)
    R = Rotation.from_rotvec(c.pose_rotvec).as_matrix()
    spots = TABLE6.zero + c.d[..., None] * TABLE6.direction  # (h, n, 3) TCS
    p = np.einsum("hij,hnj->hni", R, spots) + c.pose_origin[:, None, :]
    assert np.all(np.isfinite(p))
    assert np.abs(p[..., 2] - truth.height(p[..., 0], p[..., 1])).max() < 1e-8
    if off is None:  # commanded along the CAD's normal, which is the truth's
        assert np.degrees(c.true_angle).max() < 1e-6


@pytest.mark.parametrize("off, expect", [("shift:0,0,1", 1.0), ("dent", -0.2), ("springback@-50", 0.2)])
def test_a_panel_off_its_cad_moves_the_readings_by_the_stated_amount(off, expect):
    cad = generated_panel("wing")
    table = HoleTable("<one>", ("A",), np.array([[0.0, 0.0, 0.0]]), np.array([[0.0, 0.0, -1.0]]))
    base = dict(noise_mm=0.0, resolution_mm=0.0, angle_rad=(0.0, 0.0), table=table)
    on = one(LogSpec(TABLE6, TABLE6, cad, **base), 1)
    offp = parse_off_cad(off, cad)
    moved = one(LogSpec(TABLE6, TABLE6, offp, cad_panel=cad, **base), 1)
    # the head stands where it was commanded: square to the CAD at (0, 0); the surface rose by `expect`
    # at the drill point; each beam's reading shortens by the rise along it there
    assert moved.cad_offset[0] == pytest.approx(expect, abs=1e-6)
    spots = TABLE6.zero + on.d[0][:, None] * TABLE6.direction  # TCS
    rise = []
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(on.pose_rotvec[0]).as_matrix()
    for p in spots @ R.T + on.pose_origin[0]:
        rise.append(offp.height(p[0], p[1]) - cad.height(p[0], p[1]))
    want = -np.array(rise) / TABLE6.direction[:, 2]  # beams climb along TCS z (k toward -z of the panel)
    assert np.allclose(moved.d[0] - on.d[0], want, atol=0.05 * abs(expect))  # to first order: the spots slide
    assert np.abs(moved.d[0] - on.d[0]).max() > 0.1 * abs(expect)


def test_a_dent_shows_in_the_truths_cad_angle_where_it_slopes():
    cad = generated_panel("wing")
    table = table_of(cad)
    spec = LogSpec(TABLE6, TABLE6, parse_off_cad("dent:0.2@0,0", cad), cad_panel=cad, table=table)
    c = one(spec, 25)
    r = np.hypot(*c.nominal[:, :2].T)
    slope = np.degrees(np.pi * 0.2 / 100)  # the dent's steepest slope, at r = 25 mm
    assert np.degrees(c.cad_angle[np.isclose(r, 25.0)]).max() == pytest.approx(slope, rel=0.05)
    assert np.all(np.degrees(c.cad_angle[r >= 50]) < 1e-4)  # (finite differences at the dent's rim)


# ---------------------------------------------------------------- the controller hook
class Spy:
    """A stub controller (tests only): records what it was handed, answers the micro-plane's normal or a fixed one."""

    name = "spy"
    wants_shape = True

    def __init__(self, fixed=None):
        self.calls, self.fixed = [], fixed

    def __call__(self, layout, d, shape):
        self.calls.append((layout, d.copy(), shape.copy()))
        if self.fixed is not None:
            return np.tile(self.fixed, (len(d), 1)), np.ones(len(d), bool)
        return MicroPlane()(layout, d)


def test_the_controller_gets_the_cad_shape_in_the_tcs_of_the_commanded_pose():
    cad = generated_panel("nacelle")
    truth = parse_off_cad("shift:0.5,0,0", cad)
    table = table_of(cad)
    cell = perturb_layout(np.random.default_rng(1), TABLE6, (0.01, 0.02), (0.01, 0.02))
    spy = Spy()
    c = one(LogSpec(TABLE6, cell, truth, cad_panel=cad, table=table, controller=spy), 25)
    layout, d, shape = spy.calls[0]
    assert layout is cell and np.array_equal(d[:25], c.d, equal_nan=True)
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(c.pose_rotvec).as_matrix()
    want = np.einsum("hji,hjk,hkl->hil", R, cad.shape_at(table.points), R)  # the CAD's, not the truth's
    assert np.allclose(shape[:25], want, atol=1e-12)
    k = np.array([0, 0, 1.0])
    assert np.allclose(np.einsum("hij,j->hi", shape[:25], k), 0, atol=1e-12)  # tangent to the surface
    # the micro-plane through the spy gives the default controller's holes, byte for byte
    ref = one(LogSpec(TABLE6, cell, truth, cad_panel=cad, table=table), 25)
    assert np.array_equal(ref.d_after, c.d_after, equal_nan=True)


def test_the_cell_turns_the_drill_onto_the_controllers_normal():
    panel = generated_panel("saddle")
    table = table_of(panel)
    base = dict(noise_mm=0.0, resolution_mm=0.0, table=table)
    still = one(LogSpec(TABLE6, TABLE6, panel, controller=Spy(fixed=[0, 0, -1.0]), **base), 25)  # keep attitude
    assert np.allclose(still.true_after, still.true_angle, atol=1e-9)
    assert np.allclose(still.d_after, still.d, atol=1e-9)
    # a controller that knows the truth (the true normal in the TCS before the adjustment, which no
    # controller changes) puts the drill on the true normal
    plain = one(LogSpec(TABLE6, TABLE6, panel, **base), BLOCK_HOLES)
    exact = one(LogSpec(TABLE6, TABLE6, panel, controller=Spy(fixed=None), **base), BLOCK_HOLES)
    assert np.allclose(exact.d_after, plain.d_after, atol=1e-9)

    class Oracle(Spy):
        def __call__(self, layout, d, shape):
            return plain.normal_tcs[:len(d)], np.ones(len(d), bool)

    exact = one(LogSpec(TABLE6, TABLE6, panel, controller=Oracle(), **base), 25)
    assert np.degrees(exact.true_after).max() < 1e-7 < 1e-3 < np.degrees(plain.true_after).max()


# ---------------------------------------------------------------- determinism, bad input
def test_same_seed_same_holes_and_a_prefix_for_fewer():
    panel = generated_panel("wing")
    spec = LogSpec(TABLE6, TABLE6, parse_off_cad("dent", panel), cad_panel=panel, table=table_of(panel))
    a, b, c = one(spec, 300, seed=5), one(spec, 300, seed=5), one(spec, 100, seed=5)
    assert a.d.tobytes() == b.d.tobytes() and a.d_after.tobytes() == b.d_after.tobytes()
    assert a.d[:100].tobytes() == c.d.tobytes() and list(a.hole_ids()[:100]) == list(c.hole_ids())
    assert one(spec, 100, seed=6).d.tobytes() != c.d.tobytes()


def test_bad_off_cad_values_are_refused():
    wing = generated_panel("wing")
    for bad, msg in [("bump", "expected dent"), ("dent:x", "not 1 number"), ("shift:1,2", "3 finite"),
                     ("shift:1,2,3@4", "no @centre"), ("dent:0.2@1", "2 finite")]:
        with pytest.raises(ValueError, match=msg):
            parse_off_cad(bad, wing)
    with pytest.raises(ValueError, match="expected one of"):
        generated_panel("wingg")


def test_rotation_vector_round_trips():
    from scipy.spatial.transform import Rotation

    R = Rotation.random(50, random_state=3).as_matrix()
    assert np.allclose(Rotation.from_rotvec(rotation_vector(R)).as_matrix(), R, atol=1e-12)


def test_the_cell_keeps_its_attitude_where_the_controller_answers_nonsense():
    panel = generated_panel("wing")
    base = dict(noise_mm=0.0, resolution_mm=0.0, table=table_of(panel))
    for answer in ([0, 0, 1.0], [np.nan, 0, -1.0]):  # facing away from the head; not finite
        c = one(LogSpec(TABLE6, TABLE6, panel, controller=Spy(fixed=np.array(answer)), **base), 25)
        assert not c.adjusted.any() and np.allclose(c.true_after, c.true_angle, atol=1e-9)
