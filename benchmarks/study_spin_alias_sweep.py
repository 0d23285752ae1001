"""The spin's alias seen hole by hole (benchmarks/results/spin_convention_calibrated.md, "Why: the alias"): one
perturbed Table 6 head (the first of study_spin_convention_calibrated.py's, seed 49) on a cylinder R 500's crest,
the true spin stepped 0 to 177.5 deg by 2.5 deg (one hole each), the log without the pose measured with the head's
calibration and with its true layout: per hole accepted on the convention, the misfit's z, the error and U95 (deg).

    nice -n 10 python benchmarks/study_spin_alias_sweep.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import _one_blas_thread  # noqa: E402,F401


def main():
    from metrology.measure.holes import Settings, measure_batch
    from metrology.sim.forward import perturb_layout
    from metrology.sim.forward.panels import make_panel
    from study_measure import calibrate_head
    from study_tight_radii import all_heads, one_log

    nominal = all_heads(np.random.default_rng(49))["table6"]
    rng, rm = np.random.default_rng([49, 0]), np.array([30.0, 70.0])
    true = perturb_layout(rng, nominal)
    true = true.with_params(true.zero, true.direction, noise_mm=np.full(4, 0.005), range_mm=np.tile(rm, (4, 1)))
    cal = calibrate_head(rng, nominal, true, 0.005, rm, 60)
    panel = make_panel("cylinder", 500.0, axis=(1.0, 0.0, 0.0))
    m = 72
    spins = np.radians(np.arange(m) * 2.5)
    print("| layout | true spin deg | misfit z at the convention | error deg | U95 deg |\n|---|---|---|---|---|")
    for name, lay in (("calibration", cal), ("true", true)):
        ch, log, surf, *_ = one_log(np.random.default_rng(1), panel, true, lay, m, 2.0, pose=False, same=True,
                                    spin_deg=180.0, path=lambda h: spins[np.asarray(h) % m])
        b = measure_batch(lay, log, Settings(surfaces=surf))
        z = b.columns.column("panel_misfit_z").to_numpy(zero_copy_only=False).astype(float)
        U = b.columns.column("U95_angle_deg").to_numpy(zero_copy_only=False).astype(float)
        for i in np.flatnonzero(b.on_convention):
            print(f"| {name} | {np.degrees(spins[i]):.1f} | {z[i]:.2f} | {np.degrees(b.angle_before[i] - ch.true_angle[i]):+.4f} "
                  f"| {U[i]:.4f} |")


if __name__ == "__main__":
    main()
