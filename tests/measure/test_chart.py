"""metrology.measure.chart: the CUSUM's run lengths, its alarms on a step and a drift, batch-split
invariance."""

import numpy as np
import pytest

from metrology.measure.chart import (ARL0_HOLES, ARL_AT_DETECTABLE, BASELINE_HOLES, CUSUM_H, CUSUM_K, CusumChart,
                                     DETECTABLE_SCALES, cusum_arl, cusum_h)

SIG = np.array([0.43, -0.43, 0.43, -0.43])  # d rho / d delta of a square foot (Table 6-like)
SENSORS = ("L1", "L2", "L3", "L4")


def test_constants_are_what_the_markov_chain_gives():
    assert cusum_arl(CUSUM_H, CUSUM_K) == pytest.approx(ARL0_HOLES, rel=0.01)
    assert cusum_h(ARL0_HOLES, CUSUM_K) == pytest.approx(CUSUM_H, abs=2e-3)
    assert cusum_arl(CUSUM_H, CUSUM_K, DETECTABLE_SCALES) == pytest.approx(ARL_AT_DETECTABLE, abs=0.05)


@pytest.mark.parametrize("h, shift", [(3.0, 0.0), (4.0, 0.0), (4.0, 1.0)])
def test_markov_chain_arl_against_simulation(h, shift):
    """Brook-Evans against the run lengths of 3000 simulated two-sided CUSUMs."""
    rng = np.random.default_rng(int(h * 10 + shift))
    runs = []
    for _ in range(3000):
        up = dn = 0.0
        t = 0
        while True:
            x = rng.normal() + shift
            t += 1
            up, dn = max(0.0, up + x - CUSUM_K), max(0.0, dn - x - CUSUM_K)
            if up > h or dn > h:
                break
        runs.append(t)
    mean, se = np.mean(runs), np.std(runs) / np.sqrt(len(runs))
    assert abs(mean - cusum_arl(h, CUSUM_K, shift)) < 4 * se


def _feed(chart, rho, batch=None, panel="P"):
    n = len(rho)
    ids = np.array([f"H{i}" for i in range(n)])
    t = np.arange(n, dtype=float) * 10.0
    sd = np.full(n, 0.003)
    sig = np.tile(SIG, (n, 1))
    batch = batch or n
    for i in range(0, n, batch):
        chart.update(ids[i:i + batch], t[i:i + batch], np.full(len(ids[i:i + batch]), panel), rho[i:i + batch],
                     sd[i:i + batch], sig[i:i + batch])
    chart.finish()
    return chart


def test_a_knocked_sensor_is_flagged_sized_and_named_with_its_candidates():
    rng = np.random.default_rng(1)
    n, k, delta = 5000, 3000, 0.025  # L3 knocked by 25 um at hole 3000
    rho = rng.normal(0, 0.003, n) + 0.001  # a level from the calibration's small errors
    rho[k:] += SIG[2] * delta
    chart = _feed(CusumChart("C1", SENSORS), rho)
    assert len(chart.alarms) == 1
    a = chart.alarms[0]
    at = int(a.hole_id[1:])
    assert k <= at <= k + 20  # 3.6 scales: flagged within a few holes
    assert abs(int(a.start_hole_id[1:]) - k) <= 10
    assert a.sensor_shift_um["L3"] == pytest.approx(25.0, abs=2.0)
    assert a.sensor_shift_um["L2"] == pytest.approx(-25.0, abs=2.0)  # one redundant reading: any sensor
    assert a.advice == "recalibrate"


def test_a_slow_drift_is_flagged_soon_after_it_reaches_the_detectable_size():
    rng = np.random.default_rng(2)
    n = 20000
    rate = 0.010 / 10000  # 10 um per 10 000 holes on L1
    rho = rng.normal(0, 0.003, n)
    start = 2000
    drift = np.clip(np.arange(n) - start, 0, None) * rate
    rho += SIG[0] * drift
    chart = _feed(CusumChart("C1", SENSORS), rho, batch=777)
    assert chart.alarms
    at = int(chart.alarms[0].hole_id[1:])
    detectable_at = start + DETECTABLE_SCALES * 0.003 / (abs(SIG[0]) * rate)  # residual reaches 1 scale
    assert at <= detectable_at + 3 * ARL_AT_DETECTABLE
    assert at > start


