"""The hole-log simulator: readings checked against the geometry in the TCS, the cell's own plane fit
against an SVD, the adjustment, the faults, determinism and chunking."""

import math

import numpy as np
import pytest
from scipy import stats

from metrology.io.data import data_path
from metrology.io.layout import load_layout
from metrology.sim.forward.head import draw_head, perturb_layout
from metrology.sim.forward.log import BLOCK_HOLES, cell_sizes, plane_normal, rotation_taking_axis, simulate_cell, \
    simulate_log
from metrology.sim.forward.log_spec import HoleChunk, LogSpec, SensorDrift, SensorShift, tool_axis_sign
from metrology.sim.forward.panels import make_panel

TABLE6 = load_layout(data_path("measured", "nominal.toml"))  # beams +z, noise 0.003 mm, range 40-60 mm
TABLE2 = load_layout(data_path("layout_table2.toml"))  # beams -z, no noise, no range
HEAD3 = draw_head(np.random.default_rng(4), 3).true


def truth_of(layout, seed=1):
    return perturb_layout(np.random.default_rng(seed), layout, (0.01, 0.05), (0.01, 0.05))


def one(spec, holes=3000, seed=0, cell=0):
    return HoleChunk.concat(simulate_cell(spec, seed, cell, holes))


def perfect(layout, panel, **kw):
    """Noise-free, unrounded readings; the cell knows its true layout."""
    kw.setdefault("noise_mm", 0.0)
    return LogSpec(layout, layout, panel, resolution_mm=0.0, **kw)


# ---------------------------------------------------------------- the cell's plane fit
def test_plane_normal_matches_an_svd_fit_with_and_without_blanks():
    rng = np.random.default_rng(0)
    h, n = 500, 4
    pts = rng.normal(scale=40.0, size=(h, n, 3)) * [1, 1, 0.05] + [0, 0, 30]
    valid = rng.random((h, n)) > 0.15
    normal, ok = plane_normal(pts, valid, 1.0)
    assert np.array_equal(ok, valid.sum(1) >= 3)
    for i in np.flatnonzero(ok):
        q = pts[i][valid[i]]
        v = np.linalg.svd(q - q.mean(0))[2][-1]
        v = v if v[2] < 0 else -v  # toward the head: n . k < 0 with k = +z
        assert np.max(np.abs(normal[i] - v)) < 1e-10
    assert np.all(np.isnan(normal[~ok]))


def test_plane_normal_refuses_collinear_points_and_turns_to_the_head():
    line = np.array([[[0, 0, 10], [1, 1, 10], [2, 2, 10], [3, 3, 10.0]]])
    assert not plane_normal(line, np.ones((1, 4), bool), 1.0)[1][0]
    flat = np.array([[[0, 0, 10], [1, 0, 10], [0, 1, 10.0]]])
    for s in (1.0, -1.0):
        n, ok = plane_normal(flat, np.ones((1, 3), bool), s)
        assert ok[0] and np.allclose(n[0], [0, 0, -s])


@pytest.mark.parametrize("s", [1.0, -1.0])
def test_rotation_taking_axis_is_a_rotation_onto_w(s):
    rng = np.random.default_rng(2)
    w = rng.normal(size=(100, 3)) + [0, 0, 3 * s]
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    Q = rotation_taking_axis(s, w)
    assert np.allclose(Q @ np.array([0, 0, s]), w, atol=1e-12)
    assert np.allclose(Q @ Q.transpose(0, 2, 1), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(Q), 1.0)


# ---------------------------------------------------------------- readings from the geometry
def tcs_surface_residual(panel, chunk, spec, after):
    """Each reading put back on its beam in the TCS, checked against the panel as the truth describes it
    there: its normal ``n`` at the drill point ``D k`` (and for a sphere its centre ``D k - R n``)."""
    lay, s = spec.true_layout, spec.axis_sign
    d = chunk.d_after if after else chunk.d
    n = chunk.normal_after_tcs if after else chunk.normal_tcs
    k = np.array([0, 0, s])
    spots = lay.zero + d[..., None] * lay.direction  # (h, n, 3), TCS
    drill = spec.standoff_distance_mm * k
    if panel.kind == "flat":
        return np.einsum("hsi,hi->hs", spots - drill, n)
    centre = drill - panel.radius_mm * n
    return np.linalg.norm(spots - centre[:, None, :], axis=-1) - panel.radius_mm


