"""Candidate poses over the datum and the limits every planned pose must keep.

A pose is ``tcs2tracker`` (``p_tracker = R p_tcs + T``). Poses are built the way the paper's
random poses are (section 5, :mod:`metrology.sim.simulation`): the tool axis (the TCS z axis
signed the way the beams point, :func:`~metrology.calibration.uncertainty.tool_axis`) points
into the datum, spun about itself by a uniform angle and tilted from the datum normal by an
angle uniform in ``[0, tilt_max]`` about a uniform in-plane axis; the *stand-off* is the mean
reading the sensors would give on a plane normal to the tool axis, uniform in
``standoff_mm``; the tool axis meets the datum at a point uniform over the measured extent.

A pose is *feasible* when, with the nominal layout, every beam meets the datum inside its
measured extent at least ``spot_margin_mm`` from the edge, every reading lies inside the
sensor's range shrunk by ``reading_margin_mm`` at each end, and the tilt is at most
``tilt_max - tilt_margin``. The margins are what keeps a pose feasible when the robot does
not reach it exactly.

The real sensors are not where the drawing puts them: with a layout tolerance (``zero_tol_mm``
on each coordinate of every zero point, ``direction_tol_rad`` on the angle of every beam from
its nominal direction) a pose is feasible only if the readings of *every* layout within the
tolerance keep the range (less the margin) and their spots the extent: for a beam meeting the
datum at incidence ``gamma`` with nominal reading ``d = h / cos(gamma)``, the reading of a
layout within tolerance lies in ``[(h - e) / cos(gamma - t), (h + e) / cos(gamma + t)]`` with
``e = zero_tol_mm * |n|_1`` (``n`` the datum normal in the TCS) and ``t = direction_tol_rad``
(:func:`reading_bounds`), and its spot moves at most ``(sqrt(3) zero_tol_mm + d_max sin(t)) /
cos(gamma + t)`` on the datum.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.calibration.uncertainty import tool_axis, working_plane
from metrology.core.frames import plane_in_tcs
from metrology.core.layout import SensorLayout
from metrology.core.model import readings
from metrology.core.plane import Plane, plane_basis
from metrology.plan.extent import DatumExtent

__all__ = ["Limits", "PoseSet", "draw_candidates", "feasible", "perturb", "pose_readings", "reading_bounds"]


@dataclass(frozen=True)
class Limits:
    """What a planned pose must keep.

    Attributes
    ----------
    tilt_max_rad : float, rad, largest angle between the tool axis and the datum normal
    standoff_mm : (2,) float, mm, the mean reading on a plane normal to the tool axis
    range_mm : (n, 2) float, mm, each sensor's valid readings
    reading_margin_mm : float, mm, kept from each end of every range
    spot_margin_mm : float, mm, kept from the edge of the measured extent
    tilt_margin_rad : float, rad, kept below ``tilt_max_rad``
    tool_side : float, +1 or -1: the tool is on the side of the datum the plane's normal
        points to (+1) or the other (-1)
    zero_tol_mm : float, mm, the layout's stated uncertainty of each zero-point coordinate
    direction_tol_rad : float, rad, of each beam's angle from its nominal direction
    """

    tilt_max_rad: float
    standoff_mm: tuple
    range_mm: np.ndarray
    reading_margin_mm: float = 2.0
    spot_margin_mm: float = 5.0
    tilt_margin_rad: float = float(np.deg2rad(0.1))
    tool_side: float = 1.0
    zero_tol_mm: float = 0.0
    direction_tol_rad: float = 0.0

    def to_dict(self) -> dict:
        return {"tilt_max_deg": float(np.rad2deg(self.tilt_max_rad)), "standoff_mm": list(map(float, self.standoff_mm)),
                "range_mm": np.asarray(self.range_mm).tolist(), "reading_margin_mm": self.reading_margin_mm,
                "spot_margin_mm": self.spot_margin_mm, "tilt_margin_deg": float(np.rad2deg(self.tilt_margin_rad)),
                "tool_side": "normal" if self.tool_side > 0 else "against",
                "layout_tolerance": {"zero_mm": self.zero_tol_mm, "direction_deg": float(np.rad2deg(self.direction_tol_rad))}}


@dataclass(frozen=True)
class PoseSet:
    """Poses of the TCS in the tracker frame.

    Attributes
    ----------
    rot : (p, 3, 3) float, tcs2tracker rotations
    trans : (p, 3) float, mm, tracker frame, tcs2tracker translations
    tilt : (p,) float, rad, angle between the tool axis and the datum normal, as drawn
    standoff : (p,) float, mm, the stand-off the pose was built for (both kept by :func:`perturb`)
    """

    rot: np.ndarray
    trans: np.ndarray
    tilt: np.ndarray
    standoff: np.ndarray

    def __len__(self) -> int:
        return len(self.trans)

    def select(self, idx) -> "PoseSet":
        idx = np.asarray(idx)
        return PoseSet(self.rot[idx], self.trans[idx], self.tilt[idx], self.standoff[idx])

    def plane_in_tcs(self, plane: Plane):
        """``(p, 3)`` unit normals and ``(p,)`` offsets mm of the datum in each pose's TCS."""
        return plane_in_tcs(plane.normal, plane.offset, self.rot, self.trans)


