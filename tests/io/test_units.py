"""The unit guess (metrology.io.units.infer_units) judges extent, spacing and position together
and says nothing when the evidence is weak (issue 32): real clouds (PCL's bunny in metres,
PCL's octants) and clouds built to the sizes the issue names."""

from pathlib import Path

import numpy as np
import pytest

from metrology.io.clouds import read_cloud
from metrology.io.units import infer_units

DATA = Path(__file__).resolve().parents[1] / "data" / "clouds"


def _plate(rng, side_u, side_v, step, noise):
    g = np.stack(np.meshgrid(np.arange(0, side_u, step), np.arange(0, side_v, step)), -1).reshape(-1, 2)
    return np.column_stack([g, rng.normal(0, noise, len(g))])


def _box_surfaces(rng, size, n):
    """n points uniformly on the faces of an axis-aligned box ``size (3,)`` (a room's walls)."""
    size = np.asarray(size, float)
    areas = np.array([size[1] * size[2], size[0] * size[2], size[0] * size[1]]).repeat(2)
    face = rng.choice(6, n, p=areas / areas.sum())
    p = rng.uniform(0, 1, (n, 3)) * size
    axis = face // 2
    p[np.arange(n), axis] = np.where(face % 2, size[axis], 0.0)
    return p


def test_metres_are_told_where_only_metres_are_plausible(rng):
    bunny = read_cloud(DATA / "pcl_bunny.pcd")  # the Stanford bunny, 0.15 m across
    assert infer_units(bunny).likely == "m"
    one_metre_plate = _plate(rng, 1.0, 1.0, 0.005, 5e-5)  # a 1 m plate scanned every 5 mm, in metres
    h = infer_units(one_metre_plate)
    assert h.likely == "m" and h.sentence.endswith("looks like metres; pass --units m")
    assert h.spacing == pytest.approx(0.005, rel=1e-4)


def test_mm_is_told_where_only_mm_is_plausible(rng):
    plate = _plate(rng, 400, 300, 2.0, 0.02)
    h = infer_units(plate)
    assert h.likely == "mm" and h.sentence.endswith("consistent with mm")


@pytest.mark.parametrize("case", ["room_29m", "utm_ground", "identical", "octants", "cube_corners"])
def test_weak_evidence_says_nothing(rng, case):
    if case == "room_29m":  # a 29 x 8 x 3 m room's walls, 10^6 returns, in metres: also a 29 mm part
        pts = _box_surfaces(rng, [29.0, 8.0, 3.0], 1_000_000)
    elif case == "utm_ground":  # 200 x 200 m of ground every 0.3 m in UTM metres: a map, not a part in mm
        xy = rng.uniform(0, 200, (100_000, 2)) + [452_000.0, 5_411_000.0]
        pts = np.column_stack([xy, rng.normal(300.0, 0.1, len(xy))])
    elif case == "identical":
        pts = np.full((500, 3), 12.5)
    elif case == "octants":  # PCL test/octants.pcd: 8 points
        pts = read_cloud(DATA / "pcl_octants.pcd")
    else:  # PCL test/cube.ply: a 2 x 2 x 2 cube's 24 vertices (8 corners, each thrice)
        pts = read_cloud(DATA / "pcl_cube.ply")
    h = infer_units(pts)
    assert h.likely is None, h.sentence
    assert h.sentence.endswith("the size does not tell the unit")
