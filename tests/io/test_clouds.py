"""Point-cloud readers: every format round-trips, every bad input says where and what."""

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from metrology.io.data import DATA_DIR
from metrology.io._o3d import open3d
from metrology.io.clouds import read_cloud

PTS = np.array([[1.5, -2.25, 3.0], [1000.125, 2000.5, -14.75], [0.0, 1e-3, 7.0], [-5.5, 6.5, 1690.2827]])


def _o3d_cloud(points):
    o3d = open3d()
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))


def test_open3d_binary_ply_round_trip(tmp_path):
    path = tmp_path / "c.ply"
    assert open3d().io.write_point_cloud(str(path), _o3d_cloud(PTS), write_ascii=False)
    np.testing.assert_array_equal(read_cloud(path), PTS)


def test_open3d_written_pcd_is_float32(tmp_path):
    # Open3D writes PCD coordinates as 4-byte floats: 1.2e-4 mm resolution at 1.7 m
    path = tmp_path / "c.pcd"
    assert open3d().io.write_point_cloud(str(path), _o3d_cloud(PTS), write_ascii=False)
    np.testing.assert_array_equal(read_cloud(path), PTS.astype(np.float32).astype(float))


def test_binary_double_pcd(tmp_path):
    path = tmp_path / "c.pcd"
    head = ASCII_PCD.replace("DATA ascii", "DATA binary")
    path.write_bytes(head.encode() + PTS.astype("<f8").tobytes())
    np.testing.assert_array_equal(read_cloud(path), PTS)


ASCII_PLY = "ply\nformat ascii 1.0\nelement vertex 4\nproperty double x\nproperty double y\nproperty double z\nend_header\n"
ASCII_PCD = (
    "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 8 8 8\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 4\nHEIGHT 1\n"
    "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 4\nDATA ascii\n"
)


@pytest.mark.parametrize("suffix, head", [(".ply", ASCII_PLY), (".pcd", ASCII_PCD)])
def test_open3d_ascii_formats_keep_full_precision(tmp_path, suffix, head):
    # written by hand: Open3D's own ASCII PLY writer keeps only 6 significant digits
    path = tmp_path / f"c{suffix}"
    path.write_text(head + "".join(" ".join(repr(float(v)) for v in p) + "\n" for p in PTS))
    np.testing.assert_array_equal(read_cloud(path), PTS)


def test_pcd_binary_compressed(tmp_path):
    path = tmp_path / "c.pcd"
    assert open3d().io.write_point_cloud(str(path), _o3d_cloud(PTS), write_ascii=False, compressed=True)
    np.testing.assert_array_equal(read_cloud(path), PTS.astype(np.float32).astype(float))


def test_fixture_ply_is_read(tmp_path):
    pts = read_cloud(str(DATA_DIR / "datum_cloud.ply"))
    assert pts.shape == (3300, 3) and pts.dtype == np.float64