def _rotvec(v):
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(v).as_matrix()


def _aligning(src, dst):
    """(3, 3) rotation taking unit ``src`` onto unit ``dst`` (the shortest one; a half turn about
    an axis perpendicular to ``src`` when they are opposite)."""
    axis = np.cross(src, dst)
    s, c = np.linalg.norm(axis), float(src @ dst)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = np.eye(3)[np.argmin(np.abs(src))]
        perp = perp - (perp @ src) * src
        return _rotvec(np.pi * perp / np.linalg.norm(perp))
    return _rotvec(axis / s * np.arctan2(s, c))


def draw_candidates(rng: np.random.Generator, layout: SensorLayout, plane: Plane, extent: DatumExtent, n: int,
                    limits: Limits) -> PoseSet:
    """``n`` random poses of the paper's kind (module docstring), feasible or not.

    Parameters
    ----------
    rng : numpy.random.Generator
    layout : SensorLayout, nominal
    plane : Plane, tracker frame
    extent : DatumExtent, where the tool axis may meet the datum
    n : int
    limits : Limits, its ``tilt_max_rad``, ``standoff_mm`` and ``tool_side``

    Returns
    -------
    PoseSet
    """
    a = tool_axis(layout)
    m = limits.tool_side * plane.normal  # from the datum toward the tool
    R0 = _aligning(a, -m)
    basis = plane_basis(plane.normal)
    spin = rng.uniform(0.0, 2 * np.pi, n)
    tilt = rng.uniform(0.0, limits.tilt_max_rad, n)
    az = rng.uniform(0.0, 2 * np.pi, n)
    standoff = rng.uniform(*limits.standoff_mm, size=n)
    centre = extent.sample(rng, n)
    w = np.cos(az)[:, None] * basis[0] + np.sin(az)[:, None] * basis[1]
    R = _rotvec(w * tilt[:, None]) @ R0 @ _rotvec(a[None] * spin[:, None])
    h = np.array([-working_plane(layout, s)[1][0] for s in standoff])  # tool-axis distance to the datum
    T = centre - h[:, None] * (R @ a)
    return PoseSet(R, T, tilt, standoff)


def pose_readings(layout: SensorLayout, plane: Plane, poses: PoseSet):
    """Readings and spots of ``layout`` on the datum plane at every pose.

    Returns
    -------
    d : (p, n) float, mm; NaN where the beam misses the plane
    spots : (p, n, 3) float, mm, tracker frame
    """
    N, D = poses.plane_in_tcs(plane)
    d, _ = readings(layout.zero, layout.direction, N, D)
    S = layout.zero[None] + d[..., None] * layout.direction[None]
    return d, np.einsum("pij,pnj->pni", poses.rot, S) + poses.trans[:, None, :]


