"""Real clouds from other projects' test suites (trimesh, PCL; see tests/data/README.md) are
read with the right count, first and last point as the file's text says; NaN points of an
organized scan are dropped and counted; any well-formed ASCII PLY round-trips exactly; the
unit hint tells metres from mm."""

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from metrology.io.clouds import CloudRead, read_cloud, read_cloud_checked
from metrology.io.units import infer_units

DATA = Path(__file__).resolve().parents[1] / "data" / "clouds"


def _text_rows(path):
    """(n, xyz rows as written) from an ASCII PLY/PCD or a text cloud, by plain text reading:
    the header's count, the vertex/point rows, the x, y, z columns by the header's order."""
    lines = path.read_text().splitlines()
    if path.suffix == ".ply":
        end = lines.index("end_header") if "end_header" in lines else [i for i, s in enumerate(lines) if s.strip() == "end_header"][0]
        head = [s.split() for s in lines[:end]]
        n = int(next(t[2] for t in head if t[:2] == ["element", "vertex"]))
        start = next(i for i, t in enumerate(head) if t[:2] == ["element", "vertex"])
        names = []
        for t in head[start + 1:]:
            if t[0] == "element":
                break
            if t[0] == "property":
                names.append(t[-1])
        rows = lines[end + 1:end + 1 + n]
    elif path.suffix == ".pcd":
        data = next(i for i, s in enumerate(lines) if s.startswith("DATA"))
        names = next(s.split()[1:] for s in lines if s.startswith("FIELDS"))
        n = int(next(s.split()[1] for s in lines if s.startswith("POINTS")))
        rows = lines[data + 1:data + 1 + n]
    else:
        rows = [s for s in lines if s.strip()]
        names, n = ["x", "y", "z"], len(rows)
    cols = [names.index(a) for a in "xyz"]
    xyz = np.array([[float(r.split()[c]) for c in cols] for r in rows])
    return n, xyz


ASCII_FILES = ["trimesh_points_ascii.ply", "trimesh_points_ascii_with_lists.ply", "trimesh_multi.ply",
               "trimesh_metadata.ply", "pcl_octants.pcd", "pcl_bunny.pcd",
               "trimesh_points_agisoft.xyz", "trimesh_points_cloudcompare.xyz"]


@pytest.mark.parametrize("name", ASCII_FILES)
def test_real_ascii_file_count_first_last(name):
    n, xyz = _text_rows(DATA / name)
    pts = read_cloud(DATA / name)
    assert pts.shape == (n, 3)
    np.testing.assert_array_equal(pts[0], xyz[0])
    np.testing.assert_array_equal(pts[-1], xyz[-1])
    np.testing.assert_array_equal(pts, xyz)


def test_real_binary_ply_equals_its_ascii_twin():
    # trimesh ships the same 5 points as ASCII and as binary float32 (with an empty face list)
    ascii_pts = read_cloud(DATA / "trimesh_points_ascii.ply")
    binary = read_cloud(DATA / "trimesh_points_bin.ply")
    assert binary.shape == (5, 3)
    np.testing.assert_array_equal(binary, ascii_pts.astype(np.float32).astype(float))


def test_real_binary_ply_with_faces_decoded_independently():
    # trimesh's tet.ply: binary little-endian, 4 float x y z vertices, then a face list
    path = DATA / "trimesh_tet.ply"
    raw = path.read_bytes()
    body = raw.index(b"end_header\n") + len(b"end_header\n")
    xyz = np.frombuffer(raw, dtype="<f4", count=12, offset=body).reshape(4, 3).astype(float)
    np.testing.assert_array_equal(read_cloud(path), xyz)


def test_real_binary_pcd_decoded_independently():
    path = DATA / "pcl_office1_keypoints.pcd"
    raw = path.read_bytes()
    body = raw.index(b"DATA binary\n") + len(b"DATA binary\n")
    rec = np.frombuffer(raw, dtype="<f4", offset=body).reshape(-1, 4)  # x y z intensity, F 4 each
    pts = read_cloud(path)
    assert pts.shape == (1318, 3) == (len(rec), 3)
    np.testing.assert_array_equal(pts[[0, -1]], rec[[0, -1], :3].astype(float))


def test_real_binary_compressed_pcd_count():
    path = DATA / "pcl_noisy_slice_displaced.pcd"
    pts = read_cloud(path)
    assert pts.shape == (3782, 3) and np.isfinite(pts).all()


