"""Malformed clouds (other parsers' test cases, issue 11's cases, a real malformed file) are
refused with one line naming the line (or byte count) and the value; nothing is written.

The files are in ``tests/data/clouds/malformed``; ``tests/data/README.md`` says where each
comes from (plyfile's ``test_invalid`` and ``test_header_parse_error``, trimesh's models).
"""

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.clouds import read_cloud, read_cloud_checked

BAD = Path(__file__).resolve().parents[1] / "data" / "clouds" / "malformed"

CASES = [
    # plyfile test_invalid (element 'test' a b c -> 'vertex' x y z; see the README)
    ("plyfile_invalid_0_float_in_uchar.ply", r"line 8, column 3: '3\.3' is not an integer, expected uint8 \(property 'z'\)"),
    ("plyfile_invalid_1_empty_row_before_list.ply", r"line 9: 0 value\(s\), the row ends before list 'a', expected a count \(uint8\)"),
    ("plyfile_invalid_2_list_too_short.ply", r"line 9: list 'a' of 3 with 2 value\(s\) left on the row, expected 3 values"),
    ("plyfile_invalid_3_extra_token.ply", r"line 8: 4 values \('4' left over\), expected 3"),
    ("plyfile_invalid_4_short_row.ply", r"line 8: 1 value\(s\), the row ends before property 'y', expected one value per property \(x, y, z\)"),
    ("plyfile_invalid_5_early_eof.ply", r"line 9: the end of the file after 1 row\(s\) of element 'vertex', expected 2 rows"),
    ("plyfile_invalid_6_binary_short_row.ply", r"truncated: the header declares 1 vertices, the file holds 0"),
    ("plyfile_invalid_7_binary_no_list_count.ply", r"truncated: the file ends in row 1 of element 'vertex' \(the count of list 'a'\)"),
    ("plyfile_invalid_8_binary_list_no_scalars.ply", r"truncated: the file ends in row 1 of element 'vertex' \(property 'a'\)"),
    ("plyfile_invalid_9_binary_list_short.ply", r"truncated: the file ends in row 1 of element 'vertex' \(property 'a'\)"),
    ("plyfile_invalid_10_binary_early_eof.ply", r"truncated: the header declares 2 vertices, the file holds 1"),
    # plyfile test_header_parse_error: the same line numbers as plyfile's
    ("plyfile_header_0.ply", r"not a PLY file \(line 1: 'plyy', expected 'ply'\)"),
    ("plyfile_header_1.ply", r"not a PLY file \(line 1: 'ply xxx', expected 'ply'\)"),
    ("plyfile_header_2.ply", r"line 2: a blank line, expected a header keyword"),
    ("plyfile_header_3.ply", r"line 2: 'format', expected 'format ascii\|binary_little_endian\|binary_big_endian 1\.0'"),
    ("plyfile_header_4.ply", r"line 2: 'element vertex 0', expected 'format \.\.\.' before the first element"),
    ("plyfile_header_5.ply", r"line 2: 'format asciii 1\.0', expected 'format ascii"),
    ("plyfile_header_6.ply", r"line 2: 'format ascii 2\.0', expected 'format ascii"),
    ("plyfile_header_7.ply", r"line 3: the end of the file, expected 'end_header'"),
    ("plyfile_header_8.ply", r"line 3: 'element vertex', expected 'element <name> <count>'"),
    ("plyfile_header_9.ply", r"line 3: 'element vertex x', expected 'element <name> <count>'"),
    ("plyfile_header_10.ply", r"line 4: 'property float', expected 'property <type> <name>'"),
    ("plyfile_header_11.ply", r"line 4: 'property list float', expected 'property <type> <name>'"),
    ("plyfile_header_12.ply", r"line 4: 'property floatt x', expected 'property <type> <name>'"),
    ("plyfile_header_13.ply", r"line 4: 'property float x y', expected 'property <type> <name>'"),
    ("plyfile_header_14.ply", r"line 4: 'property list ucharr int extra', expected 'property <type> <name>'"),
    ("plyfile_header_15.ply", r"line 5: 'end_header xxx', expected 'end_header' alone"),
    # issue 11: what Open3D pads with uninitialised memory
    ("issue11_inf_in_float.ply", r"line 12, column 2: 'Inf' is not a number, expected float32 \(nan allowed, inf not\) \(property 'y'\)"),
    ("issue11_inf_in_uchar.ply", r"line 11, column 4: 'Inf' is not an integer, expected uint8 \(property 'red'\)"),
    ("issue11_float_in_uchar.ply", r"line 13, column 4: '2\.5' is not an integer, expected uint8 \(property 'red'\)"),
    ("issue11_uchar_out_of_range.ply", r"line 13, column 4: '256' is out of range, expected uint8 in \[0, 255\]"),
    ("issue11_non_numeric.ply", r"line 11, column 2: 'abc' is not a number, expected float32"),
    ("issue11_short_row.ply", r"line 12: 3 value\(s\), the row ends before property 'red'"),
    ("issue11_truncated_ascii.ply", r"line 13: the end of the file after 3 row\(s\) of element 'vertex', expected 4 rows"),
    ("issue11_trailing_garbage.ply", r"line 14: '5 6 7 8' after the last element \(4 vertex\), a row of element 'vertex' \(4 declared\), expected the end of the file"),
    ("issue11_blank_row.ply", r"line 12: 0 value\(s\), the row ends before property 'x'"),
    ("issue11_float32_overflow.ply", r"line 10, column 1: '1e39' is out of range, expected a finite float32"),
    ("binary_count_too_large.ply", r"truncated: the header declares 5 vertices, the file holds 4"),
    ("binary_count_too_small.ply", r"24 byte\(s\) after the last element: the header declares 72 bytes of data \(3 vertex\), the file holds 96"),
    # real files from trimesh's models
    ("trimesh_points_emptyascii.ply", r"line 23: '-0\.009618 -0\.013861 0\.0384' after the last element \(0 face\), a row of element 'vertex' \(12 declared\), expected the end of the file"),
    ("trimesh_ply_empty_header.ply", r"the PLY header declares no vertex element"),
    ("pcl_empty_cloud.ply", r"no points in the file$"),  # PCL test_ply_io.cpp EmptyCloud (PCL reads 0 points)
    # PCD and text
    ("pcd_ascii_short_row.pcd", r"line 13: 3 value\(s\), the row ends before property 'rgb'"),
    ("pcd_ascii_extra_value.pcd", r"line 13: 5 values \('9' left over\), expected 4"),
    ("pcd_ascii_inf.pcd", r"line 14, column 2: 'inf' is not a number, expected float32"),
    ("pcd_ascii_u8_out_of_range.pcd", r"line 15, column 4: '300' is out of range, expected uint8 in \[0, 255\]"),
    ("pcd_ascii_more_rows.pcd", r"the header declares 4 points, the file holds 5"),
    ("pcd_ascii_fewer_rows.pcd", r"the header declares 4 points, the file holds 3"),
    ("pcd_binary_extra_bytes.pcd", r"13 byte\(s\) after the 3 declared points, expected the end of the file"),
    ("xyz_short_row.xyz", r"line 2: 2 field\(s\), expected at least 3"),
    ("xyz_extra_field.xyz", r"line 2: 4 field\(s\), expected 3 as on line 1"),
    ("xyz_inf.xyz", r"line 2, column 2: '-inf': coordinates must be finite"),
    ("csv_non_numeric.csv", r"line 3, column 3: 'oops' is not a number \(z expected\)"),
]


