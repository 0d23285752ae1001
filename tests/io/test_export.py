"""Tracker export CSV (metrology.io.export): round trips and one-line errors."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from metrology.io.export import TrackerExport, read_export, write_export


def _export(rng, p=5, names=("L1", "L2", "L3")):
    q = rng.normal(size=(p, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    d = rng.uniform(40, 60, size=(p, len(names)))
    d[1, 0] = np.nan
    return TrackerExport(tuple(f"P{i}" for i in range(p)), np.arange(p) * 10.0, np.full(p, 20.5), q,
                         rng.normal(scale=1000, size=(p, 3)), names, d)


def test_export_round_trip(tmp_path, rng):
    ex = _export(rng)
    write_export(ex, tmp_path / "e.csv")
    back = read_export(tmp_path / "e.csv")
    assert back.pose_id == ex.pose_id and back.names == ex.names
    np.testing.assert_allclose(back.d, ex.d, atol=1e-9, equal_nan=True)
    np.testing.assert_allclose(back.quaternion, ex.quaternion, atol=1e-11)
    np.testing.assert_allclose(back.tcs2tracker_trans, ex.tcs2tracker_trans, atol=1e-9)


HEADER = "pose_id,x,y,z,qw,qx,qy,qz,d_L1,d_L2,d_L3\n"


@pytest.mark.parametrize("body,msg", [
    ("", "empty file"),
    ("pose_id,x,y,z,qw,qx,qy,d_L1\n", "missing column"),
    (HEADER + "1,0,0,0,1,0,0,0,40,41\n", "line 2: 10 fields"),
    (HEADER + "1,0,0,0,0.9,0,0,0,40,41,42\n", "line 2: quaternion norm"),
    (HEADER + "1,0,0,abc,1,0,0,0,40,41,42\n", "line 2: column 'z'"),
    (HEADER + "1,0,0,0,1,0,0,0,nan,41,42\n", "line 2: column 'd_L1' = 'nan' is not finite"),
    (HEADER + "1,0,0,0,1,0,0,0,40,41,42\n1,0,0,0,1,0,0,0,40,41,42\n", "duplicate pose_id"),
    ("pose_id,x,y,z,qw,qx,qy,qz,d_L1,foo\n", "unknown column"),
])
def test_export_errors_name_file_and_line(tmp_path, body, msg):
    p = tmp_path / "bad.csv"
    p.write_text(body)
    with pytest.raises(ValueError, match=msg) as exc:
        read_export(p)
    assert str(exc.value).startswith(str(p))


@settings(max_examples=50, deadline=None)
@given(values=st.lists(st.floats(-1e4, 1e4, allow_nan=False), min_size=3, max_size=3))
def test_export_parser_round_trips_any_finite_reading(tmp_path_factory, values):
    p = tmp_path_factory.mktemp("h") / "e.csv"
    p.write_text(HEADER + "a,0,0,0,1,0,0,0," + ",".join(repr(v) for v in values) + "\n")
    np.testing.assert_allclose(read_export(p).d[0], values, rtol=1e-15)
