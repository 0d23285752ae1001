"""metrology.io.arrays: the numpy <-> Arrow conversions by buffers give what pyarrow's own calls give, and
``metro measure``'s path through a batch imports no pandas."""

import subprocess
import sys

import numpy as np
import pyarrow as pa
import pytest

from metrology.io.arrays import from_numpy, strings, to_numpy


def _arrow_same(a, b):
    assert a.type == b.type and len(a) == len(b) and a.null_count == b.null_count
    assert a.is_null().to_pylist() == b.is_null().to_pylist()
    if a.null_count == 0:
        _same(a.to_numpy(zero_copy_only=False), b.to_numpy(zero_copy_only=False))
    else:  # NaN is not equal to itself in Arrow's equals: the values compared with NaN equal
        _same(np.asarray(a.to_numpy(zero_copy_only=False), float), np.asarray(b.to_numpy(zero_copy_only=False), float))


def _same(a, b):
    assert a.dtype == b.dtype
    assert np.array_equal(a, b, equal_nan=a.dtype.kind in "fc")


@pytest.mark.parametrize("arrow", [
    pa.array([1.5, None, -2.0, np.nan, 4.0, None, 7.0, 8.0, 9.0, 10.0], pa.float64()),
    pa.array(np.arange(11, dtype=np.int64)),
    pa.array([3, None, 5, 7, 11, 13, None, 1, 2], pa.int64()),
    pa.array(np.arange(12, dtype=np.int8)),
    pa.array([True, False, True, True, False, False, True, False, True, True, False]),
    pa.array(np.arange(10, dtype=np.int64) * 1000003, pa.timestamp("us", tz="UTC")),
])
def test_to_numpy_is_pyarrows(arrow):
    for a in (arrow, arrow.slice(3), arrow.slice(1, 5), pa.chunked_array([arrow.slice(0, 4), arrow.slice(5)]),
              pa.chunked_array([], arrow.type)):
        _same(to_numpy(a), a.to_numpy(zero_copy_only=False))


def test_to_numpy_writable_copy():
    a = pa.array(np.arange(5.0))
    x = to_numpy(a)
    x[0] = 99.0
    assert a[0].as_py() == 0.0


@pytest.mark.parametrize("x", [np.array([1.0, np.nan, 3.0, -0.0, np.inf] * 3), np.arange(9, dtype=np.int64),
                               np.arange(9, dtype=np.int8), np.arange(9, dtype=np.int32),
                               np.array([True, False, True] * 5)])
def test_from_numpy_is_pyarrows(x):
    _arrow_same(from_numpy(x), pa.array(x))
    _arrow_same(from_numpy(x, nan_is_null=True), pa.array(x, from_pandas=True))
    strided = np.stack([x, x], 1)[:, 1]
    _arrow_same(from_numpy(strided), pa.array(x))


def test_from_numpy_owns_its_memory_and_times():
    x = np.arange(4.0)
    a = from_numpy(x)
    x[:] = -1
    assert a.to_pylist() == [0.0, 1.0, 2.0, 3.0]
    t = pa.timestamp("us", tz="UTC")
    assert from_numpy(np.arange(3, dtype=np.int64), t).equals(pa.array(np.arange(3), t))
    with pytest.raises(TypeError):
        from_numpy(np.arange(3, dtype=np.float32))


def test_strings():
    values = ["", "fails", "été", "as measured: angle - U95 > tolerance"]
    assert strings(values).equals(pa.array(values, pa.string()))
    assert strings([]).equals(pa.array([], pa.string()))


def test_measure_imports_no_pandas(tmp_path):
    """A log measured into Parquet and CSV imports no pandas (0.35-0.4 s of CPU a process, for nothing)."""
    import pyarrow.parquet as pq

    from metrology.core.paper import TABLE6_NOMINAL, layout_from_table
    from metrology.io.layout import save_layout
    from metrology.sim.forward.log import simulate_log
    from metrology.sim.forward.log_spec import LogSpec
    from metrology.sim.forward.log_write import log_table
    from metrology.sim.forward.panels import make_panel

    lay = layout_from_table(TABLE6_NOMINAL, noise_mm=0.003)
    lay = lay.with_params(lay.zero, lay.direction, range_mm=[[30.0, 70.0]] * 4)
    save_layout(lay, tmp_path / "lay.toml")
    spec = LogSpec(true_layout=lay, cell_layout=lay, panel=make_panel("flat"))
    pq.write_table(log_table(next(simulate_log(spec, 3, 300))), tmp_path / "log.parquet")
    code = f"""
import sys
from metrology.jobs.measure import MeasureOptions, measure_files
for out in ("out.parquet", "out.csv"):
    measure_files(r"{tmp_path}/log.parquet", r"{tmp_path}/lay.toml", MeasureOptions(out=r"{tmp_path}/" + out))
print("pandas" in sys.modules)
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "out.parquet").exists() and (tmp_path / "out.csv").exists()
    assert r.stdout.strip() == "False"
