"""metro simulate keeps its poses in the sensors' range, or says so (issue 37 item 3): its
export is one the other commands accept."""

from pathlib import Path

import numpy as np
import pytest

from metrology.calibration.dataset import check
from metrology.io.export import read_export
from metrology.io.layout import load_layout
from metrology.jobs.simulate import simulate_files

DATA = Path(__file__).resolve().parents[2] / "metrology" / "data" / "measured"


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
@pytest.mark.parametrize("effect", [None, ("shift", "L2", 0.05)])
def test_bundled_files_give_an_export_in_range(tmp_path, seed, effect):
    name, sensor, size = effect if effect else (None, None, None)
    out = tmp_path / "s.csv"
    simulate_files(DATA / "truth.toml", DATA / "plane.json", out, name, sensor, size, seed=seed)
    layout = load_layout(DATA / "truth.toml")
    export = check(read_export(out), layout, str(out))  # raised "outside the sensor's range" before
    lo, hi = layout.range_mm[:, 0], layout.range_mm[:, 1]
    assert np.all((export.d >= lo) & (export.d <= hi))


def test_an_effect_that_leaves_the_range_is_refused(tmp_path):
    out = tmp_path / "s.csv"
    with pytest.raises(ValueError, match="range"):
        simulate_files(DATA / "truth.toml", DATA / "plane.json", out, "shift", "L2", 30.0, seed=0)
    assert not out.exists()