def test_organized_scan_nan_points_dropped_and_counted():
    path = DATA / "pcl_mug_organized_nan_crop.pcd"
    lines = path.read_text().splitlines()
    rows = lines[lines.index("DATA ascii") + 1:]
    assert len(rows) == 768  # WIDTH 32 x HEIGHT 24
    nan_rows = [i for i, r in enumerate(rows) if "nan" in r]
    finite = np.array([[float(v) for v in r.split()] for r in rows if "nan" not in r])
    r = read_cloud_checked(path)
    assert isinstance(r, CloudRead)
    assert (r.n_in_file, r.n_dropped_nonfinite) == (768, len(nan_rows))
    np.testing.assert_array_equal(r.points, finite)
    assert r.to_dict()["n_dropped_nonfinite"] == len(nan_rows)
    # the strict reader (read_cloud) refuses the first NaN point by its number
    with pytest.raises(ValueError, match=rf"point {nan_rows[0] + 1} is \[nan, nan, nan\]: coordinates must be finite"):
        read_cloud(path)


def test_units_hint_and_scaling(rng):
    bunny = read_cloud_checked(DATA / "pcl_bunny.pcd")  # the Stanford bunny, in metres
    assert bunny.units_hint.likely == "m" and "pass --units m" in bunny.units_hint.sentence
    in_mm = read_cloud_checked(DATA / "pcl_bunny.pcd", units="m")
    np.testing.assert_array_equal(in_mm.points, bunny.points * 1000.0)
    assert in_mm.units == "m"
    inch = read_cloud_checked(DATA / "pcl_octants.pcd", units="in")
    np.testing.assert_array_equal(inch.points, read_cloud(DATA / "pcl_octants.pcd") * 25.4)
    # a 400 x 300 mm plate sampled every 2 mm with 0.02 mm noise: mm; the same in metres: m
    g = np.stack(np.meshgrid(np.arange(0, 400, 2.0), np.arange(0, 300, 2.0)), -1).reshape(-1, 2)
    plate = np.column_stack([g, rng.normal(0, 0.02, len(g))])
    assert infer_units(plate).likely == "mm"
    hint = infer_units(plate / 1000)
    assert hint.likely == "m"
    assert hint.spacing == pytest.approx(0.002, rel=0.05)
    assert hint.noise == pytest.approx(2e-5, rel=0.1)  # n = 30000: RMS within a few %


_TYPES = {"char": (-128, 127), "uchar": (0, 255), "short": (-32768, 32767), "ushort": (0, 65535),
          "int": (-2**31, 2**31 - 1), "uint": (0, 2**32 - 1), "int16": (-32768, 32767), "uint8": (0, 255)}
_FLOATS = ["float", "double", "float32", "float64"]


@st.composite
def ascii_ply(draw):
    n = draw(st.integers(3, 25))
    extra = draw(st.lists(st.sampled_from(list(_TYPES) + _FLOATS), max_size=3))
    props = [(t, a) for t, a in zip(draw(st.lists(st.sampled_from(_FLOATS), min_size=3, max_size=3)), "xyz")]
    props += [(t, f"p{i}") for i, t in enumerate(extra)]
    props = draw(st.permutations(props))
    with_list = draw(st.booleans())
    faces = draw(st.integers(0, 3))
    faces_first = draw(st.booleans())

    def value(t):
        if t in _TYPES:
            lo, hi = _TYPES[t]
            return str(draw(st.integers(lo, hi)))
        width = 32 if t in ("float", "float32") else 64
        return repr(float(draw(st.floats(allow_nan=False, allow_infinity=False, width=width))))

    head = ["ply", "format ascii 1.0"] + draw(st.lists(st.sampled_from(["comment made by hypothesis", "obj_info x y z", "comment"]), max_size=2))
    face_head = [f"element face {faces}", "property list uchar int vertex_indices"]
    vert_head = [f"element vertex {n}"] + [f"property {t} {a}" for t, a in props]
    if with_list:
        vert_head.append("property list ushort short nbrs")
    rows, xyz = [], []
    for _ in range(n):
        vals = {a: value(t) for t, a in props}
        row = [vals[a] for _, a in props]
        if with_list:
            k = draw(st.integers(0, 3))
            row += [str(k)] + [value("short") for _ in range(k)]
        rows.append(" ".join(row))
        xyz.append([float(vals[a]) for a in "xyz"])
    face_rows = [" ".join(["3"] + [str(draw(st.integers(0, n - 1))) for _ in range(3)]) for _ in range(faces)]
    body = (face_rows + rows) if faces_first else (rows + face_rows)
    header = head + ((face_head + vert_head) if faces_first else (vert_head + face_head)) + ["end_header"]
    newline = draw(st.sampled_from(["\n", "\r\n"]))
    text = newline.join(header + body) + newline + draw(st.sampled_from(["", newline]))
    return text, np.array(xyz)


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=ascii_ply())
def test_any_well_formed_ascii_ply_round_trips_exactly(tmp_path_factory, case):
    text, xyz = case
    path = tmp_path_factory.mktemp("ply") / "c.ply"
    path.write_bytes(text.encode("ascii"))
    np.testing.assert_array_equal(read_cloud(path), xyz)