def test_every_malformed_file_has_a_case():
    assert sorted(p.name for p in BAD.iterdir()) == sorted(name for name, _ in CASES)


@pytest.mark.parametrize("name, match", CASES, ids=[c[0] for c in CASES])
@pytest.mark.parametrize("reader", [read_cloud, read_cloud_checked], ids=["read_cloud", "read_cloud_checked"])
def test_malformed_is_refused_with_line_and_value(name, match, reader, capfd):
    path = BAD / name
    with pytest.raises(ValueError, match=rf"^{path}: {match}") as info:
        reader(path)
    assert "\n" not in str(info.value)
    assert capfd.readouterr().out == ""  # nothing of Open3D's (or anyone's) on stdout


@pytest.mark.parametrize("name", ["issue11_inf_in_uchar.ply", "issue11_short_row.ply", "binary_count_too_small.ply",
                                  "pcd_ascii_short_row.pcd", "trimesh_points_emptyascii.ply"])
def test_cli_exits_2_and_writes_nothing(tmp_path, name):
    out = tmp_path / "plane.json"
    res = CliRunner().invoke(app, ["fit-plane", str(BAD / name), "--out", str(out)])
    assert res.exit_code == 2, res.output
    assert not out.exists() and list(tmp_path.iterdir()) == []
    assert "Traceback" not in res.output


