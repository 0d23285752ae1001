"""The rules that decide a hole's ``status``, in the order they apply, each with its threshold and reason; the
settings holes are judged with; and the tests of the rules that read a hole's figures alone (1b, 3, 3b, 4). One
pose's holes are measured and rules 1 to 2b applied there by :mod:`metrology.measure.measured`; a batch, its two
poses compared and its verdict, by :mod:`metrology.measure.holes`.

1. ``NOT_MEASURED``, fewer than :data:`MIN_SENSORS` usable readings: a plane needs 3 points. A
   blank reading, or one outside the sensor's ``range_mm`` (the sensor's own data are not valid
   there), is not used; with 3 left the hole is measured on those 3, with their larger U95.
1b. ``NOT_MEASURED``, with the panel known, a footprint its local surface cannot represent (a tight
   radius: a leading edge, a lip, a tube): a spot where the surface has turned more than
   :data:`MAX_SPOT_TURN_DEG` from the hole's normal (past the crest), or a beam meeting the surface at
   more than :data:`MAX_INCIDENCE_DEG` of incidence (grazing). Both from the fitted surface at the spots
   (:mod:`metrology.measure.remainder`); the hole's readings are not counted as disagreeing (rule 2):
   the model, not the head, is what fails there. (A footprint whose sampled disc leaves the CAD surface,
   past the crest or off the edge, is refused with the panel: :mod:`metrology.panel.holes`.)
2. ``NOT_MEASURED``, the readings disagree (4 sensors): the redundant reading's misfit ``rho``
   exceeds what any panel of radius >= ``min_radius_mm`` can give (``|M|_* / (2 R)``, the
   nuclear norm of the points' second moments weighted by ``q``) by more than
   :data:`GROSS_SIGMAS` of its standard deviation (the reading noise and the calibration's
   uncertainty: a head within its calibration): one reading is gross (a chip, a burr, a spot on
   an edge), or a sensor has moved far beyond its calibration; no normal from these readings can
   be trusted. (A smaller move is the drift watch's.) A hole whose before-readings disagree but
   whose after-readings are sound is judged on the after-readings (the cell turned the wrong way:
   the after-readings measure what it drilled).
2b. Without the panel (4 sensors, a finite ``min_radius_mm``), a misfit beyond :data:`EDGE_SIGMAS` of its
   standard deviation that rule 2's bound explains is the panel's curvature or one sensor's offset (a burr
   under its spot, alike before and after: the cell drills onto the tilt it gives and the after-readings
   confirm it); one redundant reading cannot tell them apart. The pose's U95 then covers both: the tilt of
   the plane through the other three sensors, the farthest over the sensors, plus that plane's own U95
   (:mod:`metrology.measure.onesensor`), so the hole cannot conform on the offset's tilt; the reason of a
   failing or undecided hole says so (:data:`metrology.measure.reasons.EDGE_TEXT`).
3. ``NOT_MEASURED`` after the adjustment, the readings before and after it disagree (4 sensors,
   both poses read on all 4, neither named gross by rule 2): the same spot of the same panel
   gives both misfits, so they differ only by what the panel's curvature does as the head
   tilts, at most
   ``|M_after - M_before|_* / (2 R) + TILT_ALLOWANCE alpha^2 max(|M|_*) / (2 R)`` (``alpha`` the
   larger angle of the two), and by their reading noise (the calibration's errors move both alike and
   cancel): more than :data:`GROSS_SIGMAS` sigmas beyond that, one of the 8 readings is gross. Which one is not identifiable (a gross before-reading,
   the cell turned by it, and a gross after-reading give the same after-readings to first
   order), so the drilled angle is not known: the hole is not measured after the adjustment,
   with that reason, not failed. (A sensor's zero shift moves both misfits alike: the drift
   watch's, not this rule's.)
3b. ``UNDECIDED``, not ``FAILS``, after the adjustment without the panel: the misfits before and after
   differ by more than :data:`CHANGE_SIGMAS` noise sigmas yet within rule 3's allowance (the before-readings
   sound): two gross after-readings whose misfits cancel in part tilt the normal by any angle, so the failure
   is not shown.
4. ISO 14253-1 (conformity with specifications, the supplier's proof): ``CONFORMS`` when
   ``angle + U95 <= tolerance``, ``FAILS`` when ``angle - U95 > tolerance``, ``UNDECIDED``
   otherwise. The angle judged is the drilled hole's: the one measured after the attitude
   adjustment where the log has after-readings, else the one measured before (a log without
   after-readings is taken as drilled as measured).

A hole is judged on its own row alone, so a batch's results do not depend on how the log was
split into batches or partitions (the Dask path relies on it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from metrology.core.sym2 import nuclear2
from metrology.measure.batch import CODE, Status

if TYPE_CHECKING:
    from metrology.measure.panel import HoleSurfaces

__all__ = ["MIN_SENSORS", "GROSS_SIGMAS", "TILT_ALLOWANCE", "EDGE_SIGMAS", "CHANGE_SIGMAS", "DEFAULT_MIN_RADIUS_MM",
           "MAX_SPOT_TURN_DEG", "MAX_INCIDENCE_DEG", "Settings", "past_footprint", "past_reason", "poses_disagree",
           "verdict"]

#: fewest readings that give a plane
MIN_SENSORS = 3
#: a redundant misfit beyond the panel's possible shape by this many noise sigmas is a gross reading
#: (two-sided p ~ 2e-9 per hole: about one false flag per 5e8 holes)
GROSS_SIGMAS = 6.0
#: rule 3: a panel seen from a head tilted by alpha has its height's curvature in the TCS changed by
#: up to ``1 / cos(alpha)^3 - 1 ~ 1.5 alpha^2`` and its principal axes turned by alpha: twice that
#: bounds both (checked on the forward simulator's spheres and cylinders of R = 500 mm)
TILT_ALLOWANCE = 3.0
#: rule 2b: a redundant misfit beyond the noise by this many sigmas, within the radius bound, may be one sensor's
#: offset as well as the panel's curvature (a burr under one spot, the same before and after): U95 then covers the
#: tilt the offset would give (:mod:`metrology.measure.onesensor`); rule 2's sigmas: a flat panel's clean holes
#: are left alone (p ~ 2e-9 a hole) (benchmarks/results/gross_issue51_item5.md)
EDGE_SIGMAS = GROSS_SIGMAS
#: rule 3b: misfits before and after that differ by more than this many noise sigmas, within rule 3's allowance,
#: may be two gross after-readings whose misfits cancel in part (which tilt the normal by any angle): such a hole
#: is not shown to fail (two-sided p ~ 0.0027 of a failing hole in control) (benchmarks/results/gross_issue51_item5.md)
CHANGE_SIGMAS = 3.0
#: the smallest panel radius the gross-reading rule allows for (mm): aircraft skins are >= 500 mm
DEFAULT_MIN_RADIUS_MM = 500.0
#: rule 1b: a spot where the surface has turned more than this from the hole's normal is past what the local
#: surface (a height over the tangent plane, to degree 8 over the footprint) holds: on a cylinder a spot past
#: 0.71 R from the crest (benchmarks/results/tight_radii.md)
MAX_SPOT_TURN_DEG = 45.0
#: rule 1b: a beam meeting the surface at more than this incidence grazes it: its spot stretched twice or more,
#: a triangulation sensor's reading there is not the one its calibration made
MAX_INCIDENCE_DEG = 60.0


@dataclass(frozen=True)
class Settings:
    """How holes are judged.

    Attributes
    ----------
    tolerance : float, rad, the perpendicularity tolerance (angle between drill axis and normal)
    min_radius_mm : float, mm, the smallest panel radius the gross-reading rule allows for
    """

    tolerance: float = float(np.radians(0.5))
    min_radius_mm: float = DEFAULT_MIN_RADIUS_MM
    #: each hole's local surface (:class:`metrology.measure.panel.HoleSurfaces`, joined by ``hole_id``):
    #: the normal is fitted with the surface known (:mod:`metrology.measure.surface`), not the micro-plane
    surfaces: "HoleSurfaces | None" = None


def past_footprint(spot_turn, incidence):
    """(h,) bool, rule 1b: a spot past the crest or a grazing beam (``spot_turn``, ``incidence`` (h,) rad)."""
    with np.errstate(invalid="ignore"):
        return (spot_turn > np.radians(MAX_SPOT_TURN_DEG)) | (incidence > np.radians(MAX_INCIDENCE_DEG))


def past_reason(spot_turn: float, incidence: float) -> str:
    """Rule 1b's reason for one hole (angles in rad)."""
    why = (f"a spot where the surface has turned {np.degrees(spot_turn):.0f} deg from the hole's normal (more than "
           f"{MAX_SPOT_TURN_DEG:g}: past the crest)" if spot_turn > np.radians(MAX_SPOT_TURN_DEG) else
           f"a beam meeting the surface at {np.degrees(incidence):.0f} deg of incidence (more than "
           f"{MAX_INCIDENCE_DEG:g}: grazing)")
    return f"the footprint is past what the panel's local surface represents: {why}"


