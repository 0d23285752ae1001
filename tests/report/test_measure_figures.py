"""The drift chart of ``metro measure --report``: what it plots is what the chart computed (every
peak, the alarm's crossing of h), its line breaks where the chart took a new baseline, and its
time axis names its origin; the figure states, in image pixels, where its line must show (and
must not) for ``benchmarks/check_reports_browser.py`` to check in Chromium."""

from __future__ import annotations

import base64
import io

import numpy as np

from metrology.measure.chart import CUSUM_H, CusumChart
from metrology.report.measure import _chart_figure
from tests.measure.test_chart import SENSORS, SIG, _feed


def _chart():
    rng = np.random.default_rng(5)
    n, k = 20000, 12000
    rho = rng.normal(0, 0.003, n)
    rho[k:] += SIG[2] * 0.015
    chart = _feed(CusumChart("C1", SENSORS), rho)
    assert len(chart.alarms) == 1
    return chart


def test_the_plotted_cusum_reaches_the_alarm_and_breaks_at_the_new_baseline():
    chart = _chart()
    a = chart.alarms[0]
    fig = _chart_figure(chart, chart.alarms)
    ax = fig.axes[0]
    line = next(ln for ln in ax.lines if ln.get_label() == "CUSUM")
    x, y = (np.asarray(v, float) for v in line.get_data())
    data = np.array([s for _, s in chart.series], float)
    assert np.nanmax(y) == np.nanmax(data) > CUSUM_H  # the crossing is drawn
    t0 = chart.series[0][0]
    at = np.flatnonzero(np.isclose(x, (a.time_s - t0) / 3600.0) & (y > CUSUM_H))
    assert at.size == 1
    assert np.isnan(y[at[0] + 1])  # no line from the alarm to the next baseline's first hole
    label = ax.get_xlabel()
    assert "first charted hole" in label and "baseline" in label
    fig.clf()


def _rgb(png):
    import matplotlib.image as mpimg

    return mpimg.imread(io.BytesIO(png), format="png")[..., :3]


def test_the_figure_states_where_its_line_shows_and_the_png_agrees():
    """The report's drift-chart figure carries ``expect`` boxes in image pixels (the line near h at
    the alarm; no line over the new baseline's gap), and the embedded PNG's pixels bear them out."""
    from matplotlib.colors import to_rgb

    from metrology.report.html import figure_from_matplotlib

    chart = _chart()
    f = figure_from_matplotlib(_chart_figure(chart, chart.alarms), "drift")
    assert {e[5] for e in f.expect} == {True, False}
    img = _rgb(base64.b64decode(f.data_uri.split(",", 1)[1]))
    for x0, y0, x1, y1, colour, present in f.expect:
        box = img[int(y0):int(np.ceil(y1)) + 1, int(x0):int(np.ceil(x1)) + 1]
        near = np.linalg.norm(box - np.array(to_rgb(colour)), axis=-1) < 0.3
        assert near.any() == present, (x0, y0, x1, y1, colour, present)
