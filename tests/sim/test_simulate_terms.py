"""``metro simulate`` draws the head an extended layout describes (metrology.sim.synth with the layout's
terms as the forward simulator's physics): against the same seed without the terms, each reading
differs by its sensor's property and no other, and the JSON names the terms drawn."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
from typer.testing import CliRunner

from metrology.core.effects import Drift, Scale
from metrology.core.effects.terms import HeadTerms
from metrology.core.layout import SensorLayout
from metrology.core.paper import table6_layouts
from metrology.io.data import DATA_DIR
from metrology.io.export import read_export
from metrology.io.layout import save_layout

GAIN, RATE, REF = 0.008, 0.003, 20.0


def test_simulate_draws_the_layouts_terms(tmp_path):
    from cli.main import app

    nom, _ = table6_layouts()
    simple = SensorLayout(nom.names, nom.zero, nom.direction, [0.003] * 4, [[20, 80]] * 4)
    comps = (Scale((1,), [GAIN], np.array([1e-4]), nom.names),
             Drift((2,), [RATE], np.array([1e-4]), nom.names, variable="temp", ref=REF))
    ext = replace(simple, effects=HeadTerms(comps, np.eye(2) * 1e-10, np.zeros((20, 2))),
                  covariance=np.eye(20) * 1e-6)
    save_layout(simple, tmp_path / "simple.toml")
    save_layout(ext, tmp_path / "ext.toml")
    plane = DATA_DIR / "measured" / "plane.json"
    out = {}
    for name in ("simple", "ext"):
        r = CliRunner().invoke(app, ["simulate", "--layout", str(tmp_path / f"{name}.toml"), "--plane", str(plane),
                                     "--out", str(tmp_path / f"{name}.csv"), "--seed", "3", "--json"])
        assert r.exit_code == 0, r.output
        out[name] = (read_export(tmp_path / f"{name}.csv"), json.loads(r.stdout))
    a, b = out["simple"][0], out["ext"][0]
    np.testing.assert_array_equal(a.temp_c, b.temp_c)
    diff = b.d - a.d
    # a gain of the true distance (the simple run's reading, less its 3 um noise: 0.02 um of the term)
    np.testing.assert_allclose(diff[:, 1], GAIN * a.d[:, 1], atol=1e-4)
    np.testing.assert_allclose(diff[:, 2], RATE * (a.temp_c - REF), atol=3e-6)  # the warm-up temperature (as written)
    np.testing.assert_array_equal(diff[:, [0, 3]], 0.0)
    assert [t["label"] for t in out["ext"][1]["terms"]] == ["scale.L2", "drift.L3@temp"]
    assert "terms" not in out["simple"][1]
