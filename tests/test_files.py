"""Layout TOML and tracker export CSV: round trips and one-line errors."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from metrology.io.export import TrackerExport, read_export, write_export
from metrology.core.layout import SensorLayout
from metrology.io.layout import load_layout, save_layout
from metrology.core.paper import table6_layouts


def test_layout_round_trip(tmp_path):
    nominal, _ = table6_layouts()
    lay = SensorLayout(nominal.names, nominal.zero, nominal.direction, [0.003] * 4, [[20, 80]] * 4,
                       np.full((4, 3), 0.01), np.full((4, 2), 0.02), {"L2": {"scale": 1e-3}})
    save_layout(lay, tmp_path / "l.toml", header="test")
    back = load_layout(tmp_path / "l.toml")
    assert back.names == lay.names and back.effects == {"L2": {"scale": 1e-3}}
    np.testing.assert_allclose(back.zero, lay.zero, atol=1e-6)
    np.testing.assert_allclose(back.direction, lay.direction, atol=1e-9)
    np.testing.assert_allclose(back.range_mm, lay.range_mm)
    np.testing.assert_allclose(back.direction_stderr_deg, 0.02)


@pytest.mark.parametrize("body,msg", [
    ('units = "inch"\n', "units must be"),
    ("[[sensors]]\nname='a'\nzero=[0,0,0]\ndirection=[0,0,1]\n", "at least 3 sensors"),
    ("[[sensors]]\nname='a'\nzero=[0,0]\ndirection=[0,0,1]\n" * 3, "'zero' must be 3"),
    ("[[sensors]]\nname='a'\nzero=[0,0,0]\ndirection=[0,0,2]\n" * 3, "expected a unit vector"),
    ("[[sensors]]\nname='a'\nzero=[0,0,0]\ndirection=[0,0,1]\n" * 3, "unique"),
    ("not toml [", "not valid TOML"),
])
def test_layout_errors_name_the_file(tmp_path, body, msg):
    p = tmp_path / "bad.toml"
    p.write_text(body)
    with pytest.raises(ValueError, match=msg) as exc:
        load_layout(p)
    assert "bad.toml" in str(exc.value) or "unique" in msg


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
