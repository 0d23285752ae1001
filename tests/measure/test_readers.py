"""Outputs any tool reads: simulate-log's folder and measure's partitioned output are hive datasets
that pyarrow.dataset, pyarrow.parquet.read_table, pandas.read_parquet and dask.dataframe.read_parquet
read as one table (one test per reader; pandas and Dask are not metro's dependencies: their tests
skip where they are missing and run in .ci/run's extras leg); simulate-log writes one Parquet
file; output folders of any name; a partition that disagrees with its folder's key."""

import json

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.layout import save_layout
from tests.measure.helpers import calibrated_layout

runner = CliRunner()
HOLES = 1200


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """simulate-log's folder (2 cells over 2 days) and metro measure's output folder of it."""
    root = tmp_path_factory.mktemp("readers")
    lay = root / "calibrated.toml"
    save_layout(calibrated_layout(), lay)
    r = runner.invoke(app, ["simulate-log", "--layout", str(lay), "--out", str(root / "log"), "--holes", str(HOLES),
                            "--cells", "2", "--holes-per-hour", "20", "--no-truth", "--seed", "4"])
    assert r.exit_code == 0, r.output
    assert len({p.parent for p in (root / "log").rglob("*.parquet")}) >= 4  # 2 cells x 2 days or more
    r = runner.invoke(app, ["measure", str(root / "log"), "--layout", str(lay), "--out", str(root / "out.one"),
                            "--json"])
    assert r.exit_code in (0, 1), r.output
    assert (root / "out.one").is_dir()  # a folder, whatever its name
    return root


def _check(cols: dict, hole_ids, cells, statuses=None):
    """One table of every hole: ``cell`` from the folder names, matching the holes' ids."""
    assert len(hole_ids) == HOLES and len(set(hole_ids)) == HOLES
    assert [h.split("-")[0] for h in hole_ids] == [str(c) for c in cells]
    if statuses is not None:
        assert set(statuses) <= {"conforms", "fails", "undecided", "not_measured"}


@pytest.mark.parametrize("which", ["log", "out.one"])
def test_pyarrow_dataset(made, which):
    import pyarrow.dataset as ds

    t = ds.dataset(made / which, format="parquet", partitioning="hive").to_table()
    _check(t, t["hole_id"].to_pylist(), t["cell"].to_pylist(), t["status"].to_pylist() if which != "log" else None)


@pytest.mark.parametrize("which", ["log", "out.one"])
def test_pyarrow_parquet_read_table(made, which):
    t = pq.read_table(made / which)  # failed before: "Field cell has incompatible types: string vs dictionary"
    _check(t, t["hole_id"].to_pylist(), t["cell"].to_pylist())


@pytest.mark.parametrize("which", ["log", "out.one"])
def test_pandas_read_parquet(made, which):
    pd = pytest.importorskip("pandas")
    df = pd.read_parquet(made / which)
    _check(df, df["hole_id"].tolist(), df["cell"].tolist())


@pytest.mark.parametrize("which", ["log", "out.one"])
def test_dask_dataframe_read_parquet(made, which):
    pytest.importorskip("pandas")
    dd = pytest.importorskip("dask.dataframe")
    df = dd.read_parquet(str(made / which)).compute()
    df = df.sort_values("hole_id")
    _check(df, df["hole_id"].tolist(), df["cell"].tolist())


def test_simulate_log_writes_one_parquet_file_that_measure_reads(tmp_path):
    lay = tmp_path / "calibrated.toml"
    save_layout(calibrated_layout(), lay)
    r = runner.invoke(app, ["simulate-log", "--layout", str(lay), "--out", str(tmp_path / "big.parquet"),
                            "--holes", "600", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["files"] == 1 and (tmp_path / "big.truth.parquet").is_file()
    t = pq.read_table(tmp_path / "big.parquet")
    assert t.num_rows == 600 and "cell" in t.column_names
    r = runner.invoke(app, ["measure", str(tmp_path / "big.parquet"), "--layout", str(lay), "--out",
                            str(tmp_path / "h.csv"), "--json"])
    assert r.exit_code in (0, 1), r.output
    assert json.loads(r.stdout)["holes"] == 600


def test_a_file_that_disagrees_with_its_folder_key_is_refused(made, tmp_path):
    log = tmp_path / "log"
    src = sorted((made / "log").rglob("*.parquet"))[0]
    d = log / src.parent.relative_to(made / "log")
    d.mkdir(parents=True)
    t = pq.read_table(src)
    t = t.append_column("cell", pa.array(["C9"] * t.num_rows))
    pq.write_table(t, d / src.name)
    r = runner.invoke(app, ["measure", str(log), "--layout", str(made / "calibrated.toml"), "--out",
                            str(tmp_path / "out")])
    assert r.exit_code == 2, r.output
    assert "cell = 'C9' disagrees with its folder's cell=C" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "out").exists()  # no manifest, no folder left by the failed run