def test_too_few_after_dropping_nan(tmp_path):
    path = tmp_path / "few.xyz"
    path.write_text("1 2 3\nnan nan nan\n4 5 6\nnan 1 2\n7 nan 9\n")
    with pytest.raises(ValueError, match=r"few\.xyz: 2 points of 5 \(3 with NaN dropped\), need at least 3$"):
        read_cloud_checked(path)
    r = read_cloud_checked(path, min_points=2, hint=False)
    np.testing.assert_array_equal(r.points, [[1, 2, 3], [4, 5, 6]])
    assert (r.n_in_file, r.n_dropped_nonfinite) == (5, 3)


def test_arguments_are_checked(tmp_path):
    path = tmp_path / "a.xyz"
    path.write_text("1 2 3\n4 5 6\n7 8 10\n")
    with pytest.raises(ValueError, match=r"units 'cm': expected one of mm, m, in"):
        read_cloud_checked(path, units="cm")
    with pytest.raises(ValueError, match=r"nonfinite 'keep': expected 'drop' or 'refuse'"):
        read_cloud_checked(path, nonfinite="keep")


def test_binary_ply_with_a_truncated_face_list_after_good_vertices(tmp_path, capfd):
    # RPly reads the 4 vertices, prints an error of its own about the faces, and Open3D
    # returns the cloud; metro walks the face list and refuses the truncated file
    head = (b"ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty double x\nproperty double y\n"
            b"property double z\nelement face 3\nproperty list uchar int vertex_indices\nend_header\n")
    faces = np.array([(3, (0, 1, 2))] * 3, dtype=[("n", "u1"), ("i", "<i4", (3,))]).tobytes()
    vertices = np.arange(12, dtype="<f8").tobytes()
    path = tmp_path / "mesh.ply"
    path.write_bytes(head + vertices + faces)
    np.testing.assert_array_equal(read_cloud(path), np.arange(12.0).reshape(4, 3))
    path.write_bytes(head + vertices + faces[:-3])
    with pytest.raises(ValueError, match=r"mesh\.ply: truncated: the file ends in row 3 of element 'face' \(property 'vertex_indices'\)"):
        read_cloud(path)
    path.write_bytes(head + vertices + faces + b"\0")
    with pytest.raises(ValueError, match=r"mesh\.ply: 1 byte\(s\) after the last element"):
        read_cloud(path)
    assert capfd.readouterr().out == ""


def test_binary_ply_with_mixed_face_sizes_is_walked_row_by_row(tmp_path):
    head = (b"ply\nformat binary_big_endian 1.0\nelement face 2\nproperty list uchar int vertex_indices\n"
            b"element vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n")
    faces = bytes([3]) + np.array([0, 1, 2], ">i4").tobytes() + bytes([4]) + np.array([0, 1, 2, 0], ">i4").tobytes()
    xyz = np.array([[1.5, 2, 3], [4, 5, 6], [7, 8, 9.25]], ">f4")
    path = tmp_path / "mixed.ply"
    path.write_bytes(head + faces + xyz.tobytes())
    np.testing.assert_array_equal(read_cloud(path), xyz.astype(float))
    path.write_bytes(head + faces[:-1] + xyz.tobytes())  # one byte short: the vertices are shifted
    with pytest.raises(ValueError, match=r"mixed\.ply: truncated: the header declares 3 vertices, the file holds 2"):
        read_cloud(path)


def test_empty_ply_error_is_the_only_line_on_stderr(tmp_path):
    # issue 32: numpy's "loadtxt: input contained no data" warning leaked before the error
    r = CliRunner().invoke(app, ["fit-plane", str(BAD / "pcl_empty_cloud.ply")])
    assert r.exit_code == 2
    assert r.stderr.strip().splitlines() == [f"error: {BAD / 'pcl_empty_cloud.ply'}: no points in the file"]