@pytest.mark.parametrize("layout", [TABLE6, TABLE2, HEAD3], ids=["table6", "table2", "3-sensor"])
@pytest.mark.parametrize("kind", ["flat", "sphere"])
def test_readings_lie_on_the_panel_seen_from_the_tcs(layout, kind):
    panel = make_panel(kind, 700.0)
    spec = perfect(truth_of(layout), panel, standoff_mm=50.0, spin_rad=math.radians(30))
    chunk = one(spec, 2000)
    assert np.all(np.isfinite(chunk.d)) and np.all(np.isfinite(chunk.d_after))
    for after in (False, True):
        assert np.max(np.abs(tcs_surface_residual(panel, chunk, spec, after))) < 1e-9


def test_tool_axis_sign_follows_the_beams():
    assert tool_axis_sign(TABLE6) == 1.0 and tool_axis_sign(TABLE2) == -1.0
    for layout in (TABLE6, TABLE2):
        spec = LogSpec(layout, layout, make_panel("flat"), noise_mm=0.0, standoff_mm=50.0, angle_rad=(0.0, 0.0))
        chunk = one(spec, 100)
        assert np.allclose(chunk.d.mean(1), 50.0, atol=1e-4)  # square to a flat panel: the target reading
        assert np.allclose(chunk.normal_tcs, [0, 0, -tool_axis_sign(layout)], atol=1e-12)


def test_true_angles_are_uniform_on_their_range_and_match_the_tcs_normal():
    spec = LogSpec(truth_of(TABLE6), TABLE6, make_panel("cylinder", 800.0))
    chunk = one(spec, 20000)
    deg = np.degrees(chunk.true_angle)
    assert deg.min() >= 0.5 - 1e-9 and deg.max() <= 5.0 + 1e-9
    assert stats.kstest(deg, stats.uniform(0.5, 4.5).cdf).pvalue > 1e-3
    assert np.allclose(np.arccos(-chunk.normal_tcs[:, 2]), chunk.true_angle, atol=1e-7)


def test_the_cell_with_its_true_layout_ends_square_on_a_flat_panel():
    chunk = one(perfect(TABLE6, make_panel("flat")), 2000)
    assert np.max(chunk.true_after) < 1e-10 and chunk.adjusted.all()
    noisy = one(LogSpec(TABLE6, TABLE6, make_panel("flat")), 2000)  # 3 um noise over a ~50 mm foot
    assert np.degrees(noisy.true_after).mean() < 0.02
    wrong = one(LogSpec(truth_of(TABLE6), TABLE6, make_panel("flat")), 2000)  # a calibration's error remains
    assert np.degrees(wrong.true_after).mean() > np.degrees(noisy.true_after).mean()
    assert np.all(wrong.true_after < wrong.true_angle)


# ---------------------------------------------------------------- faults
def pair(**kw):
    base = dict(true_layout=truth_of(TABLE6), cell_layout=TABLE6, panel=make_panel("flat"))
    return LogSpec(**base), LogSpec(**base, **kw)


def test_a_shift_moves_one_sensors_readings_by_its_size_from_its_hole():
    clean, knocked = pair(shifts=(SensorShift("L2", 0.05, 5000),))
    a, b = one(clean, 12000), one(knocked, 12000)
    diff = b.d - a.d
    assert np.all(np.abs(diff[:5000]) < 1e-12) and np.all(np.abs(diff[5000:, 1] - 0.05) < 1.01e-4)
    assert np.all(np.abs(np.delete(diff, 1, axis=1)) < 1e-12)
    assert np.array_equal(b.offset[:, 1], np.where(b.hole >= 5000, 0.05, 0.0))


def test_a_drift_grows_with_time_from_its_hole_and_only_in_its_cell():
    rate = 0.01  # mm per hour
    clean, drifting = pair(drifts=(SensorDrift("L3", rate, "hour", 1000, cell="C1"),))
    a, b = one(clean, 9000), one(drifting, 9000)
    t0 = clean.start_time_s + 1000 * 3600 / clean.holes_per_hour
    want = np.where(a.hole >= 1000, rate * np.maximum(a.time_s - t0, 0) / 3600, 0.0)
    assert np.all(np.abs(b.d[:, 2] - a.d[:, 2] - want) < 1.01e-4)
    assert want[-1] == pytest.approx(rate * 8000 / 600, rel=1e-3)  # 8000 holes at 600 per hour
    other = one(drifting, 2000, cell=1)  # C2: not drifting
    assert np.array_equal(other.d, one(clean, 2000, cell=1).d)
    per_hole = pair(drifts=(SensorDrift("L1", 1e-5, "hole", 0),))[1]
    assert np.abs(one(per_hole, 3000).d[:, 0] - one(clean, 3000).d[:, 0] - 1e-5 * np.arange(3000)).max() < 1.01e-4


