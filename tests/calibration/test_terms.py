"""calibrate with a layout's head terms (metrology.calibration.terms): the joint fit, the datum's share."""

import numpy as np
from dataclasses import replace

from metrology.calibration.calibrate import calibrate_dataset
from metrology.calibration.dataset import load_dataset
from metrology.core.effects import Scale
from metrology.core.effects.terms import HeadTerms
from metrology.io.data import DATA_DIR
from metrology.io.layout import layout_to_toml, load_layout

M = DATA_DIR / "measured"


def test_a_term_the_data_do_not_have_comes_out_zero_and_the_joint_covariance_stays_psd(tmp_path):
    """The bundled run has no gain error: a scale term fitted with the sensors and the datum's scan
    covariance is within its uncertainty of zero, and the written layout (base, datum share, term)
    reads back (its covariance positive semi-definite)."""
    ds = load_dataset(M / "calibration.csv", M / "datum.ply", M / "nominal.toml")
    lay = ds.layout
    terms = HeadTerms((Scale((1,), [0.002], np.array([1e-3]), lay.names),), [[1e-6]], np.zeros((20, 1)))
    rep = calibrate_dataset(replace(ds, layout=replace(lay, effects=terms)))
    (t,) = rep.terms.to_dict()
    k, se = t["params"]["k"]["value"], t["params"]["k"]["stderr"]
    assert t["identified"] and abs(k) < 3 * se and se < 0.01
    assert rep.calibration.datum is not None
    p = tmp_path / "cal.toml"
    p.write_text(layout_to_toml(rep.layout))
    back = load_layout(p)
    assert back.effects.param_names == ("scale.L2.k",)
    full = np.block([[back.covariance, back.effects.cross], [back.effects.cross.T, back.effects.cov]])
    assert np.linalg.eigvalsh(full).min() > -1e-12 * np.abs(full).max()
