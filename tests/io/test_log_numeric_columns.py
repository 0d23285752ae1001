"""One schema whatever the log's format (issue 51, item 8): the commanded pose ``pose_*`` and ``temperature_c``
read as float64 from a CSV as from Parquet (they were strings from a CSV; no test read them: the walk found the
schema test passes with that cast reverted, since the results carry no pose)."""

import pyarrow as pa
import pyarrow.parquet as pq

from metrology.io.holelog import open_log
from metrology.io.holelog_schema import NUMERIC

SENSORS = ("L1", "L2", "L3", "L4")
POSE = ("pose_rx_deg", "pose_ry_deg", "pose_rz_deg", "pose_x_mm", "pose_y_mm", "pose_z_mm")


def _tables(path):
    log = open_log(path, SENSORS)
    return pa.concat_tables([t for part in log.partitions for t, _ in log.batches(part)])


def test_pose_and_temperature_are_float64_from_csv_and_parquet(tmp_path):
    assert set(POSE) | {"temperature_c"} <= set(NUMERIC)
    header = "hole_id,time,temperature_c,d_L1,d_L2,d_L3,d_L4," + ",".join(POSE) + "\n"
    rows = [f"H{i},2026-11-25T08:00:{i:02d}Z,20,50,50.1,49.9,50.2,-170.5,0,-27,-500,-300,-93" for i in range(5)]
    csv = tmp_path / "log.csv"
    csv.write_text(header + "".join(r + "\n" for r in rows))
    from_csv = _tables(csv)
    pq.write_table(pa.Table.from_pydict({c: from_csv.column(c) for c in ("hole_id", "time")} | {
        c: pa.array([float(x) for x in from_csv.column(c).to_pylist()]) for c in (*POSE, "temperature_c", "d_L1",
                                                                                   "d_L2", "d_L3", "d_L4")}),
                   tmp_path / "log.parquet")
    from_parquet = _tables(tmp_path / "log.parquet")
    for t in (from_csv, from_parquet):
        for c in (*POSE, "temperature_c"):
            assert t.schema.field(c).type == pa.float64(), (c, t.schema.field(c).type)
    assert from_csv.column("pose_x_mm").to_pylist() == [-500.0] * 5
