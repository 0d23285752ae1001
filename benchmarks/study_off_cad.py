"""A panel formed off its CAD: what the Table 6 head's redundant reading sees, and what goes into the angle.

The forward simulator drills a sphere or a barrel of R 500 (holes within 40 mm of the crest); metro
measures it with the CAD's shape operator of R 560 (a spring-back), its form tolerance left at 0.
Per case: the share of holes named off their CAD (|panel_misfit_z| > 4), the median size named
(1/mm), the median error of the measured angle and the coverage of angle +- U95.

    python benchmarks/study_off_cad.py
"""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from metrology.io.data import data_path  # noqa: E402
from metrology.io.layout import load_layout  # noqa: E402
from metrology.measure.surface import PanelTerms, surface_hole_normals  # noqa: E402
from metrology.sim.forward.log import simulate_cell  # noqa: E402
from metrology.sim.forward.log_spec import LogSpec  # noqa: E402
from metrology.sim.forward.panels import make_panel  # noqa: E402


def main():
    lay = load_layout(data_path("measured", "nominal.toml"))
    print("| panel (R 500) | CAD | axis | holes named off CAD | median size named [1/mm] | median angle error [deg] | coverage |")
    print("|---|---|---|---|---|---|---|")
    for kind, R, Rc, ax in [("sphere", 500, 500, (0, 1, 0)), ("sphere", 500, 560, (0, 1, 0)),
                            ("cylinder", 500, 560, (0, 1, 0)), ("cylinder", 500, 560, (0.7071, 0.7071, 0))]:
        spec = LogSpec(lay, lay, make_panel(kind, R, axis=ax), resolution_mm=0.0, patch_half_mm=40)
        ch = next(simulate_cell(spec, 0, 0, 2000, 2000))
        ok = np.isfinite(ch.d).all(1)
        a = np.array(ax, float)
        c = np.array([-a[1], a[0], 0.0]) * [1, -1, -1]  # across the axis, in the TCS (spin 0, beams +z)
        K = np.diag([1.0, 1.0, 0.0]) / Rc if kind == "sphere" else np.outer(c, c) / Rc
        h, ex = surface_hole_normals(lay, ch.d[ok], np.broadcast_to(K, (ok.sum(), 3, 3)), PanelTerms(np.zeros(ok.sum())))
        err = np.abs(h.angle - ch.true_angle[ok])
        print(f"| {kind} | R {Rc} | {tuple(round(v, 3) for v in ax)} | {np.mean(np.abs(ex.panel_misfit_z) > 4):.0%} | "
              f"{np.median(ex.panel_misfit):.2g} | {np.degrees(np.median(err)):.4f} | {np.mean(err <= h.U95):.0%} |")


if __name__ == "__main__":
    main()
