"""metrology.io.holelog and holeout: hole logs read in batches, errors that name the line,
partitioned outputs written atomically and resumed."""

import os

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from metrology.io.holelog import open_log
from metrology.io.holelog_schema import INTERNAL, TIME_S
from metrology.io.holeout import is_file_out, PartitionedOutput, TableSink, check_out

SENSORS = ("L1", "L2", "L3", "L4")
HEADER = "hole_id,time,d_L1,d_L2,d_L3,d_L4,extra\n"


def _csv(tmp_path, rows, header=HEADER, name="log.csv"):
    p = tmp_path / name
    p.write_text(header + "".join(r + "\n" for r in rows))
    return p


def _read(log):
    return [t for part in log.partitions for t, _ in log.batches(part)]


def test_csv_in_batches_with_iso_and_zone_offsets(tmp_path):
    rows = [f"H{i},2026-11-25T08:00:{i:02d}Z,50,50.1,,49.9,x{i}" for i in range(50)]
    rows[1] = "H1,2026-11-25T09:00:01+01:00,50,50.1,,49.9,x1"
    log = open_log(_csv(tmp_path, rows), SENSORS, batch_rows=16)
    tables = _read(log)
    assert [t.num_rows for t in tables] == [16, 16, 16, 2]
    t = pa.concat_tables(tables)
    ts = t.column(TIME_S).to_numpy()
    assert ts[1] - ts[0] == pytest.approx(1.0)  # 09:00:01+01:00 is 08:00:01Z
    assert np.isnan(t.column("d_L3").to_numpy(zero_copy_only=False)).all()
    assert t.column("extra").to_pylist()[:2] == ["x0", "x1"]


def test_time_in_seconds(tmp_path):
    log = open_log(_csv(tmp_path, ["A,12.5,50,50,50,50,", "B,13,50,50,50,50,"]), SENSORS)
    assert _read(log)[0].column(TIME_S).to_pylist() == [12.5, 13.0]


@pytest.mark.parametrize("rows, header, message", [
    (["H1,1,50,50,50,50,", "H2,2,50,abc,50,50,"], HEADER, r"log\.csv line 3: d_L2 = 'abc' is not a number"),
    (["H1,1,50,50,50,50,"], "hole_id,time,d_L1,d_L2,d_L3,d_L5,extra\n", r"column d_L5 names no sensor of the layout"),
    (["H1,1,50,50,50,"], "hole_id,time,d_L1,d_L2,d_L3,extra\n", r"no reading column for L4 .*do not match the layout"),
    (["H1,1,50,50,50,50,"], "id,time,d_L1,d_L2,d_L3,d_L4,extra\n", r"no 'hole_id' column"),
    (["H1,1,50,50,50,50,1"], "hole_id,time,d_L1,d_L2,d_L3,d_L4,d_L1_after\n", r"after-readings for L1 but not for L2"),
    (["H1,yesterday,50,50,50,50,"], HEADER, r"log\.csv line 2: time 'yesterday' is neither ISO 8601"),
    ([], "", r"empty file"),
])
def test_bad_csv_is_one_line_naming_line_and_value(tmp_path, rows, header, message):
    p = _csv(tmp_path, rows, header)
    with pytest.raises(ValueError, match=message) as err:
        _read(open_log(p, SENSORS))
    assert "\n" not in str(err.value)