def test_in_control_million_holes_raise_alarms_at_the_stated_rate():
    """1e6 in-control holes: the expected count is 1e6 / ARL0 = 1; Poisson(1) exceeds 4 with p 0.4 %."""
    rng = np.random.default_rng(3)
    n = 1_000_000
    rho = rng.normal(0, 0.003, n)
    chart = CusumChart("C1", SENSORS)
    ids = np.char.add("H", np.arange(n).astype(str))
    t = np.arange(n, dtype=float)
    sig = np.broadcast_to(SIG, (n, 4))
    for i in range(0, n, 1 << 18):
        s = slice(i, i + (1 << 18))
        chart.update(ids[s], t[s], np.full(len(t[s]), "P"), rho[s], np.full(len(t[s]), 0.003), sig[s])
    assert len(chart.alarms) <= 4
    assert chart.charted >= n - BASELINE_HOLES * (1 + len(chart.alarms))


def test_batches_do_not_change_the_alarms():
    rng = np.random.default_rng(4)
    rho = rng.normal(0, 0.003, 6000)
    rho[2500:] += 0.012
    rho[4500:] -= 0.02
    whole = _feed(CusumChart("C1", SENSORS), rho)
    split = _feed(CusumChart("C1", SENSORS), rho, batch=313)
    assert [a.to_dict() for a in whole.alarms] == [a.to_dict() for a in split.alarms]
    assert len(whole.alarms) == 2


def test_a_gross_reading_alone_raises_no_alarm():
    rng = np.random.default_rng(5)
    rho = rng.normal(0, 0.003, 3000)
    rho[1500] += 5.0  # one hole 1600 scales off: clipped to CLIP before the sum
    assert not _feed(CusumChart("C1", SENSORS), rho).alarms


def test_the_chart_runs_on_across_panels_and_by_panel_takes_new_baselines():
    """By default a drift spread over many panels is seen; with by_panel, a panel whose shape moves
    the residual's level is not a drift."""
    rng = np.random.default_rng(6)
    rho = rng.normal(0, 0.003, 6000) + np.arange(6000) * (0.015 / 6000)  # 15 um of residual over 30 panels
    panels = np.repeat([f"P{i}" for i in range(30)], 200)
    chart = CusumChart("C1", SENSORS)
    chart.update(np.array([f"H{i}" for i in range(6000)]), np.arange(6000.0), panels, rho, np.full(6000, 0.003),
                 np.tile(SIG, (6000, 1)))
    assert chart.alarms
    chart = CusumChart("C1", SENSORS, by_panel=True)
    for panel, level in (("A", 0.0), ("B", 0.050), ("C", -0.030)):
        rho = rng.normal(level, 0.003, 2000)
        n = len(rho)
        chart.update(np.array([f"{panel}{i}" for i in range(n)]), np.arange(n, dtype=float), np.full(n, panel), rho,
                     np.full(n, 0.003), np.tile(SIG, (n, 1)))
    assert not chart.alarms


def _segments(series):
    """The series' runs between breaks (NaN statistic): list of (m, 2) arrays."""
    a = np.array(series, float)
    cut = np.flatnonzero(np.isnan(a[:, 1]))
    runs = [r[~np.isnan(r[:, 1])] for r in np.split(a, cut)]
    return [r for r in runs if len(r)]


