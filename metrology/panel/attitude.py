"""The attitude loop (paper Eqs. 20-22): measure the normal, turn the head onto it, repeat."""

from __future__ import annotations

import math
from dataclasses import dataclass
import numpy as np
from metrology.core.normals import angle_between, attitude_angles, micro_plane_normal, rot_x, rot_y
from metrology.core.sphere import SPHERE_PRIOR_RADIUS_MM, micro_sphere_normal
from metrology.panel.head import _rotvec_matrix, cast_beams, place_head, tool_axis_tcs
from metrology.panel.head_terms import corrected, with_terms


#: attitude loop: at most this many adjustments per point
MAX_ADJUSTMENTS = 10


#: per-point status codes, in order of precedence
STATUS = {
    "ok": "measured",
    "off_panel": "drilling point is farther than the tolerance from the panel",
    "approach_behind": "approach direction points out of the panel (head behind the panel)",
    "spot_crease": "a spot lies on the other side of a crease",
    "spot_bend": "a spot lies where the surface has turned more than the crease angle (a bend tighter than the head)",
    "footprint_crease": "the head's footprint crosses a crease",
    "footprint_hole": "the head's footprint crosses a hole",
    "footprint_boundary": "the head's footprint crosses the panel boundary",
    "beam_miss": "a beam missed the panel",
    "beam_behind": "a beam hit the panel from behind",
    "out_of_range": "a reading is outside the sensor's range",
}


@dataclass(frozen=True)
class MotionError:
    """The robot's error in executing an attitude adjustment.

    The executed rotation vector is ``(1 + scale g) w + repeat h`` for a commanded ``w``
    (``g ~ N(0, 1)``, ``h ~ N(0, I3)``), and the tool centre point lands
    ``position_mm N(0, I3)`` off (then back on the surface along the tool axis).

    Attributes
    ----------
    repeat : float, rad, 1 sigma per axis
    scale : float, unitless, 1 sigma relative error of the commanded rotation
    position_mm : float, mm, 1 sigma per axis
    """

    repeat: float = math.radians(0.02)
    scale: float = 0.03
    position_mm: float = 0.05

    def __post_init__(self):
        for k in ("repeat", "scale", "position_mm"):
            v = getattr(self, k)
            if not (v >= 0 and math.isfinite(v)):
                raise ValueError(f"motion error {k} must be a finite number >= 0, got {v}")


def _readings(caster, layout_true, R, T, noise, rng, offsets=None):
    """Noisy readings from poses ``(R, T)``; ``offsets`` the true head's terms
    (:func:`metrology.panel.head_terms.with_terms`), or None.

    Returns
    -------
    d : (m, n) float, mm, with noise; NaN for every sensor of a pose with a bad beam
    miss, behind, out_of_range : (m, n) bool, per beam (a beam is counted in one only)
    tri : (m, n) int, the face each beam hit, -1 on a miss
    """
    d, tri, behind = cast_beams(caster, layout_true, R, T)
    d = with_terms(d, offsets, caster, layout_true, R, tri)
    miss = tri < 0
    beh = behind & ~miss
    d = d + rng.standard_normal(d.shape) * noise
    lo, hi = layout_true.range_mm[:, 0], layout_true.range_mm[:, 1]
    oor = ((d < lo) | (d > hi)) & ~miss & ~beh
    bad = np.any(miss | beh | oor, axis=1)
    return np.where(bad[:, None], np.nan, d), miss, beh, oor, tri


def _beam_detail(names, miss, beh, oor):
    """Per pose, which beams failed and why (``"L3 missed; L4 out of range"``), '' if none."""
    out = []
    for i in range(len(miss)):
        parts = []
        for mask, what in ((miss[i], "missed"), (beh[i], "hit from behind"), (oor[i], "out of range")):
            if np.any(mask):
                parts.append(" ".join(n for n, b in zip(names, mask) if b) + " " + what)
        out.append("; ".join(parts))
    return out


def _normal_from(layout_est, a_tcs, R, d, method, noise_mm=0.0, prior_radius_mm=SPHERE_PRIOR_RADIUS_MM):
    """Normal by ``method`` ("plane" or "sphere") from readings ``d (m, n)``.

    Returns
    -------
    n : (m, 3) float, unit, panel frame, out of the panel; NaN where d has NaN
    radius : (m,) float, mm (inf for the plane)
    """
    d = corrected(layout_est, d)  # the layout's head terms removed
    if method == "plane":
        n_tcs = micro_plane_normal(layout_est.zero, layout_est.direction, d)
        rad = np.full(len(d), np.inf)
    elif method == "sphere":
        n_tcs, rad, _, _ = micro_sphere_normal(layout_est.zero, layout_est.direction, d, axis=a_tcs,
                                               noise_mm=noise_mm, prior_radius_mm=prior_radius_mm)
    else:
        raise ValueError(f"method must be 'plane' or 'sphere', got {method!r}")
    return np.einsum("mij,mj->mi", R, n_tcs), rad