def _partitioned(tmp_path, corrupt=False):
    root = tmp_path / "fleet"
    for cell in ("C1", "C2"):
        for day in ("2026-11-24", "2026-11-25"):
            d = root / f"cell={cell}" / f"date={day}"
            d.mkdir(parents=True)
            n = 5
            pq.write_table(pa.table({"hole_id": [f"{cell}{day}{i}" for i in range(n)],
                                     "time": [f"{day}T08:00:0{i}Z" for i in range(n)],
                                     **{f"d_{s}": [50.0] * n for s in SENSORS}}), d / "part-0.parquet")
    if corrupt:
        f = root / "cell=C2" / "date=2026-11-25" / "part-0.parquet"
        f.write_bytes(f.read_bytes()[: len(f.read_bytes()) // 2])
    return root


def test_hive_partitions_carry_their_keys(tmp_path):
    log = open_log(_partitioned(tmp_path), SENSORS)
    assert len(log.partitions) == 4 and log.partitioned
    assert log.partitions[0].keys == {"cell": "C1", "date": "2026-11-24"}
    t = _read(log)[0]
    assert set(t.column("cell").to_pylist()) == {"C1"}
    assert "cell" not in log.file_columns(log.partitions[0])


def test_a_truncated_partition_is_named(tmp_path):
    with pytest.raises(ValueError, match=r"partition cell=C2/date=2026-11-25/part-0\.parquet: not a readable Parquet"):
        open_log(_partitioned(tmp_path, corrupt=True), SENSORS)


def test_a_folder_without_parquet_and_a_wrong_suffix(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="must hold .parquet files"):
        open_log(tmp_path / "empty", SENSORS)
    (tmp_path / "log.txt").write_text("x")
    with pytest.raises(ValueError, match=r"must be one of \.csv, \.parquet"):
        open_log(tmp_path / "log.txt", SENSORS)


def test_table_sink_is_atomic(tmp_path):
    out = tmp_path / "holes.parquet"
    with pytest.raises(RuntimeError):
        with TableSink(out) as sink:
            sink.write(pa.table({"a": [1, 2]}))
            raise RuntimeError("killed mid-run")
    assert not out.exists() and not [p for p in os.listdir(tmp_path) if p.startswith(".")]
    with TableSink(out) as sink:
        sink.write(pa.table({"a": [1, 2]}))
        sink.write(pa.table({"a": [3]}))
    assert pq.read_table(out).column("a").to_pylist() == [1, 2, 3]


def test_partitioned_output_refuses_other_settings(tmp_path):
    out = PartitionedOutput(tmp_path / "o", {"tolerance_deg": 0.5})
    out.begin()
    with out.sink("cell=C1/part-0.parquet") as s:
        s.write(pa.table({"a": [1]}))
    assert PartitionedOutput(tmp_path / "o", {"tolerance_deg": 0.5}).done("cell=C1/part-0.parquet")
    with pytest.raises(ValueError, match=r"other settings \(tolerance_deg differ\)"):
        PartitionedOutput(tmp_path / "o", {"tolerance_deg": 0.3})
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "x").write_text("")
    with pytest.raises(ValueError, match="not empty and is not a metro measure output"):
        PartitionedOutput(tmp_path / "busy", {})


def test_check_out(tmp_path):
    """One process or Dask alike: a log into one file or stdout, a partitioned log into a folder;
    a folder is any name that is not a .csv/.parquet file (out.one too)."""
    assert check_out(None, False, False) is None and check_out(None, True, True) is None
    assert check_out(tmp_path / "h.csv", True, True) == tmp_path / "h.csv"
    assert check_out(tmp_path / "h.parquet", False, True) == tmp_path / "h.parquet"
    with pytest.raises(ValueError, match="mirrors a partitioned Parquet log"):
        check_out(tmp_path / "folder", False, False)
    with pytest.raises(ValueError, match=r"for a single log give a file: \.csv, \.parquet"):
        check_out(tmp_path / "h.txt", False, False)
    assert check_out(tmp_path / "out.one", True, False) == tmp_path / "out.one"
    assert not is_file_out(tmp_path / "out.one") and is_file_out(tmp_path / "h.CSV")
    (tmp_path / "dir.parquet").mkdir()
    assert not is_file_out(tmp_path / "dir.parquet")
    assert INTERNAL


def test_two_runs_into_one_folder_at_once_are_refused(tmp_path, monkeypatch):
    from metrology.io import holeout

    monkeypatch.setattr(holeout, "LOCK_WAIT_S", 0.3)  # the wait's length is not what is checked (5 s idle otherwise)
    first = PartitionedOutput(tmp_path / "o", {"tolerance_deg": 0.5})
    first.begin()
    second = PartitionedOutput(tmp_path / "o", {"tolerance_deg": 0.5})
    with pytest.raises(ValueError, match=r"another run is writing into it \(pid \d+ on .*; waited 0.3 s; if none is, remove"):
        second.begin()
    first.release()
    second.begin()  # the first has ended: the folder is free
    second.release()
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["_metro_measure.json"]