@pytest.mark.parametrize(
    "name, text",
    [
        ("a.xyz", "1.5 -2.25 3\n1000.125 2000.5 -14.75\n0 0.001 7\n-5.5 6.5 1690.2827\n"),
        ("a.xyzn", "1.5 -2.25 3 0 0 1\n1000.125 2000.5 -14.75 0 0 1\n0 0.001 7 0 0 1\n-5.5 6.5 1690.2827 0 0 1\n"),
        ("a.pts", "4\n1.5 -2.25 3 10 1 2 3\n1000.125 2000.5 -14.75 10 1 2 3\n0 0.001 7 9 1 2 3\n-5.5 6.5 1690.2827 9 1 2 3\n"),
        ("a.pts", "1.5 -2.25 3 10\n1000.125 2000.5 -14.75 10\n0 0.001 7 9\n-5.5 6.5 1690.2827 9\n"),
        ("a.csv", "x,y,z\n1.5,-2.25,3\n1000.125,2000.5,-14.75\n0,0.001,7\n-5.5,6.5,1690.2827\n"),
        ("a.csv", "1.5,-2.25,3\n1000.125,2000.5,-14.75\n0,0.001,7\n-5.5,6.5,1690.2827\n"),
        ("a.csv", "Name;X [mm];Y [mm];Z [mm]\nP1;1,5;-2,25;3\nP2;1000,125;2000,5;-14,75\nP3;0;0,001;7\nP4;-5,5;6,5;1690,2827\n"),
        ("a.csv", "# SpatialAnalyzer export\n\nPoint,Z,X,Y\nP1,3,1.5,-2.25\nP2,-14.75,1000.125,2000.5\nP3,7,0,0.001\nP4,1690.2827,-5.5,6.5\n"),
        ("a.txt", "P1\t1.5\t-2.25\t3\nP2\t1000.125\t2000.5\t-14.75\nP3\t0\t0.001\t7\nP4\t-5.5\t6.5\t1690.2827\n"),
        ("a.txt", '"pos_x" "pos_y" "pos_z" "intensity"\n1.5 -2.25 3 1\n1000.125 2000.5 -14.75 1\n0 0.001 7 1\n-5.5 6.5 1690.2827 1\n'),
        ("a.txt", "1.5;-2.25;3\n1000.125;2000.5;-14.75\n0;0.001;7\n-5.5;6.5;1690.2827\n"),
    ],
)
def test_text_formats(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    np.testing.assert_array_equal(read_cloud(path), PTS)


def test_e57_metres_to_mm(tmp_path):
    pye57 = pytest.importorskip("pye57")
    path = tmp_path / "c.e57"
    e57 = pye57.E57(str(path), mode="w")
    metres = PTS / 1000
    e57.write_scan_raw({"cartesianX": metres[:, 0], "cartesianY": metres[:, 1], "cartesianZ": metres[:, 2]})
    e57.close()
    # pye57 writes single-precision coordinates; the reader converts metres to mm
    np.testing.assert_allclose(read_cloud(path), metres.astype(np.float32).astype(float) * 1000, rtol=1e-15, atol=0)


def test_e57_garbage_is_one_line(tmp_path):
    pytest.importorskip("pye57")
    path = tmp_path / "g.e57"
    path.write_text("garbage\n")
    with pytest.raises(ValueError, match=r"g\.e57: not a readable E57 point cloud") as info:
        read_cloud(path)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    "name, content, match",
    [
        ("e.ply", "", r"e\.ply: empty file"),
        ("e.csv", "", r"e\.csv: empty file"),
        ("e.csv", "x,y,z\n", r"e\.csv: no points in the file \(a header only\)"),
        ("e.xyz", "# nothing\n\n", r"e\.xyz: no points in the file"),
        ("e.csv", "1,2,3\n4,5,6\n", r"e\.csv: 2 points, need at least 3"),
        ("e.xyz", "1 2 3\n4 5 abc\n7 8 9\n", r"e\.xyz: line 2, column 3: 'abc' is not a number \(z expected\)"),
        ("e.csv", "x,y,z\n1,2,3\n4,5,6\n7,,9\n", r"e\.csv: line 4, column 2: '' is not a number \(y expected\)"),
        ("e.csv", "x,y,z\n1,2,3\n4,nan,6\n7,8,9\n", r"e\.csv: line 3, column 2: 'nan': coordinates must be finite"),
        ("e.txt", "1 2 3\n4 5 6\n7 8 inf\n", r"e\.txt: line 3, column 3: 'inf': coordinates must be finite"),
        ("e.txt", "1 2 3\n4 5\n7 8 9\n", r"e\.txt: line 2: 2 field\(s\), expected at least 3"),
        ("e.csv", "a,b,c\n1,2,3\n4,5,6\n7,8,9\n", r"e\.csv: line 1 is a header without x, y, z columns"),
        ("e.csv", "x,y\n1,2\n4,5\n7,8\n", r"e\.csv: line 1 is a header without x, y, z columns"),
        ("e.pts", "5\n1 2 3\n4 5 6\n7 8 9\n", r"e\.pts: the first line says 5 points, the file holds 3"),
        ("e.ply", "plyx\nformat ascii 1.0\n", r"e\.ply: not a PLY file"),
        ("e.ply", "ply\nformat ascii 1.0\nelement face 3\nend_header\n", r"e\.ply: the PLY header declares no vertex"),
        ("e.pcd", "# .PCD v0.7\nFIELDS x y\nSIZE 4 4\nTYPE F F\nCOUNT 1 1\nPOINTS 3\nDATA ascii\n1 2\n", r"no x, y, z fields"),
        ("e.pcd", "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nPOINTS 4\nDATA ascii\n1 2 3\n4 5 6\n7 8 9\n",
         r"e\.pcd: the header declares 4 points, the file holds 3"),
        ("e.pcd", "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nPOINTS 3\nDATA ascii\n1 2 3\n4 x 6\n7 8 9\n",
         r"e\.pcd: line 8, column 2: 'x' is not a number"),
        ("e.pcd", "not a pcd\n", r"e\.pcd: not a PCD file"),
        ("e.obj", "v 1 2 3\n", r"e\.obj: unknown point-cloud extension '\.obj'"),
        ("e", "1 2 3\n", r"unknown point-cloud extension '\(none\)'"),
    ],
)
def test_bad_text_inputs(tmp_path, name, content, match):
    path = tmp_path / name
    path.write_text(content)
    with pytest.raises(ValueError, match=match) as info:
        read_cloud(path)
    assert "\n" not in str(info.value)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(ValueError, match=r"nope\.ply: no such file"):
        read_cloud(tmp_path / "nope.ply")
    d = tmp_path / "d.ply"
    d.mkdir()
    with pytest.raises(ValueError, match="is a directory"):
        read_cloud(d)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nonfinite_in_binary_ply_names_the_point(tmp_path, bad):
    pts = PTS.copy()
    pts[2, 1] = bad
    path = tmp_path / "n.ply"
    assert open3d().io.write_point_cloud(str(path), _o3d_cloud(pts))
    with pytest.raises(ValueError, match=r"n\.ply: point 3 is .*coordinates must be finite"):
        read_cloud(path)


