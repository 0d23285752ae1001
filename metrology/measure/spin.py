"""The head's spin about the tool axis with the panel known: from the robot's commanded pose, from a
convention the redundant reading confirms, or not known: never assumed silently.

The local surface's shape operator is put into the TCS by the head's rotation. The commanded pose
(the log's ``pose_*`` columns) gives it whole. Without it metro can take the cell's convention (TCS
``x, y`` near the panel's, the spin within ``+-spin``: ``--spin-deg``), but a cell that turns the
head for reach breaks it, and the curvature then tilts the normal the wrong way. So, per hole
without a pose (rule 1b of :mod:`metrology.measure.holes`):

- **a redundant reading** (4 sensors read): the hole is measured in the convention and its misfit to
  the CAD's surface there (``panel_misfit_z``: the redundant reading's misfit over its standard
  deviation from the noise, the calibration, the panel's terms and the spin within ``+-spin``) tested:
  beyond :data:`SPIN_SIGMAS` the convention does not hold at that hole, and the hole is judged with
  the spin not known;
- **no redundancy** (3 readings): the convention where it is stated (``--spin-deg``), else the spin not
  known;
- **the spin not known** (:class:`metrology.measure.surface.PanelTerms` ``free``): the shape's
  isotropic part (the mean curvature, the same at every spin) is fitted, and its deviatoric part, of
  known size ``(k1 - k2) / 2`` and unknown direction, enters the budget as a bound over every spin;
  the redundant reading's gross-reading allowance takes the most it moves the misfit.

The reason column says which holes were judged with the spin not known, the summary how many rest on
the convention.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from metrology.measure.normals import HoleNormals, concat_normals

if TYPE_CHECKING:
    from metrology.measure.surface import PanelFit

__all__ = ["SPIN_SIGMAS", "DEFAULT_SPIN_DEG", "SpinJudged", "panel_normals"]

#: a redundant reading's misfit to the CAD's surface beyond this many of its standard deviations, the
#: head's spin in the cell's convention: the convention does not hold at that hole (two-sided p = 6e-5
#: per hole where it holds: a hole judged with the wider, every-spin U95 by mistake, never a wrong verdict)
SPIN_SIGMAS = 4.0
#: deg: the head's spin about the tool axis beyond the cell's convention where ``--spin-deg`` does not state it
#: and a redundant reading confirms the convention (a cell's usual orientation error)
DEFAULT_SPIN_DEG = 2.0
#: rows per call of the fit (as :data:`metrology.measure.holes.CACHE_ROWS`)
CACHE_ROWS = 16384


@dataclass(frozen=True)
class SpinJudged:
    """Holes measured with the panel known, and how their spin was taken.

    Attributes
    ----------
    normals : HoleNormals of the holes, in order (its ``budget`` None where the two ways were merged)
    extra : PanelFit of the holes
    free : (m,) bool, judged with the spin not known (a U95 over every spin)
    convention : (m,) bool, judged with the spin in the cell's convention (no pose: the convention assumed)
    z : (m,) float, the convention's misfit in sigmas where the test refused it (NaN elsewhere)
    """

    normals: HoleNormals
    extra: "PanelFit"
    free: np.ndarray
    convention: np.ndarray
    z: np.ndarray


def _fit(sub, dd, shape, u_shape, spin, higher, free=False):
    """:func:`metrology.measure.surface.surface_hole_normals` in slices of :data:`CACHE_ROWS` rows."""
    from metrology.measure.surface import PanelFit, PanelTerms, surface_hole_normals

    def part(s):
        return surface_hole_normals(sub, dd[s], shape[s], PanelTerms(u_shape[s], spin[s], free),
                                    beyond=None if higher is None or free else higher.rows(s))

    parts = [part(slice(i, i + CACHE_ROWS)) for i in range(0, len(dd), CACHE_ROWS)]
    return concat_normals([p[0] for p in parts]), PanelFit.concat([p[1] for p in parts])


def _merge(m, parts):
    """HoleNormals and extra of ``m`` holes from ``parts``, each ``(index, normals, extra)``."""
    first = parts[0][1]
    fields = {}
    for f in first.__dataclass_fields__:
        if f == "budget" or getattr(first, f) is None:
            fields[f] = None
            continue
        v = getattr(first, f)
        a = np.empty((m,) + v.shape[1:], v.dtype)
        for idx, h, _ in parts:
            a[idx] = getattr(h, f)
        fields[f] = a
    extra = parts[0][2].blank(m)
    for idx, _, e in parts:
        extra.put(idx, e)
    return HoleNormals(**fields), extra


def panel_normals(sub, dd, shape, u_shape, spin, higher, convention, stated: bool) -> SpinJudged:
    """Holes measured with their local surface known, the spin known, confirmed or bounded (module docstring).

    Parameters
    ----------
    sub : SensorLayout, the sensors that read these holes; dd : (m, n) float, mm, their readings
    shape : (m, 3, 3) float, 1/mm, TCS; u_shape : (m,) 1/mm; spin : (m,) rad; higher : Beyond or None
    convention : (m,) bool, holes whose shape was put into the TCS by the cell's convention (no pose)
    stated : bool, the convention was stated (``--spin-deg``): without redundancy it is taken
    """
    m = len(dd)
    redundant = sub.n == 4
    free0 = convention & (not redundant) & (not stated)
    nan = np.full(m, np.nan)
    if not free0.any() and not (redundant and convention.any()):  # the usual: the pose, or a stated 3-sensor convention
        h, extra = _fit(sub, dd, shape, u_shape, spin, higher)
        return SpinJudged(h, extra, np.zeros(m, bool), convention.copy(), nan)
    a = np.flatnonzero(~free0)
    parts = []
    z = nan.copy()
    free = free0.copy()
    if a.size:
        h, extra = _fit(sub, dd[a], shape[a], u_shape[a], spin[a], None if higher is None else higher.rows(a))
        test = np.abs(extra.panel_misfit_z)
        off = convention[a] & (test > SPIN_SIGMAS) if redundant else np.zeros(a.size, bool)
        free[a[off]] = True
        z[a[off]] = extra.panel_misfit_z[off]
        keep = ~off
        if keep.any():
            parts.append((a[keep], _rows(h, keep), extra.rows(keep)))
    b = np.flatnonzero(free)
    if b.size:
        h, extra = _fit(sub, dd[b], shape[b], u_shape[b], spin[b], None, free=True)
        parts.append((b, h, extra))
    h, extra = _merge(m, parts) if len(parts) > 1 or parts[0][0].size != m else (parts[0][1], parts[0][2])
    return SpinJudged(h, extra, free, convention & ~free, z)


def _rows(h, sel):
    return HoleNormals(**{f: None if getattr(h, f) is None else
                          (getattr(h, f).rows(sel) if f == "budget" else getattr(h, f)[sel])
                          for f in h.__dataclass_fields__})
