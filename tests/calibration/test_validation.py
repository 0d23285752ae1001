"""ValidationReport: its statistics against numpy's nan-aware reductions, and its printed table."""

import numpy as np

from metrology.calibration import ValidationReport
from metrology.report.calibration import validation_text


def _report(rng, p=40, n_sensors=4):
    dev = np.abs(rng.normal(0.0, 1e-3, size=(2, p)))
    nread = np.full(p, n_sensors)
    nread[[3, 17]] = 2  # too few readings: no normal
    nread[[5, 9, 30]] = 3  # one reading missing: normal from the rest
    dev[:, nread < 3] = np.nan
    return ValidationReport(tuple(f"P{i}" for i in range(p)), ("layout_before", "layout"), dev, nread, n_sensors,
                            {"layout": "cal.toml"})


def test_stats_deg_matches_nan_aware_numpy(rng):
    rep = _report(rng)
    for k in range(2):
        a = np.rad2deg(rep.deviation[k])
        s = rep.stats_deg(k)
        assert list(s) == ["max_deg", "mean_deg", "std_deg", "n_poses"]  # the JSON key order
        assert s["n_poses"] == 38
        assert s["max_deg"] == np.nanmax(a)
        assert np.isclose(s["mean_deg"], np.nanmean(a), rtol=1e-12)
        assert np.isclose(s["std_deg"], np.nanstd(a, ddof=1), rtol=1e-12)


def test_to_dict_carries_the_stats_and_every_pose(rng):
    rep = _report(rng)
    d = rep.to_dict()
    assert d["n_poses"] == 40 and list(d["layouts"]) == ["layout_before", "layout"]
    for k, lab in enumerate(rep.labels):
        assert {key: d["layouts"][lab][key] for key in rep.stats_deg(k)} == rep.stats_deg(k)
        assert np.array_equal(d["layouts"][lab]["deviation_deg"], np.rad2deg(rep.deviation[k]), equal_nan=True)


def test_validation_text_has_one_row_per_layout_and_notes_missing_readings(rng):
    rep = _report(rng)
    lines = validation_text(rep).splitlines()
    assert lines[0].split()[:2] == ["layout", "max"]
    # the layouts in the user's words (the file given, its role), as the HTML report and figure
    for k, words in enumerate(("before", "cal.toml (validated)")):
        assert lines[1 + k].startswith(words + "  ")
        row = lines[1 + k][len(words):].split()
        assert abs(float(row[0]) - rep.stats_deg(k)["max_deg"]) <= 5e-5 and row[3] == "38"
    assert lines[2].endswith("cal.toml")
    assert lines[3].startswith("2 pose(s) with fewer than 3 readings")
    assert lines[4].startswith("3 pose(s) with a missing reading")