def reading_bounds(layout: SensorLayout, plane: Plane, poses: PoseSet, zero_tol_mm: float, direction_tol_rad: float):
    """The readings of every layout within the tolerance (module docstring), at every pose.

    Returns
    -------
    d_lo, d_hi : (p, n) float, mm; NaN where a beam within the tolerance may miss the datum
    spot_shift : (p, n) float, mm, how far the spot may move on the datum
    """
    N, _ = poses.plane_in_tcs(plane)
    d, _ = pose_readings(layout, plane, poses)
    cos_g = np.abs(np.einsum("pk,nk->pn", N, layout.direction))
    h = d * cos_g  # the zero point's distance to the datum
    gamma = np.arccos(np.clip(cos_g, 0.0, 1.0))
    e = zero_tol_mm * np.abs(N).sum(axis=1)[:, None]
    t = direction_tol_rad
    far = gamma + t < np.pi / 2
    with np.errstate(divide="ignore", invalid="ignore"):
        d_hi = np.where(far, (h + e) / np.cos(np.minimum(gamma + t, np.pi / 2)), np.nan)
        d_lo = np.where(far, (h - e) / np.cos(np.maximum(gamma - t, 0.0)), np.nan)
        # a moved origin moves the spot by at most |dz| / cos(gamma'), a turned beam by d' sin(t) / cos(gamma')
        shift = (np.sqrt(3.0) * zero_tol_mm + d_hi * np.sin(t)) / np.cos(np.minimum(gamma + t, np.pi / 2))
    return d_lo, d_hi, shift


def feasible(layout: SensorLayout, plane: Plane, extent: DatumExtent, poses: PoseSet, limits: Limits,
             margins: bool = True) -> np.ndarray:
    """``(p,)`` bool: the poses that keep every limit (with the margins and the layout tolerance
    unless ``margins`` is False).

    The tilt is measured from the poses' rotations, not taken from how they were drawn.
    """
    d, spots = pose_readings(layout, plane, poses)
    rm, sm, tm = (limits.reading_margin_mm, limits.spot_margin_mm, limits.tilt_margin_rad) if margins else (0, 0, 0)
    lo, hi = limits.range_mm[:, 0] + rm, limits.range_mm[:, 1] - rm
    ok = np.all(np.isfinite(d) & (d >= lo) & (d <= hi), axis=1)
    if margins and (limits.zero_tol_mm > 0 or limits.direction_tol_rad > 0):
        d_lo, d_hi, shift = reading_bounds(layout, plane, poses, limits.zero_tol_mm, limits.direction_tol_rad)
        ok &= np.all(np.isfinite(d_lo) & np.isfinite(d_hi) & (d_lo >= lo) & (d_hi <= hi), axis=1)
        sm = sm + np.nan_to_num(shift, nan=np.inf)
    ok &= np.all(extent.inside(spots, sm), axis=1)
    a = tool_axis(layout)
    cos = np.clip((poses.rot @ a) @ (-limits.tool_side * plane.normal), -1.0, 1.0)
    ok &= np.arccos(cos) <= limits.tilt_max_rad - tm + 1e-12
    return ok


def perturb(rng: np.random.Generator, poses: PoseSet, error_mm: float, error_rad: float) -> PoseSet:
    """Where the robot may really go: each pose moved by ``error_mm`` (tracker frame) in a random
    direction and turned by ``error_rad`` about a random axis (TCS)."""
    p = len(poses)
    v = rng.normal(size=(p, 3))
    w = rng.normal(size=(p, 3))
    v *= error_mm / np.linalg.norm(v, axis=1, keepdims=True)
    w *= error_rad / np.linalg.norm(w, axis=1, keepdims=True)
    return PoseSet(poses.rot @ _rotvec(w), poses.trans + v, poses.tilt, poses.standoff)
