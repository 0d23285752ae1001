"""measure --panel's batched path (each hole_id's surface once, every hole of a batch in one set of
array operations) gives every hole what it gets measured on its own (to the last bits: numpy's
einsum sums a batch of one in another order), and the same bytes wherever it sits in the batch: a
forward-simulated wing log (simulate-log --panel wing.stl --points wing.holes.csv, the commanded pose in the log)."""

import dataclasses

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.data import data_path
from metrology.io.layout import load_layout
from metrology.jobs.measure_panel import hole_surfaces
from metrology.measure.holes import Settings, measure_batch

TABLE6 = str(data_path("measured", "nominal.toml"))


@pytest.fixture(scope="module")
def wing(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("wing")
    log = tmp / "wing.parquet"
    r = CliRunner().invoke(app, ["simulate-log", "--panel", str(data_path("panels", "wing.stl")), "--points",
                                 str(data_path("panels", "wing.holes.csv")), "--holes", "120", "--seed", "4",
                                 "--layout", TABLE6, "--out", str(log), "--no-truth"])
    assert r.exit_code == 0, r.output
    layout = load_layout(TABLE6)
    surf = hole_surfaces(layout, str(data_path("panels", "wing.stl")), str(data_path("panels", "wing.holes.csv")),
                     0.5, 0.0, 0.0)
    return layout, pq.read_table(log), dataclasses.replace(Settings(), surfaces=surf)


def _columns(batch):
    return {k: batch.columns.column(k).to_pylist() for k in batch.columns.column_names}


def _same(a, b, rtol=0.0):
    assert a.keys() == b.keys()
    for k in a:
        x, y = a[k], b[k]
        if x and isinstance(next((v for v in x if v is not None), None), float):
            xa = np.array([np.nan if v is None else v for v in x])
            ya = np.array([np.nan if v is None else v for v in y])
            if rtol == 0.0:
                assert xa.tobytes() == ya.tobytes(), k  # the same bytes, NaN where null
            else:
                np.testing.assert_allclose(xa, ya, rtol=rtol, atol=1e-15, err_msg=k)
        else:
            assert x == y, k


def test_the_batch_gives_each_hole_what_it_gets_on_its_own(wing):
    layout, table, settings = wing
    assert "pose_rx_deg" in table.column_names
    assert "cad_offset_mm" in measure_batch(layout, table[:2], settings).columns.column_names
    whole = _columns(measure_batch(layout, table, settings))
    one = [_columns(measure_batch(layout, table.slice(i, 1), settings)) for i in range(table.num_rows)]
    _same(whole, {k: [v for o in one for v in o[k]] for k in whole}, rtol=1e-12)
    assert np.isfinite(np.array(whole["correction_deg"], float)).all()
    assert np.nanmax(np.abs(np.array(whole["correction_deg"], float))) > 0  # the panel's curvature was used


def test_the_order_of_the_log_does_not_change_a_hole(wing):
    layout, table, settings = wing
    order = np.random.default_rng(7).permutation(table.num_rows)
    whole = _columns(measure_batch(layout, table, settings))
    mixed = _columns(measure_batch(layout, table.take(pa.array(order)), settings))
    _same({k: [v[i] for i in order] for k, v in whole.items()}, mixed)
