"""The judged angle's capability (issue 37 item 2): an angle is bounded below by 0 (a folded
distribution), so metro gives the ISO 22514-2 percentile-based Ppk against the one upper limit,
with a bootstrap confidence interval. On logs of the independent forward simulator."""


import numpy as np
import pytest

from metrology.core.paper import TABLE6_NOMINAL, layout_from_table
from metrology.io.holelog import batch_of
from metrology.measure.holes import Settings, measure_batch
from metrology.measure.summary import FleetSummary
from metrology.sim.forward import perturb_layout
from metrology.sim.forward.log import simulate_cell
from metrology.sim.forward.log_spec import LogSpec
from metrology.sim.forward.log_write import log_table
from metrology.sim.forward.panels import make_panel


def _summary(holes, seed, tol_deg=0.05):
    rng = np.random.default_rng(3)
    nominal = layout_from_table(TABLE6_NOMINAL, noise_mm=0.003)
    nominal = nominal.with_params(nominal.zero, nominal.direction, range_mm=np.tile([30.0, 70.0], (4, 1)))
    true = perturb_layout(rng, nominal, zero_error_mm=(0.002, 0.01), direction_error_deg=(0.001, 0.01))
    cov = np.diag(np.tile([0.005 ** 2] * 3 + [np.radians(0.01) ** 2] * 2, 4))
    spec = LogSpec(true_layout=true, cell_layout=nominal.with_params(nominal.zero, nominal.direction, covariance=cov),
                   panel=make_panel("flat"))
    (chunk,) = list(simulate_cell(spec, seed, 0, holes, chunk_holes=holes))
    b = measure_batch(spec.cell_layout, batch_of(log_table(chunk), spec.cell_layout.names),
                      Settings(tolerance=np.radians(tol_deg), min_radius_mm=np.inf))
    s = FleetSummary(tol_deg)
    s.add(b)
    return s, np.degrees(b.judged[np.isfinite(b.judged)])


def test_ppk_is_the_percentile_method_on_the_judged_angle_with_its_interval():
    s, j = _summary(20000, 1)
    f = s.figures(s.total())
    assert "cpk" not in f.to_dict()  # a normal-theory index of a folded angle means nothing
    p50, p99865 = np.quantile(j, [0.5, 0.99865])
    assert f.ppk == pytest.approx((0.05 - p50) / (p99865 - p50), rel=0.05)
    lo, hi = f.ppk_ci95
    assert lo < f.ppk < hi and hi - lo < 0.5 * f.ppk
    assert "22514-2" in f.capability
    # same data, same interval (the bootstrap's Generator is seeded)
    assert s.figures(s.total()).ppk_ci95 == f.ppk_ci95


def test_ppk_is_not_given_on_too_few_holes():
    s, _ = _summary(300, 3)
    f = s.figures(s.total())
    assert np.isnan(f.ppk) and all(np.isnan(f.ppk_ci95))


def test_the_interval_covers_the_process_ppk():
    """Logs of the same process: their 95 % intervals hold the process's Ppk (from a log 6x larger)
    about 95 % of the time (here: at least 5 of 6)."""
    _, big = _summary(120000, 100)
    p50, p99865 = np.quantile(big, [0.5, 0.99865])
    truth = (0.05 - p50) / (p99865 - p50)
    held = 0
    for seed in range(6):
        s, _ = _summary(20000, 10 + seed)
        lo, hi = s.figures(s.total()).ppk_ci95
        held += lo <= truth <= hi
    assert held >= 5