@pytest.mark.parametrize("batch", [None, 777])
def test_the_thinned_series_keeps_every_extreme_the_alarm_and_breaks_at_the_new_baseline(batch):
    """The plotted series, thinned to a few hundred points, keeps the chart's maximum and minimum
    between re-basings (the alarm point itself, above h) and their ends, and breaks (a NaN) where
    the chart took a new baseline, so no line joins the alarm to the next baseline's first hole."""
    rng = np.random.default_rng(5)
    n, k = 20000, 12000
    rho = rng.normal(0, 0.003, n)
    rho[k:] += SIG[2] * 0.015
    full = _feed(CusumChart("C1", SENSORS, keep=10 ** 9), rho, batch)
    thin = _feed(CusumChart("C1", SENSORS, keep=150), rho, batch)
    assert len(full.alarms) == len(thin.alarms) == 1
    assert len(thin.series) <= 4 * 150 + 4
    a = thin.alarms[0]
    whole, shown = _segments(full.series), _segments(thin.series)
    assert len(whole) == len(shown) == 2  # before the alarm, after the new baseline
    for w, s in zip(whole, shown):
        assert s[:, 1].max() == w[:, 1].max() and s[:, 1].min() == w[:, 1].min()
        assert s[0, 0] == w[0, 0] and s[-1, 0] == w[-1, 0]  # the segment's ends
        assert np.all(np.diff(s[:, 0]) > 0)
    assert shown[0][-1, 0] == a.time_s and shown[0][-1, 1] > CUSUM_H  # the crossing is drawn
    assert shown[1][0, 0] > a.time_s + (BASELINE_HOLES - 1) * 10.0  # after the baseline's holes


class _LoopChart(CusumChart):
    """The plotted series thinned one bin at a time in Python (the M4 rule as first written): the
    oracle of the vectorised bins."""

    def __init__(self, *args, **kw):
        self._loop = []
        super().__init__(*args, **kw)

    def _restart(self, segment):
        super()._restart(segment)
        if self._loop and self._loop[-1] is not None:
            self._loop.append(None)

    def _record(self, t, stat):
        def m4(pts):
            s = [p[1] for p in pts]
            return tuple(pts[i] for i in sorted({0, int(np.argmin(s)), int(np.argmax(s)), len(pts) - 1}))

        w = self._stride
        self._loop += [m4(list(zip(t[i:i + w].tolist(), stat[i:i + w].tolist()))) for i in range(0, len(t), w)]
        while sum(b is not None for b in self._loop) > self.keep:
            out, run = [], []
            for b in [*self._loop, None]:
                if b is None:
                    out += [m4([p for q in run[i:i + 2] for p in q]) for i in range(0, len(run), 2)] + [None]
                    run = []
                else:
                    run.append(b)
            self._loop, self._stride = out[:-1], self._stride * 2

    @property
    def series(self):
        out = []
        for b in self._loop:
            out.extend([(out[-1][0], float("nan"))] if b is None else b)
        return out


@pytest.mark.parametrize("keep, batch, by_panel", [(3, None, False), (40, 777, True), (150, 1234, False)])
def test_the_vectorised_series_is_the_per_bin_rule_point_for_point(keep, batch, by_panel):
    """The bins thinned with numpy give the same points as the rule applied bin by bin, ties
    included (a residual rounded to 1 µm: the sums hit 0 and repeat often), across alarms and panels."""
    rng = np.random.default_rng(keep)
    n = 9000
    rho = np.round(rng.normal(0, 0.003, n), 3)
    rho[5000:] += 0.01
    panels = np.repeat(["P1", "P2", "P3"], n // 3)
    charts = []
    for cls in (CusumChart, _LoopChart):
        chart, b = cls("C1", SENSORS, keep=keep, by_panel=by_panel), batch or n
        t = np.floor(np.arange(n) / 2) * 10.0  # two holes a time stamp
        for i in range(0, n, b):
            chart.update(np.array([f"H{j}" for j in range(i, min(i + b, n))]), t[i:i + b], panels[i:i + b],
                         rho[i:i + b], np.full(len(rho[i:i + b]), 0.003), np.tile(SIG, (len(rho[i:i + b]), 1)))
        chart.finish()
        charts.append(chart)
    new, old = (np.array(c.series, float) for c in charts)
    assert len(charts[0].alarms) >= 1 and charts[0].alarms == charts[1].alarms
    assert new.shape == old.shape and np.array_equal(new, old, equal_nan=True)
