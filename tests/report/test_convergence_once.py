"""``calibrate --report --plot`` draws the convergence figure twice (the page, the plot file): its
numbers, one refit per pose count, are computed once a report (issue 51 item 15)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from metrology.calibration.calibrate import calibrate_dataset
from metrology.calibration.sanity import load_checked
from metrology.sim.forward import draw_case, write_case


def test_the_batch_convergence_is_computed_once_a_report(tmp_path, monkeypatch):
    import metrology.calibration.convergence as cc
    import metrology.report.calibration as rc
    from metrology.report.style import close

    paths = write_case(draw_case(np.random.default_rng([51, 15]), "none", n_poses=12), tmp_path)
    report = calibrate_dataset(load_checked(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"]))
    calls = []
    real = cc.batch_convergence
    monkeypatch.setattr(cc, "batch_convergence", lambda *a: calls.append(a) or real(*a))
    first = report.convergence
    for _ in range(2):  # the page's figure and the plot file's
        close(rc.convergence_figure(report))
    assert len(calls) == 1 and report.convergence is first
    # the numbers are batch_convergence's own
    for (k, th, se), (k2, th2, se2) in zip(first, real(*calls[0])):
        assert np.array_equal(k, k2) and np.array_equal(th, th2) and np.array_equal(se, se2)
    # another report, even an equal copy, is computed afresh
    other = replace(report)
    _ = other.convergence
    assert len(calls) == 2
