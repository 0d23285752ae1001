"""Without the commanded pose the head's spin is read from the redundant reading (metrology.measure.spin):
on a tight radius drawn by the forward simulator, the no-pose angles are as good as the posed ones."""

from __future__ import annotations

import numpy as np

from metrology.io.data import data_path
from metrology.io.layout import load_layout
from metrology.sim.forward.log import simulate_cell
from metrology.sim.forward.log_spec import LogSpec
from metrology.sim.forward.panels import make_panel
from tests.measure.panel_fixtures import panel_mesh


def test_the_spin_read_from_the_redundant_reading_gives_the_posed_accuracy_on_r50():
    from metrology.jobs.measure_panel import footprint_mm, panel_hole_surfaces
    from metrology.measure.holes import Settings, measure_batch
    from metrology.measure.panel import HoleTable
    from metrology.panel.mesh import Panel
    from metrology.sim.forward.holes import HoleTable as SimTable
    from metrology.sim.forward.log_write import log_table

    lay = load_layout(data_path("measured/nominal.toml"))
    panel = make_panel("cylinder", 50.0, axis=(1.0, 0.0, 0.0))
    m = 48
    P = np.zeros((m, 3))
    P[:, 0] = np.linspace(-60.0, 60.0, m)
    feed = np.tile([0.0, 0.0, -1.0], (m, 1))
    ids = tuple(f"H{i}" for i in range(m))
    spec = LogSpec(lay, lay, panel, table=SimTable("t", ids, P, feed), spin_rad=np.radians(2.0), resolution_mm=0.0)
    ch = next(simulate_cell(spec, 11, 0, m, chunk_holes=m))
    log = log_table(ch)
    mesh = panel_mesh(panel, half_mm=100.0, step_mm=2.0)
    table = HoleTable(ids, P, feed, "holes")
    err = {}
    for pose in (True, False):
        lg = log if pose else log.drop_columns([c for c in log.column_names if c.startswith("pose_")])
        surf = panel_hole_surfaces(Panel(mesh), table, footprint_mm(lay), 0.5, 0.0, 0.0 if pose else np.radians(2.0))
        b = measure_batch(lay, lg, Settings(surfaces=surf))
        U = np.radians(b.columns.column("U95_angle_deg").to_numpy(zero_copy_only=False).astype(float))
        e = np.abs(b.angle_before - ch.true_angle)
        assert np.isfinite(e).all() and (e <= 1.5 * U).all()  # every hole judged, none far outside its U95
        err[pose] = (np.median(e), np.median(U))
        if not pose:
            assert b.on_convention.all() and not b.spin_free.any()
    # the spin's +-2 deg left as a doubt doubles the error and U95 here (issue 53); read, it is the pose's
    assert err[False][0] < 1.3 * err[True][0], err
    assert err[False][1] < 1.2 * err[True][1], err
