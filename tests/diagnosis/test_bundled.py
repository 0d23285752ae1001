"""`metro diagnose` on the README's worked example (the bundled measured data set)."""

from __future__ import annotations

import json
from pathlib import Path

import metrology

MEASURED = Path(metrology.__file__).parent / "data" / "measured"


def test_readme_example_names_the_tracker_noise_at_its_size():
    # fixtures/make_measured.py writes the poses with the tracker's noise: 5 um per axis in
    # position and 20 urad in rotation, 3 um reading noise, 14 poses with blank readings (5 of
    # them with two readings). This crashed ('Singular matrix') and then reported 7.7 mm.
    from typer.testing import CliRunner

    from cli.main import app

    r = CliRunner().invoke(app, ["diagnose", str(MEASURED / "calibration.csv"), "--plane", str(MEASURED / "plane.json"),
                                 "--layout", str(MEASURED / "nominal.toml"), "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.output)
    assert out["cause"] == "pose_error"
    sig = out["causes"][0]["params"]["sigma_mm"]
    assert 0.0 < sig["stderr"] < 0.003
    assert abs(sig["value"] - 0.005) < 3 * sig["stderr"]  # the offset along the normal: 5 um
