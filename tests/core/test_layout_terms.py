"""A layout's head terms (metrology.core.effects.terms, io/layout): round trip and one-line refusals."""

import numpy as np
import pytest

from metrology.core.effects import Drift, Incidence, Nonlinearity, Scale
from metrology.core.effects.apply import correct_readings, covariates_for
from metrology.core.effects.terms import HeadTerms
from metrology.core.layout import SensorLayout
from metrology.core.paper import table6_layouts
from metrology.io.layout import layout_to_toml, load_layout, save_layout


def _layout():
    nom, _ = table6_layouts()
    names = nom.names
    comps = (Nonlinearity((0,), [0.01, 0.02], np.array([1e-3, 1e-3]), names),
             Scale((1,), [0.005], np.array([1e-4]), names),
             Drift((2,), [0.003], np.array([1e-4]), names, variable="temp", ref=20.5),
             Incidence((3,), [0.02], np.array([1e-3]), names))
    rng = np.random.default_rng(0)
    A = rng.normal(size=(25, 25)) * 1e-4
    full = A @ A.T
    return SensorLayout(names, nom.zero, nom.direction, [0.003] * 4, [[20, 80]] * 4, None, None,
                        HeadTerms(comps, full[20:, 20:], full[:20, 20:]), full[:20, :20])


def test_terms_round_trip_with_their_joint_covariance(tmp_path):
    lay = _layout()
    save_layout(lay, tmp_path / "l.toml")
    back = load_layout(tmp_path / "l.toml")
    assert back.effects.param_names == lay.effects.param_names
    np.testing.assert_allclose(back.effects.cov, lay.effects.cov, rtol=1e-8)
    np.testing.assert_allclose(back.effects.cross, lay.effects.cross, rtol=1e-8)
    np.testing.assert_allclose(back.covariance, lay.covariance, rtol=1e-8)
    assert back.effects.components[2].ref == 20.5
    sub = back.subset(["L1", "L2", "L4"])
    assert sub.effects.param_names == ("nonlinearity.L1.c2_mm", "nonlinearity.L1.c3_mm", "scale.L2.k", "incidence.L4.c_mm")
    assert sub.effects.cross.shape == (15, 4)


@pytest.mark.parametrize("old,new,msg", [
    ("[sensors.effects.scale]", "[sensors.effects.gain]", "unknown effect term 'gain' on sensor L2: known terms are scale, incidence"),
    ("k = 0.005\n", "k = 0.5\n", "effects.scale.k = 0.5 outside its physical range"),
    ("k_stderr = 0.0001\n", "", "effects.scale lacks k_stderr"),
    ('variable = "temp"', 'variable = "time"', "a layout carries a temperature coefficient"),
    ('"scale.L2.k", ', '', "has no covariance of the term parameter scale.L2.k"),
    ("c_mm = 0.02\n", "c_mm = 0.02\nbogus = 1\n", "unknown key(s) bogus"),
])
def test_bad_terms_are_one_line_errors_naming_file_and_sensor(tmp_path, old, new, msg):
    text = layout_to_toml(_layout())
    assert old in text
    bad = text.replace(old, new, 1)
    if old.startswith('"scale'):  # the covariance loses the row and column too
        import tomllib

        d = tomllib.loads(text)
        i = d["calibration"]["parameters"].index("scale.L2.k")
        cov = np.delete(np.delete(np.array(d["calibration"]["covariance"]), i, 0), i, 1)
        head, _ = bad.split("covariance = [")
        bad = head + "covariance = [\n" + "".join("  [" + ", ".join(f"{v:.9g}" for v in r) + "],\n" for r in cov) + "]\n"
    p = tmp_path / "bad.toml"
    p.write_text(bad)
    with pytest.raises(ValueError, match="bad.toml") as exc:
        load_layout(p)
    assert msg in str(exc.value) and "\n" not in str(exc.value)


def test_terms_without_any_covariance_are_refused(tmp_path):
    text = layout_to_toml(_layout())
    p = tmp_path / "nocov.toml"
    p.write_text(text.split("[calibration]")[0])
    with pytest.raises(ValueError, match="has no covariance"):
        load_layout(p)


def test_correction_inverts_the_terms_and_names_a_missing_temperature():
    lay = _layout()
    rng = np.random.default_rng(1)
    d0 = rng.uniform(30, 70, size=(50, 4))
    temp = rng.uniform(18, 24, 50)
    cos = rng.uniform(0.8, 1.0, size=(50, 4))
    cov = covariates_for(lay, 50, temp, cos)
    f = sum(c.evaluate(c.values, d0, cov) for c in lay.effects.components)
    out = correct_readings(lay.effects, d0 + f, cov)
    np.testing.assert_allclose(out.d, d0, atol=1e-10)
    assert out.jac.shape == (50, 4, 5)
    with pytest.raises(ValueError, match="temperature_c"):
        correct_readings(lay.effects, d0 + f, covariates_for(lay, 50, None, cos))


def test_a_calibration_row_naming_a_term_the_layout_lacks_is_refused(tmp_path):
    text = layout_to_toml(_layout()).replace('"incidence.L4.c_mm"', '"incidence.L9.c_mm"')
    p = tmp_path / "stray.toml"
    p.write_text(text)
    with pytest.raises(ValueError, match="has no covariance of the term parameter incidence.L4.c_mm"):
        load_layout(p)


@pytest.mark.parametrize("args", [
    ["plan", "--layout", "{lay}", "--plane", "{plane}", "--poses", "10"],
])
def test_commands_that_cannot_apply_terms_refuse_them_in_one_line(tmp_path, args):
    """Never measured silently with the simple model: exit 2, one line naming the terms."""
    from typer.testing import CliRunner

    from cli.main import app
    from metrology.io.data import DATA_DIR

    save_layout(_layout(), tmp_path / "ext.toml")
    sub = {"lay": str(tmp_path / "ext.toml"), "plane": str(DATA_DIR / "measured" / "plane.json"),
           "panel": str(DATA_DIR / "panel_cyl800.stl"), "tmp": str(tmp_path)}
    r = CliRunner().invoke(app, [a.format(**sub) for a in args])
    assert r.exit_code == 2, r.output
    assert "effect terms (nonlinearity.L1, scale.L2, drift.L3@temp, incidence.L4)" in r.output
    assert len(r.output.strip().splitlines()) == 1
