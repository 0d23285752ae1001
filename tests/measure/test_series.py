"""The drift chart's plotted series: a long batch binned at once at the stride the pairwise merges reach
gives the bins those merges give (metrology.measure.chart.CusumChart._record, metrology.measure.series)."""

import numpy as np

from metrology.measure.chart import CusumChart
from metrology.measure.series import Bins, extremes, merge_pairs


def _merged(chart_bins, stride, keep, t, s):
    """The series made the plain way: bins of ``stride`` holes added, then merged while over ``keep``."""
    bins = Bins(chart_bins.t.copy(), chart_bins.s.copy(), chart_bins.v.copy(), chart_bins.br.copy())
    full = len(s) // stride * stride
    bins.add(*extremes(t[:full].reshape(-1, stride), s[:full].reshape(-1, stride)))
    if full < len(s):
        bins.add(*extremes(t[full:][None, :], s[full:][None, :]))
    while bins.count > keep:
        bins = merge_pairs(bins)
        stride *= 2
    return bins, stride


def test_long_batches_bin_as_the_merges_would():
    rng = np.random.default_rng(3)
    chart = CusumChart("C1", ("L1", "L2", "L3", "L4"), keep=50)
    start = 0
    for k, n in enumerate([7, 3000, 1, 513, 64, 9000, 2, 777]):
        if k in (3, 6):
            chart._bins.brk()  # a new baseline: the line breaks
        t = start + np.arange(n, dtype=float)
        s = np.round(rng.normal(size=n), 1)  # ties: the first of equal extremes is kept
        want, stride = _merged(chart._bins, chart._stride, chart.keep, t, s)
        chart._record(t, s)
        start += n
        np.testing.assert_array_equal(chart._bins.t, want.t)
        np.testing.assert_array_equal(chart._bins.s, want.s)
        np.testing.assert_array_equal(chart._bins.v, want.v)
        np.testing.assert_array_equal(chart._bins.br, want.br)
        assert chart._stride == stride
