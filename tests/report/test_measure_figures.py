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


def _png_size(uri):
    import struct

    png = base64.b64decode(uri.split(",", 1)[1])
    return struct.unpack(">II", png[16:24])


def test_every_figure_has_a_phone_version_with_its_text_at_9_px_or_more():
    """At a 412 px window the page's column is 394 px: a 960 px figure would show its 12 px text
    at 5 px. Each figure is drawn again 380 px wide, its text as large in its pixels, and long
    axis labels wrapped onto more lines so none runs off the figure."""
    from metrology.report.html import NARROW_IN, figure_from_matplotlib
    from metrology.report.style import pyplot

    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    for ax in axes:
        ax.plot([0, 1], [0, 1])
        ax.set_xlabel("angle between the drill axis and the measured normal [deg]")
        ax.set_ylabel("share of holes per bin [1]")
    f = figure_from_matplotlib(fig, "three panels")
    assert f.narrow_uri.startswith("data:image/png;base64,")
    w, _ = _png_size(f.narrow_uri)
    assert w == round(NARROW_IN * 96) <= 394
    assert _png_size(f.data_uri)[0] == 960
    assert f.min_font_px >= 12.0  # 9 pt at 96 px per inch, in both images: >= 9 px on a 360 px phone too


def test_the_narrow_figure_wraps_a_label_longer_than_its_axes():
    from metrology.report.html import _narrow
    from metrology.report.style import pyplot

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 2.6))
    ax.plot([0, 1], [0, 1])
    ax.set_xlabel("hours since the first charted hole, 2026-11-25T07:40:01Z (after the cell's 1000 baseline holes)")
    fig.suptitle("datum.ply: 2420/2500 inliers, RMS 0.0147 mm, flatness 0.0887 mm\nquadratic form P-V 0.0014 mm "
                 "(p = 0.78, not significant: dotted)")
    _narrow(fig)
    r = fig.canvas.get_renderer()
    width = fig.get_size_inches()[0] * fig.dpi
    assert "\n" in ax.get_xlabel()
    assert ax.xaxis.label.get_window_extent(r).width <= width
    assert fig._suptitle.get_text().count("\n") >= 2 and fig._suptitle.get_window_extent(r).width <= width
    plt.close(fig)


def test_table_cells_and_the_command_line_break_between_words_only():
    """A hole id, a time's date and an option such as ``--out`` are kept whole (a no-wrap span);
    a path longer than a phone's line may still break."""
    from metrology.report.html import Headline, RunInfo, Section, Table, render_html

    long_path = "/tmp/" + "x" * 40 + "/log.csv"
    page = render_html("t", RunInfo(command=f"metro measure {long_path} --out r.parquet"),
                       [Section("s", Headline(True, "ok"), tables=(Table("worst", ("hole", "time [UTC]"),
                                                                        (("C1-00018770", "2026-11-26 13:16:54"),)),))])
    assert '<td><span class="nb">C1-00018770</span></td>' in page
    assert '<span class="nb">2026-11-26</span> <span class="nb">13:16:54</span>' in page
    assert page.count('<span class="nb">--out</span>') == 2  # the header and the "what was run" table
    assert f" {long_path} " in page  # too long to keep whole
