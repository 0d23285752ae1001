"""The datum check's false-alarm rate on flat datums scanned without fault (issue 30, item 6).

    python benchmarks/study_datum_null.py [--nulls 200] [--seed 78]

Null cases of the forward simulator (``draw_case(rng, "none")``: a flat datum, its tracker cloud
passed as ``--plane``, nothing wrong), loaded as ``metro diagnose`` loads them. For each, the
check :func:`metrology.diagnosis.decide.check_datum` makes when no cause is named: the readings'
``plane_form`` (the base model plus the quadratic form) against the cloud's form under the spots
(:func:`metrology.diagnosis.datum.form_agreement`). Printed: how often it says "disagrees"
(``p < alpha_form`` = 0.01) and how often ``p < 0.05``, with 95 % Clopper-Pearson intervals. This
is the path of every null the diagnosis names nothing on (almost all); the full path, the whole
diagnosis, is counted by ``study_blind.py`` (``datum check 'disagrees' on flat datums``).
"""

from __future__ import annotations

import argparse
import tempfile
import time

import _one_blas_thread  # noqa: F401  (first: one BLAS thread; same directory)
import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nulls", type=int, default=200)
    ap.add_argument("--seed", type=int, default=78)
    a = ap.parse_args(argv)
    from study_blind import clopper_pearson

    from metrology.core.effects import PlaneForm
    from metrology.diagnosis.datum import form_agreement
    from metrology.diagnosis.decide import base_analysis
    from metrology.diagnosis.fit import FitData, fit_any
    from metrology.diagnosis.thresholds import THRESHOLDS
    from metrology.calibration.sanity import load_checked
    from metrology.sim.forward import draw_case, write_case

    ps = []
    t0 = time.time()
    for i in range(a.nulls):
        case = draw_case(np.random.default_rng([a.seed, 0, 0, i]), "none")
        with tempfile.TemporaryDirectory() as d:
            paths = write_case(case, d)
            ds = load_checked(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"])
        b = base_analysis(ds, 5)
        pf = fit_any(FitData(ds.layout, ds.obs, b.cov, b.sigma), (PlaneForm((), names=ds.layout.names),), b.theta0)
        ps.append(form_agreement(b.datum, pf).p)
    ps = np.array(ps)
    for level in (THRESHOLDS["alpha_form"], 0.05):
        k = int(np.sum(ps < level))
        lo, hi = clopper_pearson(k, len(ps))
        print(f"p < {level:g}: {k}/{len(ps)} ({100 * k / len(ps):.1f} %, 95 % CP [{100 * lo:.1f}, {100 * hi:.1f}] %)")
    print(f"wall time {time.time() - t0:.0f} s for {len(ps)} nulls")


if __name__ == "__main__":
    main()
