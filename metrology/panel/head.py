"""The end-effector's head over a drilling point: tool axis, stand-off, tilted feed, placement, beams cast."""

from __future__ import annotations

import math
import numpy as np
from metrology.core.layout import SensorLayout
from metrology.panel.rays import RayCaster


#: the tool axis of a layout is +-z; the mean beam direction must make at most this angle
#: with it (deg)
AXIS_MAX_DEG = 60.0


#: largest initial attitude error accepted (rad): beyond it the head is no longer a head
#: looking at the panel
MAX_TILT = math.radians(45.0)


def tool_axis_tcs(layout: SensorLayout):
    """The tool (feed) axis of a layout in its TCS: ``+e_z`` or ``-e_z``, the side the beams point to.

    Returns
    -------
    a : (3,) float, unit, TCS
    """
    m = layout.direction.mean(axis=0)
    m = m / np.linalg.norm(m)
    if np.degrees(np.arccos(min(1.0, abs(m[2])))) > AXIS_MAX_DEG:
        raise ValueError(f"the layout's beams do not point along the TCS z axis (mean direction {np.round(m, 4).tolist()}); the tool axis must be +-z")
    return np.array([0.0, 0.0, math.copysign(1.0, m[2])])


def default_standoff(layout: SensorLayout) -> float:
    """A stand-off (mm) when none is given.

    The distance along the tool axis from the sensor-zero plane to the TCS origin when the
    origin lies ahead of that plane, between 20 % and 80 % of the way to where the beams
    cross the tool axis (the paper's Table 6: 35 mm, the pressure-foot datum); otherwise
    half the distance to the crossing (Table 2: 43.3 mm, spots at half the foot radius).
    """
    a = tool_axis_tcs(layout)
    z0 = float(np.mean(layout.zero @ a))
    # how far along the axis does each beam reach the axis? (lateral closing rate)
    r = np.linalg.norm(layout.zero[:, :2], axis=1)
    lat = -np.sum(layout.zero[:, :2] * layout.direction[:, :2], axis=1) / np.maximum(r, 1e-12)
    axial = layout.direction @ a
    ok = lat > 1e-6
    if not np.any(ok):
        raise ValueError("the beams do not converge towards the tool axis; give the stand-off explicitly")
    cross = float(np.mean(r[ok] / lat[ok] * axial[ok]))
    if 0.2 * cross <= -z0 <= 0.8 * cross:
        return -z0
    return 0.5 * cross


def _perp_basis(v):
    """Two unit vectors ``(m, 3)`` perpendicular to unit ``v (m, 3)`` and to each other.

    Not :func:`metrology.core.model.direction_basis`: its ``e1`` is another vector of the
    same plane, so the random azimuths of :func:`tilted_feed` would land on other feeds and
    every seeded run would change. Kept so that same seed gives the same bytes as before.
    """
    helper = np.where(np.abs(v[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    e1 = np.cross(v, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(v, e1)


def _rotvec_matrix(rv):
    """Rotation matrices ``(m, 3, 3)`` of rotation vectors ``(m, 3)`` (rad), Rodrigues."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.asarray(rv, float).reshape(-1, 3)).as_matrix()


def tilted_feed(normal, tilt, rng):
    """Feed directions: the inward normal tilted by ``tilt`` about a random azimuth.

    Parameters
    ----------
    normal : (m, 3) float, unit, panel frame, out of the panel
    tilt : float, rad
    rng : numpy.random.Generator

    Returns
    -------
    feed : (m, 3) float, unit, panel frame, into the panel
    """
    n = np.asarray(normal, float)
    e1, e2 = _perp_basis(n)
    az = rng.uniform(0.0, 2 * np.pi, len(n))
    w = np.cos(az)[:, None] * e1 + np.sin(az)[:, None] * e2
    return np.einsum("mij,mj->mi", _rotvec_matrix(w * tilt), -n)


def orientation_from_feed(feed, a_tcs):
    """tcs2panel rotations ``(m, 3, 3)`` that turn the TCS tool axis onto ``feed`` ``(m, 3)``.

    The roll about the axis is fixed so that the TCS x axis lies in the plane of the feed
    and the panel x axis (the panel y axis where the feed is along x).
    """
    f = np.asarray(feed, float)
    ref = np.where(np.abs(f[:, :1]) < 0.95, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    x = ref - np.sum(ref * f, axis=1, keepdims=True) * f
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    # columns: images of TCS x, y, z; TCS z goes to f * sign so that R a_tcs = f
    s = a_tcs[2]
    z = f * s
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=2)


def place_head(points, R, a_tcs, layout: SensorLayout, standoff):
    """TCS origins so that the tool axis meets ``points`` at ``standoff``.

    Parameters
    ----------
    points : (m, 3) float, mm, panel frame, drilling points
    R : (m, 3, 3) float, tcs2panel rotations
    a_tcs : (3,) float, unit, TCS tool axis
    layout : SensorLayout
    standoff : float, mm, from the sensor-zero plane to the drilling point along the axis

    Returns
    -------
    T : (m, 3) float, mm, panel frame
    """
    z0 = float(np.mean(layout.zero @ a_tcs))
    return np.asarray(points, float) - (R @ a_tcs) * (z0 + standoff)


def cast_beams(caster: RayCaster, layout: SensorLayout, R, T):
    """Cast the layout's beams from poses ``(R, T)``.

    Returns
    -------
    d : (m, n) float, mm, readings without noise; NaN where a beam missed or hit from behind
    tri : (m, n) int, face hit, -1 on a miss
    behind : (m, n) bool, the beam hit a face from behind
    """
    m, n = len(T), layout.n
    origins = (np.einsum("mij,nj->mni", R, layout.zero) + T[:, None, :]).reshape(-1, 3)
    dirs = np.einsum("mij,nj->mni", R, layout.direction).reshape(-1, 3)
    tri, t, _ = caster.cast(origins, dirs)
    behind = np.zeros(len(tri), bool)
    hit = tri >= 0
    v = caster.triangles[tri[hit]]  # face normals of the hit faces only (not of the whole mesh)
    fn = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    behind[hit] = np.sum(fn * dirs[hit], axis=1) > 0
    t = np.where(behind | ~hit | (t < 0), np.nan, t)
    return t.reshape(m, n), tri.reshape(m, n), behind.reshape(m, n)