# issue 32: files the format's own readers read, where the points are unambiguous

def test_rply_input_with_a_row_after_the_last_element_is_read_as_rply_reads_it():
    # RPly's own test input (Open3D 3rdparty/rply/etc/input.ply): `element face 1` then two
    # face rows; the second (line 16) cannot be a vertex row (4 values for x y z)
    r = read_cloud_checked(DATA / "rply_input.ply", hint=False)
    np.testing.assert_array_equal(r.points, [[-1, 0, 0], [0, 1, 0], [1, 0, 0]])
    assert r.ignored_lines == (16,)
    assert r.to_dict()["ignored_lines"] == [16]


def test_pcl_comment_at_the_end_is_read_as_pcl_reads_it():
    # PCL test/io/test_ply_io.cpp CommentAtTheEnd: 'comment hi' after the 4 vertex rows;
    # its third point has a NaN intensity (not a coordinate: kept)
    r = read_cloud_checked(DATA / "pcl_comment_at_the_end.ply", hint=False)
    np.testing.assert_array_equal(r.points, [[4.23607, 0, 1.61803], [2.61803, 2.61803, 0], [0, 1.61803, 4.23607],
                                             [0, -1.61803, 4.23607]])
    assert (r.ignored_lines, r.n_dropped_nonfinite) == ((13,), 0)


def test_a_trailing_line_that_parses_as_a_vertex_row_is_still_refused(tmp_path):
    text = (DATA / "pcl_comment_at_the_end.ply").read_text().replace("comment hi", "1 2 3 4")
    path = tmp_path / "count_too_small.ply"
    path.write_text(text)
    with pytest.raises(ValueError, match=r"line 13: '1 2 3 4' after the last element \(4 vertex\), a row of element 'vertex'"):
        read_cloud(path)


def test_pcl_complex_ascii_pcd_with_padding_fields():
    # PCL test/io/test_io.cpp ComplexPCDFileASCII: FIELDS fpfh _ x y z, the `_` field TYPE F
    # SIZE 1 COUNT 10 (padding, skipped); PCL expects x, y, z = -69.234001 -65.460999 19.173
    r = read_cloud_checked(DATA / "pcl_complex_ascii.pcd", min_points=1, hint=False)
    np.testing.assert_array_equal(r.points, [[-69.234001, -65.460999, 19.173]])


def test_binary_pcd_with_pcl_point_xyz_padding():
    # PCL's PointXYZ layout in binary: FIELDS x y z _, the padding's 4 bytes skipped
    pts = read_cloud(DATA / "pcl_xyz_padding_binary.pcd")
    np.testing.assert_array_equal(pts, np.array([[1.5, -2.25, 3], [1000.125, 2000.5, -14.75], [0, 0.001, 7],
                                                 [-5.5, 6.5, 1690.25]], dtype=np.float32).astype(float))


@pytest.mark.parametrize("order", ["<", ">"])
@pytest.mark.parametrize("layout", ["xyz_double", "float_with_extras"])
def test_binary_ply_read_by_numpy(tmp_path, order, layout):
    from metrology.io._o3d import open3d

    rng = np.random.default_rng(3)
    xyz = rng.normal(0, 100, (1000, 3))
    if layout == "xyz_double":
        props, rec = "property double x\nproperty double y\nproperty double z\n", xyz.astype(order + "f8")
    else:
        props = "property uchar red\nproperty float z\nproperty float x\nproperty double t\nproperty float y\n"
        rec = np.zeros(len(xyz), dtype=[("red", "u1"), ("z", order + "f4"), ("x", order + "f4"), ("t", order + "f8"),
                                        ("y", order + "f4")])
        rec["x"], rec["y"], rec["z"], rec["red"] = xyz[:, 0], xyz[:, 1], xyz[:, 2], 7
    fmt = "binary_little_endian" if order == "<" else "binary_big_endian"
    path = tmp_path / "c.ply"
    path.write_bytes(f"ply\nformat {fmt} 1.0\nelement vertex {len(xyz)}\n{props}end_header\n".encode() + rec.tobytes())
    ours = read_cloud(path)
    if layout == "xyz_double":
        np.testing.assert_array_equal(ours, xyz)
        np.testing.assert_array_equal(ours, np.asarray(open3d().io.read_point_cloud(str(path)).points))
    else:  # Open3D 0.20 aborts on this layout ("RPly: Aborted by user") and returns garbage
        np.testing.assert_array_equal(ours, xyz.astype(np.float32).astype(float))