def _axis_surface(caster, panel, P_axis, f):
    """Where the tool axis through ``P_axis`` along ``f`` meets the panel, and the normal there."""
    tri, t, bary = caster.cast(P_axis - 50.0 * f, f)
    hit = tri >= 0
    pts = np.where(hit[:, None], P_axis - 50.0 * f + np.nan_to_num(t)[:, None] * f, P_axis)
    nrm = np.full_like(pts, np.nan)
    if np.any(hit):
        nrm[hit] = panel.reference_normal_at(tri[hit], bary[hit])[0]
    if panel.surface is not None:
        exact = panel.surface.normal(pts)
        # a B-rep face's orientation is its own: the outside is the mesh's
        exact *= np.where(np.sum(exact * np.nan_to_num(nrm), axis=1) < 0, -1.0, 1.0)[:, None]
        nrm = np.where(hit[:, None], exact, nrm)
    return pts, nrm, hit


def _feed_frame(a_tcs):
    """``F`` (3, 3): TCS to a frame whose +z is the tool axis (identity or Rot(X, pi))."""
    return np.eye(3) if a_tcs[2] > 0 else np.diag([1.0, -1.0, -1.0])


def attitude_loop(caster, panel, layout_true, layout_est, points, R0, standoff, noise, rng, method,
                  tolerance, motion: MotionError, max_adjustments=MAX_ADJUSTMENTS,
                  prior_radius_mm=SPHERE_PRIOR_RADIUS_MM, offsets=None):
    """The attitude loop of section 4.2 (Eqs. 20-22) at many points at once.

    At each step the head measures the normal (``method``: "plane" or "sphere"); if the
    measured deviation between the tool axis and the normal is under ``tolerance`` the point
    is done; otherwise the robot turns the TCS by ``Rot(Y, theta) Rot(X, phi)`` of Eq. 22
    (in a frame whose +z is the tool axis), with ``motion`` errors, pivoting about the
    drilling point, and measures again.

    Parameters
    ----------
    points : (m, 3) float, mm, panel frame
    R0 : (m, 3, 3) float, initial tcs2panel rotations
    standoff : float, mm
    noise : (n,) float, mm, reading noise 1 sigma
    tolerance : float, rad
    rng : numpy.random.Generator
    offsets : the true head's terms (:func:`metrology.panel.head_terms.with_terms`), or None

    Returns
    -------
    dict of arrays (m,): ``iterations`` (adjustments made), ``converged`` (bool),
    ``measured_dev`` (rad, last measured), ``final_dev`` (rad, true deviation of the final
    tool axis from the true normal where it meets the panel), ``theta``, ``phi`` (rad, the
    first adjustment; 0 where none was needed), ``lost`` (a beam missed during the loop)
    """
    a_tcs = tool_axis_tcs(layout_est)
    F = _feed_frame(a_tcs)
    m = len(points)
    R = np.array(R0, float)
    P = np.array(points, float)
    it = np.zeros(m, int)
    done = np.zeros(m, bool)
    lost = np.zeros(m, bool)
    mdev = np.full(m, np.nan)
    theta0 = np.zeros(m)
    phi0 = np.zeros(m)
    for k in range(max_adjustments + 1):
        act = ~done & ~lost
        if not np.any(act):
            break
        Ra, Pa = R[act], P[act]
        T = place_head(Pa, Ra, a_tcs, layout_est, standoff)
        d = _readings(caster, layout_true, Ra, T, noise, rng, offsets)[0]
        n_meas, _ = _normal_from(layout_est, a_tcs, Ra, d, method, float(np.mean(noise)), prior_radius_mm)
        bad = ~np.all(np.isfinite(n_meas), axis=1)
        f = Ra @ a_tcs
        dev = angle_between(f, -np.nan_to_num(n_meas), oriented=True)
        idx = np.flatnonzero(act)
        lost[idx[bad]] = True
        mdev[idx[~bad]] = dev[~bad]
        ok_now = ~bad & (dev < tolerance)
        done[idx[ok_now]] = True
        go = ~bad & ~ok_now
        if k == max_adjustments or not np.any(go):
            break
        # Eq. 22 in the feed frame: the inward measured normal, expressed there
        n_in_tcs = np.einsum("mji,mj->mi", Ra[go], -n_meas[go])
        n_feed = n_in_tcs @ F.T
        theta, phi = attitude_angles(n_feed)
        first = it[idx[go]] == 0
        theta0[idx[go][first]] = theta[first]
        phi0[idx[go][first]] = phi[first]
        adj = np.stack([F.T @ rot_y(th) @ rot_x(ph) @ F for th, ph in zip(theta, phi)])
        from scipy.spatial.transform import Rotation

        w = Rotation.from_matrix(adj).as_rotvec()  # commanded, TCS
        g = rng.standard_normal(len(w))
        h = rng.standard_normal(w.shape)
        w_exec = (1 + motion.scale * g)[:, None] * w + motion.repeat * h
        Rn = Ra[go] @ _rotvec_matrix(w_exec)
        # the TCP pivots about the drilling point, lands a little off, back onto the panel
        fn = Rn @ a_tcs
        Pn = Pa[go] + motion.position_mm * rng.standard_normal((int(go.sum()), 3))
        Pn, _, hit = _axis_surface(caster, panel, Pn, fn)
        lost[idx[go][~hit]] = True
        R[idx[go]] = Rn
        P[idx[go]] = Pn
        it[idx[go]] += 1
    f = R @ a_tcs
    _, n_true, hit = _axis_surface(caster, panel, P, f)
    final = angle_between(f, -np.nan_to_num(n_true), oriented=True)
    final[~hit] = np.nan
    return {"iterations": it, "converged": done, "measured_dev": mdev, "final_dev": final,
            "theta": theta0, "phi": phi0, "lost": lost | ~hit}