def test_gross_readings_are_rare_and_large():
    clean, gross = pair(gross_rate=0.01)
    a, b = one(clean, 20000), one(gross, 20000)
    frac, n = b.gross.mean(), b.gross.size
    assert abs(frac - 0.01) < 5 * math.sqrt(0.01 * 0.99 / n)
    big = np.abs(b.d - a.d)[b.gross & np.isfinite(b.d)]
    assert big.min() > 0.2 - 0.1  # 0.2-2 mm off (and noise drawn after differs a little)


def test_out_of_range_readings_are_blank_and_a_hole_short_of_three_is_not_adjusted():
    narrow = TABLE6.with_params(TABLE6.zero, TABLE6.direction, range_mm=np.tile([48.5, 51.5], (4, 1)))
    chunk = one(LogSpec(narrow, narrow, make_panel("flat"), angle_rad=(math.radians(4), math.radians(5))), 5000)
    fin = chunk.d[np.isfinite(chunk.d)]
    assert np.isnan(chunk.d).any() and fin.min() >= 48.5 and fin.max() <= 51.5
    short = np.isfinite(chunk.d).sum(1) < 3
    assert short.any() and np.array_equal(~chunk.adjusted, short)
    assert np.allclose(chunk.true_after[short], chunk.true_angle[short])  # the cell kept its attitude


def test_bad_specs_are_refused():
    flat = make_panel("flat")
    with pytest.raises(ValueError, match="differ"):
        LogSpec(TABLE6, HEAD3, flat)
    with pytest.raises(ValueError, match="opposite sides"):
        LogSpec(TABLE6, TABLE6.with_params(TABLE6.zero, -TABLE6.direction), flat)
    with pytest.raises(ValueError, match="noise"):
        LogSpec(TABLE2, TABLE2, flat, standoff_mm=50)
    with pytest.raises(ValueError, match="stand-off"):
        LogSpec(TABLE2, TABLE2, flat, noise_mm=0.003)
    with pytest.raises(ValueError, match="angle range"):
        LogSpec(TABLE6, TABLE6, flat, angle_rad=(0.1, 0.05))
    with pytest.raises(ValueError, match="not in the layout"):
        LogSpec(TABLE6, TABLE6, flat, shifts=(SensorShift("L9", 0.1, 3),))


# ---------------------------------------------------------------- determinism and chunks
def fields(chunk):
    return {k: v for k, v in vars(chunk).items() if isinstance(v, np.ndarray)}


def test_same_seed_same_holes_other_seed_other_holes():
    spec = LogSpec(truth_of(TABLE6), TABLE6, make_panel("sphere", 900.0))
    a, b, c = one(spec, 500, seed=3), one(spec, 500, seed=3), one(spec, 500, seed=4)
    for k, v in fields(a).items():
        assert np.array_equal(v, fields(b)[k], equal_nan=True), k
    assert not np.array_equal(a.d, c.d, equal_nan=True)


def test_chunked_generation_equals_one_shot_and_a_short_log_is_a_prefix():
    spec = LogSpec(truth_of(TABLE6), TABLE6, make_panel("flat"), gross_rate=0.001)
    holes = 2 * BLOCK_HOLES + 123
    whole = list(simulate_cell(spec, 9, 0, holes, chunk_holes=holes))
    assert len(whole) == 1
    for size in (1000, 7777):
        parts = list(simulate_cell(spec, 9, 0, holes, chunk_holes=size))
        assert max(p.n for p in parts) == size and sum(p.n for p in parts) == holes
        joined = HoleChunk.concat(parts)
        for k, v in fields(whole[0]).items():
            assert np.array_equal(v, fields(joined)[k], equal_nan=True), (size, k)
    short = one(spec, 5000, seed=9)
    assert np.array_equal(short.d, whole[0].d[:5000], equal_nan=True)


def test_cells_split_the_holes_and_each_has_its_own_stream():
    assert cell_sizes(10, 3) == [4, 3, 3]
    spec = LogSpec(truth_of(TABLE6), TABLE6, make_panel("flat"))
    chunks = list(simulate_log(spec, 0, 1001, cells=2, chunk_holes=300))
    assert [c.cell for c in chunks] == ["C1"] * 2 + ["C2"] * 2 and sum(c.n for c in chunks) == 1001
    c1, c2 = HoleChunk.concat(chunks[:2]), HoleChunk.concat(chunks[2:])
    assert np.all(np.diff(c1.time_s) > 0) and not np.array_equal(c1.d[:500], c2.d)
    assert c1.hole_ids()[0] == "C1-00000001" and c2.hole_ids()[-1] == "C2-00000500"
