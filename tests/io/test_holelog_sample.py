"""metrology.io.holelog_sample reads a log's first rows through the log's own reader (a CSV file, lines in memory,
Parquet), and the log's column names live in metrology.io.holelog_schema alone."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.csv as pcsv
import pyarrow.parquet as pq

from metrology.io.holelog import open_log
from metrology.io.holelog_sample import commanded_positions, first_readings
from metrology.io.holelog_schema import HOLE_ID, NUMERIC, POINT_ID, POSE_POSITION, POSE_ROTATION, table_key
from metrology.io.loglines import lines_log

HEADER = ("hole_id", "time", "d_L1", "d_L2", "d_L3", "point_id", "pose_x_mm", "pose_y_mm", "pose_z_mm")
ROWS = [("h1", "0", "50.1", "50.2", "50.3", "P7", "1.5", "-2", "300"),
        ("h2", "20", "49.9", "", "50.0", "P8", "2.5", "x", "301")]


def _expect(got):
    keys, xyz = got
    assert keys.tolist() == ["P7", "P8"]  # the table's own id: point_id where the log has it
    np.testing.assert_array_equal(xyz, [[1.5, -2.0, 300.0], [2.5, np.nan, 301.0]])


def test_the_first_rows_read_by_the_logs_reader_whatever_its_file(tmp_path):
    table = pa.table({c: [r[i] for r in ROWS] for i, c in enumerate(HEADER)})
    csv_path, pq_path = tmp_path / "log.csv", tmp_path / "log.parquet"
    pcsv.write_csv(table, csv_path)
    pq.write_table(table, pq_path)
    for path in (csv_path, pq_path):
        log = open_log(path, ("L1", "L2", "L3"))
        _expect(commanded_positions(log))
        np.testing.assert_array_equal(first_readings(log, ["d_L1", "d_L2"]), [[50.1, 50.2], [49.9, np.nan]])
    # lines a stream gave (measure --follow): no file at all, the CSV reader reads them from memory
    lines = [",".join(r) + "\n" for r in ROWS]
    live = lines_log(HEADER, lines, (2, 3), ("L1", "L2", "L3"), "<stdin>")
    _expect(commanded_positions(live))
    np.testing.assert_array_equal(first_readings(live, ["d_L3"]), [[50.3], [50.0]])


def test_the_logs_column_names_are_named_once():
    assert table_key(["hole_id", "point_id", "d_L1"]) == POINT_ID == "point_id"
    assert table_key(["hole_id", "d_L1"]) == HOLE_ID == "hole_id"
    assert NUMERIC == ("temperature_c", *POSE_ROTATION, *POSE_POSITION)
    from metrology.io import panel_units
    from metrology.measure.pose import POSE_COLUMNS

    assert POSE_COLUMNS == POSE_ROTATION + POSE_POSITION
    assert panel_units.POSE_POSITION is POSE_POSITION
