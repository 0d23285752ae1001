"""metrology.measure.summary: mergeable counts, quantiles within their bin, Ppk."""

import numpy as np
import pyarrow as pa
import pytest

from metrology.io.holelog import batch_of
from metrology.measure.holes import Settings, measure_batch
from metrology.measure.summary import FleetSummary, quantile_deg

from .helpers import calibrated_layout, hole_log


def _batch(n, seed, cells=("C1", "C2")):
    cols, _, _ = hole_log(calibrated_layout(), n=n, seed=seed, cells=cells, angle_deg=(0.1, 0.8))
    cols["time"] = (1.79e9 + np.arange(len(cols["hole_id"])) * 600.0).tolist()
    t = batch_of(pa.table(cols), calibrated_layout().names)
    return measure_batch(calibrated_layout(), t, Settings())


def test_merged_halves_equal_one_pass():
    b = _batch(500, 1)
    whole = FleetSummary(0.5)
    whole.add(b)
    halves = FleetSummary(0.5)
    for part in (slice(0, 400), slice(400, None)):
        other = FleetSummary(0.5)
        from dataclasses import replace

        idx = np.arange(len(b))[part]
        sub = replace(b, columns=b.columns.take(pa.array(idx)), status=b.status[idx], judged=b.judged[idx],
                      judged_u95=b.judged_u95[idx], angle_before=b.angle_before[idx], angle_after=b.angle_after[idx],
                      cell=None, panel=None)  # the labels read again from the rows taken
        other.add(sub)
        halves.merge(other)
    assert whole.counts() == halves.counts()
    assert sorted(whole.groups) == sorted(halves.groups) and len(whole.groups) > 2  # cells x days
    assert whole.figures(whole.total()).mean_deg == pytest.approx(halves.figures(halves.total()).mean_deg, rel=1e-9)
    assert np.array_equal(whole.total().hist_judged, halves.total().hist_judged)
    assert whole.worst == halves.worst


def test_quantiles_and_moments_against_numpy():
    b = _batch(3000, 2, cells=("C1",))
    s = FleetSummary(0.5)
    s.add(b)
    f = s.figures(s.total())
    a = np.degrees(b.angle_before)
    for q in (0.5, 0.95):
        assert f.quantiles_before_deg.to_dict()[f"p{q * 100:g}"] == pytest.approx(np.quantile(a, q), rel=0.02)
    j = np.degrees(b.judged)
    assert f.mean_deg == pytest.approx(j.mean(), rel=1e-9) and f.sd_deg == pytest.approx(j.std(ddof=1), rel=1e-9)
    assert quantile_deg(np.zeros(10, int), 0.5) != quantile_deg(np.zeros(10, int), 0.5)  # NaN when empty


def test_histogram_bins_are_the_edges_search():
    from metrology.measure.summary import EDGES_DEG, _bins

    rng = np.random.default_rng(0)
    a = np.concatenate([EDGES_DEG, np.nextafter(EDGES_DEG, -1)[1:], np.nextafter(EDGES_DEG, np.inf),
                        rng.uniform(0, 100, 10 ** 5), 10 ** rng.uniform(-6, 2.5, 10 ** 5), [0.0, 90.0, 1e9]])
    want = np.clip(np.searchsorted(EDGES_DEG, a, side="right") - 1, 0, len(EDGES_DEG) - 1)
    np.testing.assert_array_equal(_bins(a), want)


def test_worst_holes_are_the_full_sort_s_first():
    """Ties at the cut: the earliest rows among equal angles, as a stable sort of every hole keeps them."""
    from dataclasses import replace

    from metrology.measure.summary import WORST

    b = _batch(3000, 3)
    rng = np.random.default_rng(1)
    judged = np.radians(np.round(rng.uniform(0, 1, len(b)), 2))  # many ties at the cut
    b = replace(b, judged=judged, status=np.zeros(len(b), np.int8))
    s = FleetSummary(0.5)
    s.add(b)
    deg = np.degrees(judged)
    want = np.argsort(-deg, kind="stable")[:WORST]
    assert [w.hole_id for w in s.worst] == [b.columns.column("hole_id")[int(i)].as_py() for i in want]


def test_the_json_reads_the_typed_records_key_for_key():
    """FleetSummary's records are typed (GroupKey, Counts, Figures, WorstHole, the CAD sums); the JSON they make is
    the one it was when they were dicts: the same keys in the same order, the same values."""
    from metrology.measure.tally import Counts, Figures, GroupKey, WorstHole

    b = _batch(3000, 2, cells=("C1", "C2"))
    s = FleetSummary(0.5)
    s.add(b)
    assert all(isinstance(k, GroupKey) for k in s.groups) and all(isinstance(w, WorstHole) for w in s.worst)
    c = s.counts()
    assert isinstance(c, Counts) and list(c.to_dict()) == ["conforms", "fails", "undecided", "not_measured"]
    assert c.total == len(b) == sum(c.to_dict().values())
    fleet = s.figures(s.total())
    assert isinstance(fleet, Figures)
    d = fleet.to_dict()
    assert list(d) == ["measured", "mean_deg", "sd_deg", "ppk", "ppk_ci95", "capability", "quantiles_before_deg",
                       "quantiles_after_deg"]
    assert list(d["quantiles_before_deg"]) == ["p50", "p95", "p99", "p99.9"] and isinstance(d["ppk_ci95"], list)
    assert d["quantiles_before_deg"]["p99.9"] == fleet.quantiles_before_deg.p99_9
    key, grp = sorted(s.groups.items())[0]
    assert list(s.figures(grp).to_dict()) == ["measured", "mean_deg", "sd_deg"]  # a group keeps no histogram
    assert tuple(key) == (key.cell, key.panel, key.day) and key.day.count("-") == 2
    w = s.worst[0].to_dict()
    assert list(w) == ["hole_id", "cell", "panel", "time_s", "angle_deg", "U95_deg", "status"]
    assert w["angle_deg"] == max(x.angle_deg for x in s.worst)
    assert s.off_cad_figures() == {"off_cad_sigmas": 4.0, "off_cad_checked": 0, "off_cad_holes": 0,
                                   "off_cad_mean_per_mm": 0.0, "off_cad_max_per_mm": 0.0, "off_cad_max_hole": None}
