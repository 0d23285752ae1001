"""Without the pose and with the cell's convention not stated, a 4-sensor head's redundant reading cannot confirm the
convention: it admits an alias spin (metrology.measure.spin.SPIN_ALIAS_SHARE). On a perturbed head (not the symmetric
nominal, where the alias is harmless) drawn by the forward simulator with a free spin, the holes left on the
convention must hold their U95, and the holes the alias sent to every spin say so with the fix."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.io.data import data_path
from metrology.io.layout import load_layout
from metrology.sim.forward import perturb_layout
from metrology.sim.forward.log import simulate_cell
from metrology.sim.forward.log_spec import LogSpec
from metrology.sim.forward.panels import make_panel
from tests.measure.panel_fixtures import panel_mesh


def _free_spin(stated_deg=None, spin_deg=180.0, holes=120, seed=49, panel=("cylinder", 500.0), sensors=None, span=60.0):
    """``(batch, covered (N,) bool, true spin (N,) rad)``: a perturbed Table 6 head (its ``sensors``, all if None) on
    a ``panel``'s crest (a cylinder's axis along x; ``|x| <= span`` mm), the spin uniform within +-spin_deg per hole,
    measured with its true layout and the CAD, no pose."""
    from dataclasses import replace

    from metrology.jobs.measure_panel import footprint_mm, panel_hole_surfaces
    from metrology.measure.holes import Settings, measure_batch
    from metrology.measure.panel import HoleTable
    from metrology.panel.mesh import Panel
    from metrology.sim.forward.holes import HoleTable as SimTable
    from metrology.sim.forward.log_write import log_table

    rng = np.random.default_rng(seed)
    lay = perturb_layout(rng, load_layout(data_path("measured/nominal.toml")))
    lay = lay if sensors is None else lay.subset(list(sensors))
    panel = make_panel(panel[0], panel[1], axis=(1.0, 0.0, 0.0)) if panel[0] == "cylinder" else make_panel(*panel)
    P = np.zeros((holes, 3))
    P[:, 0] = np.linspace(-span, span, holes)
    P[:, 2] = panel.height(P[:, 0], P[:, 1])
    feed = -panel.normal_at(P)
    ids = tuple(f"H{i}" for i in range(holes))
    spins = rng.uniform(-1.0, 1.0, holes) * np.radians(spin_deg)
    spec = LogSpec(lay, lay, panel, table=SimTable("t", ids, P, feed), resolution_mm=0.0,
                   spin_path=lambda h: spins[np.asarray(h) % holes])
    ch = next(simulate_cell(spec, seed, 0, holes, chunk_holes=holes))
    log = log_table(ch)
    log = log.drop_columns([c for c in log.column_names if c.startswith("pose_")])
    surf = panel_hole_surfaces(Panel(panel_mesh(panel, half_mm=120.0, step_mm=2.0)), HoleTable(ids, P, feed, "holes"),
                               footprint_mm(lay), 0.5, 0.0, np.radians(2.0 if stated_deg is None else stated_deg))
    surf = replace(surf, spin_stated=stated_deg is not None)
    b = measure_batch(lay, log, Settings(surfaces=surf))
    U = np.radians(b.columns.column("U95_angle_deg").to_numpy(zero_copy_only=False).astype(float))
    return b, np.abs(b.angle_before - ch.true_angle) <= U, spins


def test_a_free_spin_on_a_perturbed_head_without_a_stated_convention_is_judged_over_every_spin():
    b, covered, spins = _free_spin()
    far = np.abs((spins + np.pi / 2) % np.pi - np.pi / 2) > np.radians(2.0)  # beyond the convention, mod 180
    assert np.isfinite(b.angle_before).all()  # every hole judged, none refused for the spin
    # the holes left on the convention hold U95 (54.6 % before the rule: the alias's holes passed as the convention's)
    on = b.on_convention
    assert (~covered[on & far]).sum() <= 1, (on.sum(), (on & far).sum(), covered[on & far].mean())
    assert covered.mean() >= 0.93, covered.mean()
    reasons = b.columns.column("reason").to_pylist()
    alias = [r for r, f in zip(reasons, b.spin_free) if f and "cannot tell it from a spin of" in r]
    assert alias and all("--spin-deg" in r and "commanded pose" in r for r in alias)


@pytest.mark.parametrize("stated", [None, 2.0])
def test_a_cell_that_keeps_its_convention_keeps_it_where_it_is_stated(stated):
    """The spin within +-2 deg: stated, the convention is kept (the spin read); unstated, the perturbed head's alias
    sends the holes to every spin (the price of not stating it), each covered."""
    b, covered, _ = _free_spin(stated, spin_deg=2.0, holes=60)
    assert covered.mean() >= 0.93, covered.mean()
    if stated:
        assert b.on_convention.all() and not b.spin_free.any()
    else:
        assert b.spin_free.mean() > 0.5, b.spin_free.mean()


@pytest.mark.parametrize("panel,sensors", [(("sphere", 50.0), None), (("sphere", 50.0), ("L1", "L2", "L3")),
                                           (("cylinder", 50.0), None)])
def test_holes_judged_over_every_spin_keep_the_cad_beyond_second_order_at_a_tight_radius(panel, sensors):
    """R 50 under Table 6: a fit over every spin without the CAD beyond second order tilted the normal on a sphere
    0.12-0.20 deg against a U95 of 0.02 deg (no deviatoric part to cover it), and on a cylinder its misfit was taken
    for a gross reading (19 % of a free spin's holes not measured): metrology.measure.spin_free. 3 sensors with nothing
    stated: every hole judged over every spin; 4 sensors, a free spin: the holes the reading refutes or cannot tell
    from an alias."""
    b, covered, _ = _free_spin(spin_deg=180.0, holes=80, seed=6111, panel=panel, sensors=sensors,
                               span=12.0 if panel[0] == "sphere" else 60.0)
    judged = np.isfinite(b.angle_before)
    assert judged.all(), [r for r, j in zip(b.columns.column("reason").to_pylist(), judged) if not j][:3]
    free = b.spin_free if sensors is not None else np.array(
        ["covers every spin" in (r or "") for r in b.columns.column("reason").to_pylist()])
    if sensors is not None:
        assert free.all()
    assert covered[free].mean() >= 0.9 if free.sum() >= 10 else (~covered[free]).sum() <= 1, (free.sum(), covered[free])
    assert covered.mean() >= 0.93, covered.mean()