def test_truncated_binary_ply_and_pcd(tmp_path):
    head = "ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty double x\nproperty double y\nproperty double z\nend_header\n"
    ply = tmp_path / "t.ply"
    ply.write_bytes(head.encode() + PTS.astype("<f8").tobytes())
    with pytest.raises(ValueError, match=r"t\.ply: truncated: the header declares 10 vertices, the file holds 4"):
        read_cloud(ply)
    pcd = tmp_path / "t.pcd"
    pcd.write_bytes(ASCII_PCD.replace("DATA ascii", "DATA binary").replace("POINTS 4", "POINTS 9").encode() + PTS.astype("<f8").tobytes())
    with pytest.raises(ValueError, match=r"t\.pcd: truncated: the header declares 9 points, the file holds 4"):
        read_cloud(pcd)


def test_two_points_in_ply(tmp_path):
    path = tmp_path / "two.ply"
    assert open3d().io.write_point_cloud(str(path), _o3d_cloud(PTS[:2]))
    with pytest.raises(ValueError, match=r"two\.ply: 2 points, need at least 3"):
        read_cloud(path)


# ---------------------------------------------------------------------------------------
# property tests of the text parser

finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)
rows = st.lists(st.tuples(finite, finite, finite), min_size=3, max_size=30)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    rows=rows,
    delim=st.sampled_from([",", ";", " ", "\t", " , ", "  "]),
    header=st.sampled_from([None, ("x", "y", "z"), ("X [mm]", "Y [mm]", "Z [mm]"), ("Point X", "Point Y", "Point Z"), ("pos_x", "pos_y", "pos_z")]),
    suffix=st.sampled_from([".csv", ".txt", ".xyz"]),
)
def test_text_round_trip(tmp_path_factory, rows, delim, header, suffix):
    # with white space between fields, a name holding a space must be quoted (a unit
    # in brackets may stand alone)
    if header is not None and delim.strip() == "":
        header = tuple(f'"{h}"' if " " in h and "[" not in h else h for h in header)
    path = tmp_path_factory.mktemp("p") / f"c{suffix}"
    lines = [] if header is None else [delim.join(header)]
    lines += [delim.join(repr(v) for v in r) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    np.testing.assert_array_equal(read_cloud(path), np.array(rows))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rows=rows)
def test_decimal_comma_round_trip(tmp_path_factory, rows):
    path = tmp_path_factory.mktemp("p") / "c.csv"
    body = "\n".join(";".join(repr(v).replace(".", ",") for v in r) for r in rows)
    path.write_text("X;Y;Z\n" + body + "\n")
    np.testing.assert_array_equal(read_cloud(path), np.array(rows))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rows=rows, data=st.data(), token=st.sampled_from(["abc", "1.2.3", "--", "x1", "1e", "NaN", "-inf"]))
def test_a_bad_field_is_named_by_line_and_column(tmp_path_factory, rows, data, token):
    header = data.draw(st.booleans())
    i = data.draw(st.integers(0, len(rows) - 1))
    j = data.draw(st.integers(0, 2))
    fields = [[repr(v) for v in r] for r in rows]
    fields[i][j] = token
    lines = (["x,y,z"] if header else []) + [",".join(f) for f in fields]
    assume(header or i > 0)  # a bad first line without a header is taken for a header (tested above)
    path = tmp_path_factory.mktemp("p") / "c.csv"
    path.write_text("\n".join(lines) + "\n")
    line = i + 1 + int(header)
    with pytest.raises(ValueError, match=rf"c\.csv: line {line}, column {j + 1}: '{token}'"):
        read_cloud(path)
