"""``metro normals`` with a layout's head terms (metrology.panel.head_terms): the true head's terms drawn
into the ray-cast readings by the forward simulator's physics (metrology.sim.head_terms), the
estimating layout's removed before each normal; a term needing the temperature is refused."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from typer.testing import CliRunner

from metrology.core.effects import Drift, Incidence, Scale
from metrology.core.effects.terms import HeadTerms
from metrology.core.layout import SensorLayout
from metrology.core.paper import table6_layouts
from metrology.io.layout import save_layout
from metrology.panel.surfaces import ParametricSurface, panel_mesh, write_binary_stl


def _simple():
    nom, _ = table6_layouts()
    cov = np.diag(np.tile([0.002 ** 2] * 3 + [np.radians(0.005) ** 2] * 2, 4))
    return SensorLayout(nom.names, nom.zero, nom.direction, [0.003] * 4, [[20, 80]] * 4, None, None, None, cov)


def _with(layout, comps):
    k = sum(c.n_params for c in comps)
    return replace(layout, effects=HeadTerms(tuple(comps), np.eye(k) * 1e-10, np.zeros((20, k))))


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("normals_terms")
    surf = ParametricSurface("cylinder", 800.0)
    write_binary_stl(panel_mesh(surf, 100, 100, 1.0, 20.0), d / "cyl.stl", surf.tag)
    simple = _simple()
    names = simple.names
    ext = _with(simple, (Scale((1,), [0.01], np.array([1e-4]), names),
                         Incidence((3,), [0.08], np.array([1e-3]), names)))
    save_layout(simple, d / "simple.toml")
    save_layout(ext, d / "ext.toml")
    save_layout(_with(simple, (Drift((2,), [0.003], np.array([1e-4]), names, variable="temp", ref=20.0),)),
                d / "drift.toml")
    return d


def _plane_error(files, layout, true=None):
    from cli.main import app

    args = ["normals", files / "cyl.stl", "--layout", files / layout, "--grid", "45", "--no-loop", "--seed", "4",
            "--tilt-deg", "4", "--json"] + ([] if true is None else ["--true-layout", files / true])
    r = CliRunner().invoke(app, [str(a) for a in args])
    assert r.exit_code in (0, 1), r.output
    s = json.loads(r.stdout)
    return s["plane"]["mean_deg"], s["plane"]["n"]


def test_normals_removes_the_terms_of_the_head_it_draws(files):
    ref, n = _plane_error(files, "simple.toml")
    ext, n_ext = _plane_error(files, "ext.toml")  # the head drawn with the terms, the same terms removed
    blind, _ = _plane_error(files, "simple.toml", true="ext.toml")  # the same head measured by the simple model
    assert n == n_ext > 5
    assert blind > 3 * ref  # the terms are there: a 1 % gain on L2 tilts every normal
    assert abs(ext - ref) < 0.05 * (blind - ref)


def test_normals_refuses_a_temperature_coefficient_naming_the_column(files):
    from cli.main import app

    r = CliRunner().invoke(app, ["normals", str(files / "cyl.stl"), "--layout", str(files / "drift.toml"),
                                 "--grid", "30"])
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1
    assert "temperature_c" in r.output and "drift.L3@temp" in r.output