def _nuclear2(m):
    """(N,) the nuclear norm of the symmetric 2 x 2 matrices ``m (N, 3)`` as (xx, yy, xy)."""
    return nuclear2(m[:, 0], m[:, 2], m[:, 1])


def poses_disagree(before, after, settings):
    """(N,) bool, rule 3: the before- and after-readings' misfits differ by more than the panel's
    curvature can make them as the head tilts, beyond :data:`GROSS_SIGMAS` sigmas; the difference
    (N,) mm; and (N,) bool, rule 3b: it is beyond :data:`CHANGE_SIGMAS` noise sigmas."""
    R = settings.min_radius_mm
    diff = after.residual - before.residual
    alpha = np.fmax(before.angle, after.angle)
    curve = 0.0 if not np.isfinite(R) else (_nuclear2(after.moment - before.moment)
                                             + TILT_ALLOWANCE * alpha ** 2 * np.fmax(before.twist, after.twist)) / (2 * R)
    sd = np.hypot(before.noise_sd, after.noise_sd)  # noise alone: the calibration's errors move both alike
    sd = np.where(np.isfinite(sd), sd, np.hypot(before.residual_sd, after.residual_sd))
    allowed = curve + GROSS_SIGMAS * sd
    with np.errstate(invalid="ignore"):
        out = np.abs(diff) > allowed
        changed = np.abs(diff) > CHANGE_SIGMAS * sd  # rule 3b
    return out & np.isfinite(allowed) & np.isfinite(diff), diff, changed & np.isfinite(diff)


def verdict(judged, judged_u, tol, sound) -> np.ndarray:
    """(N,) int8, rule 4 (ISO 14253-1) on the angle judged and its U95 (rad; NaN: not measured), rule 1-3's
    holes not measured; ``sound`` (N,) bool, a hole whose readings gave a normal before or after."""
    code = np.full(len(judged), CODE[Status.UNDECIDED], np.int8)
    code[judged + judged_u <= tol] = CODE[Status.CONFORMS]
    code[judged - judged_u > tol] = CODE[Status.FAILS]
    code[~(np.isfinite(judged) & sound)] = CODE[Status.NOT_MEASURED]
    return code
