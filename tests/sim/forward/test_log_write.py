"""Hole logs on disk: the CSV and the hive-partitioned Parquet hold what was drawn, the truth is apart,
same seed same bytes, every file atomic."""

import math

import numpy as np
import pyarrow.csv as pcsv
import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest

from metrology.io.data import data_path
from metrology.io.layout import load_layout
from metrology.sim.forward.head import perturb_layout
from metrology.sim.forward.log import simulate_log
from metrology.sim.forward.log_spec import HoleChunk, LogSpec
from metrology.sim.forward.log_write import check_log_output, write_log_csv, write_log_parquet
from metrology.sim.forward.panels import make_panel

LAYOUT = load_layout(data_path("measured", "nominal.toml"))
NAMES = LAYOUT.names
# 400 holes per hour from 06:00 UTC: 10000 holes per cell span 25 h, 2 days
SPEC = LogSpec(perturb_layout(np.random.default_rng(1), LAYOUT, (0.01, 0.05), (0.01, 0.05)), LAYOUT,
               make_panel("sphere", 800.0), holes_per_hour=400.0, gross_rate=0.002)


def chunks(seed=0, holes=20000, cells=2, chunk_holes=6000):
    return simulate_log(SPEC, seed, holes, cells, chunk_holes)


def test_csv_log_holds_the_readings_and_the_truth_is_keyed_apart(tmp_path):
    log, truth = tmp_path / "log.csv", tmp_path / "truth.csv"
    assert write_log_csv(chunks(), log, truth) == 20000
    t = pcsv.read_csv(log)
    assert t.column_names == ["hole_id", "time", "cell", "panel", "temperature_c", *[f"d_{n}" for n in NAMES],
                              *[f"d_{n}_after" for n in NAMES], "pose_rx_deg", "pose_ry_deg", "pose_rz_deg",
                              "pose_x_mm", "pose_y_mm", "pose_z_mm"]
    drawn = [HoleChunk.concat(list(simulate_log(SPEC, 0, 20000, 2, 20000))[i:i + 1]) for i in range(2)]
    d = np.vstack([c.d for c in drawn])
    got = np.column_stack([t[f"d_{n}"].to_numpy(zero_copy_only=False) for n in NAMES])
    assert np.array_equal(got, d, equal_nan=True)  # blanks come back blank, values exactly
    assert t["hole_id"].to_pylist()[:2] == ["C1-00000001", "C1-00000002"]
    assert t["hole_id"].to_pylist()[-1] == "C2-00010000" and len(set(t["hole_id"].to_pylist())) == 20000
    tr = pcsv.read_csv(truth)
    assert tr["hole_id"].equals(t["hole_id"])
    assert np.allclose(tr["true_angle_deg"].to_numpy(), np.degrees(np.concatenate([c.true_angle for c in drawn])))
    assert {"true_normal_x", "true_after_deg", "drill_z_mm", "offset_L1", "gross_L4_after", "adjusted"} <= set(
        tr.column_names)
    assert not ({"true_angle_deg", "offset_L1"} & set(t.column_names))  # the log looks like a cell's log


def test_same_seed_same_bytes(tmp_path):
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        write_log_csv(chunks(seed, holes=3000), tmp_path / f"{name}.csv", tmp_path / f"{name}.truth.parquet")
    a, b, c = ((tmp_path / f"{x}.csv").read_bytes() for x in "abc")
    assert a == b and a != c
    assert (tmp_path / "a.truth.parquet").read_bytes() == (tmp_path / "b.truth.parquet").read_bytes()


def test_partitioned_parquet_is_hive_by_cell_and_utc_date(tmp_path):
    out = tmp_path / "logs"
    n, files = write_log_parquet(chunks(), out, tmp_path / "truth.parquet")
    assert n == 20000 and all(f.exists() for f in files)
    for f in files:
        rel = f.relative_to(out).parts
        assert len(rel) == 3 and rel[0].startswith("cell=C") and rel[1].startswith("date=")
        assert rel[2].startswith("part-") and rel[2].endswith(".parquet")
        t = pq.read_table(f)
        day = np.unique((t["time"].to_numpy() // 86400).astype("datetime64[D]").astype(str))
        assert day.tolist() == [rel[1][len("date="):]] and "cell" not in t.column_names  # the key: the folder's name
    assert {f.parent.parent.name for f in files} == {"cell=C1", "cell=C2"}
    assert len({f.parent for f in files}) >= 4  # 2 cells x at least 2 days
    whole = ds.dataset(out, partitioning="hive").to_table()
    assert whole.num_rows == 20000 and len(set(whole["hole_id"].to_pylist())) == 20000
    assert [c.split("-")[0] for c in whole["hole_id"].to_pylist()] == whole["cell"].to_pylist()
    write_log_csv(chunks(), tmp_path / "same.csv")
    csv = pcsv.read_csv(tmp_path / "same.csv")
    whole = whole.sort_by("hole_id")
    for col in ("time", "d_L1", "d_L3_after"):
        assert np.array_equal(whole[col].to_numpy(zero_copy_only=False), csv[col].to_numpy(zero_copy_only=False),
                              equal_nan=True)
    assert pq.read_table(tmp_path / "truth.parquet").num_rows == 20000


def failing(after):
    for i, c in enumerate(chunks(chunk_holes=3000)):
        if i == after:
            raise RuntimeError("disk full")
        yield c


def test_an_interrupted_write_leaves_no_partial_file(tmp_path):
    log, truth = tmp_path / "log.csv", tmp_path / "truth.parquet"
    with pytest.raises(RuntimeError, match="disk full"):
        write_log_csv(failing(2), log, truth)
    assert list(tmp_path.iterdir()) == []  # neither file, no temporary left
    with pytest.raises(RuntimeError, match="disk full"):
        write_log_parquet(failing(2), tmp_path / "logs", truth)
    files = sorted(p for p in (tmp_path / "logs").rglob("*") if p.is_file())
    assert files and all(p.name.startswith("part-") for p in files)  # each written part is whole
    assert sum(pq.read_table(p).num_rows for p in files) == 6000 and not truth.exists()


def test_outputs_are_checked_before_any_work(tmp_path):
    assert check_log_output(tmp_path / "x.csv") == "csv"
    assert check_log_output(tmp_path / "new") == "parquet"
    assert check_log_output(tmp_path / "out.one") == "parquet"  # a new folder, whatever its name
    assert check_log_output(tmp_path / "x.parquet") == "parquet-file"
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "f").write_text("x")
    (tmp_path / "x.txt").write_text("x")
    for out, truth, msg in [(tmp_path / "full", None, "not an empty folder"), (tmp_path / "x.txt", None, "not an empty folder"),
                            (tmp_path / "no" / "x.csv", None, "does not exist"),
                            (tmp_path / "new", tmp_path / "new" / "t.parquet", "apart from the log"),
                            (tmp_path / "x.csv", tmp_path / "t.json", ".csv or .parquet")]:
        with pytest.raises(ValueError, match=msg):
            check_log_output(out, truth)
    assert math.isfinite(SPEC.standoff_distance_mm)
