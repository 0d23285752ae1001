"""One result schema whatever the log's format (issue 51, item 8): ``time`` a UTC timestamp, from a CSV, a
Parquet file (time in seconds) and a hive folder; metro's inputs (the commanded pose ``pose_*``,
``temperature_c``, the readings) stay in the log, not in the results (issue 49)."""

import numpy as np
import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq
from typer.testing import CliRunner

from cli.main import app
from metrology.io.layout import save_layout
from tests.measure.helpers import calibrated_layout, hole_log, write_log_csv

runner = CliRunner()
POSE = ("pose_rx_deg", "pose_ry_deg", "pose_rz_deg", "pose_x_mm", "pose_y_mm", "pose_z_mm")


def test_results_have_one_schema_for_csv_parquet_and_a_hive_folder(tmp_path):
    layout = tmp_path / "cal.toml"
    save_layout(calibrated_layout(), layout)
    cols, _, _ = hole_log(calibrated_layout(), n=60, seed=4, angle_deg=(0.5, 2))
    rng = np.random.default_rng(0)
    for c in POSE:
        cols[c] = np.round(rng.normal(0, 100, 60), 3).tolist()
    cols["temperature_c"] = [20] * 60  # integers in the log
    csv_log = write_log_csv(cols, tmp_path / "log.csv")
    t = pa.table(cols)
    secs = pa.array([np.datetime64(v.rstrip("Z"), "us").astype("int64") / 1e6 for v in cols["time"]], pa.float64())
    t = t.set_column(t.column_names.index("time"), "time", secs)  # seconds, as simulate-log writes them
    pq.write_table(t, tmp_path / "log.parquet")
    (tmp_path / "hive" / "cell=C1").mkdir(parents=True)
    pq.write_table(t.drop_columns(["cell"]), tmp_path / "hive" / "cell=C1" / "part-0.parquet")
    schemas = {}
    for name, log, out in (("csv", csv_log, "r_csv.parquet"), ("parquet", tmp_path / "log.parquet", "r_pq.parquet"),
                           ("hive", tmp_path / "hive", "r_hive")):
        r = runner.invoke(app, ["measure", str(log), "--layout", str(layout), "--out", str(tmp_path / out), "--json"])
        assert r.exit_code in (0, 1), r.output
        res = ds.dataset(tmp_path / out, format="parquet", partitioning="hive").to_table() if name == "hive" else \
            pq.read_table(tmp_path / out)
        schemas[name] = {f.name: f.type for f in res.schema if f.name != "cell"}
        assert res.schema.field("time").type == pa.timestamp("us", tz="UTC"), (name, res.schema.field("time").type)
        for c in (*POSE, "temperature_c", "d_L1"):
            assert c not in res.schema.names, (name, c)
        assert {"hole_id", "time", "reason"} <= set(res.schema.names)
        assert res.column("time")[0].as_py().isoformat().startswith(cols["time"][0][:19])
    assert schemas["csv"] == schemas["parquet"] == schemas["hive"]


def test_the_manifest_names_the_layout_by_its_files_sha256(tmp_path):
    """Issue 51, item 9: ``_metro_measure.json``'s layout_sha256 is the file's, as the certificate, the
    report and the QIF give it."""
    import hashlib
    import json

    layout = tmp_path / "cal.toml"
    save_layout(calibrated_layout(), layout)
    cols, _, _ = hole_log(calibrated_layout(), n=30, seed=1, angle_deg=(0.5, 2))
    (tmp_path / "log" / "cell=C1").mkdir(parents=True)
    pq.write_table(pa.table(cols).drop_columns(["cell"]), tmp_path / "log" / "cell=C1" / "part-0.parquet")
    r = runner.invoke(app, ["measure", str(tmp_path / "log"), "--layout", str(layout), "--out", str(tmp_path / "o"),
                            "--json"])
    assert r.exit_code in (0, 1), r.output
    manifest = json.loads((tmp_path / "o" / "_metro_measure.json").read_text(encoding="utf-8"))
    text = json.dumps(manifest)
    assert hashlib.sha256(layout.read_bytes()).hexdigest() in text
