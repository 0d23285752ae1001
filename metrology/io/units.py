"""Length units of a point cloud: scale factors to mm, and a guess from the cloud itself.

A cloud exported in metres and read as mm gives a "noise 0.02654 mm" that looks like a
superb scan. metro cannot know a file's unit, but the cloud's size says a lot: the parts
metro measures (datum plates, panels, sensor spots) are tens to thousands of mm across and
scanned with spots 0.01 mm to a few mm apart.

The rule (:func:`infer_units`): with ``extent`` the largest side of the bounding box and
``spacing`` the median nearest-neighbour distance (both in the file's numbers),

- ``extent < 5`` and ``spacing < 0.01`` -> ``"m"`` (a part under 5 mm sampled every 10 µm is
  not what metro measures; a 5 m cell sampled every 10 mm is);
- otherwise ``"mm"`` (what metro assumes).

Inches are never guessed (their range overlaps mm): pass ``units="in"``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

#: unit name -> mm per unit
MM_PER_UNIT = {"mm": 1.0, "m": 1000.0, "in": 25.4}
#: below both, a cloud looks like metres (file's numbers)
METRES_MAX_EXTENT = 5.0
METRES_MAX_SPACING = 0.01
_SAMPLE = 20_000


def mm_per_unit(units: str) -> float:
    """mm per ``units`` (``"mm"``, ``"m"`` or ``"in"``); raise naming the accepted ones."""
    try:
        return MM_PER_UNIT[units]
    except KeyError:
        raise ValueError(f"units {units!r}: expected one of {', '.join(MM_PER_UNIT)}") from None


@dataclass(frozen=True)
class UnitsHint:
    """What a cloud's size suggests about its unit.

    Attributes
    ----------
    likely : str
        ``"mm"`` or ``"m"``.
    extent : (3,) float, file units
        Bounding-box sides.
    spacing : float, file units
        Median nearest-neighbour distance (on a patch of 2 x 10^4 points for large clouds).
    noise : float, file units
        RMS distance of the points to their best-fit (total least squares) plane.
    sentence : str
        One line for a user, e.g. ``"extent 0.42 x 0.30 x 0.01, spacing 0.0011, noise 2.7e-05:
        looks like metres; pass --units m"``.
    """

    likely: str
    extent: tuple
    spacing: float
    noise: float
    sentence: str

    def to_dict(self) -> dict:
        return asdict(self)


def _spacing(points) -> float:
    """Median nearest-neighbour distance. Above ``_SAMPLE`` points, on the ``_SAMPLE`` points
    nearest (in the max norm) to the cloud's middle point: a contiguous patch, so the local
    density is kept (a regular or random thinning would change it)."""
    from scipy.spatial import cKDTree

    P = points
    if len(P) > _SAMPLE:
        d = np.abs(P - P[len(P) // 2]).max(axis=1)
        P = P[np.argpartition(d, _SAMPLE)[:_SAMPLE]]
    if len(P) < 2:
        return float("nan")
    dist, _ = cKDTree(P).query(P, k=2)
    nn = dist[:, 1]
    nn = nn[nn > 0]
    return float(np.median(nn)) if len(nn) else 0.0


def infer_units(points) -> UnitsHint:
    """Guess the unit of ``points (n, 3) float, file units`` from extent and spacing (module rule).

    Returns
    -------
    UnitsHint
    """
    P = np.asarray(points, dtype=float)
    extent = np.ptp(P, axis=0) if len(P) else np.zeros(3)
    spacing = _spacing(P)
    sub = P[:: max(1, len(P) // _SAMPLE)]
    sub = sub - sub.mean(axis=0)
    noise = float(np.linalg.svd(sub, compute_uv=False)[-1] / np.sqrt(len(sub))) if len(sub) >= 3 else float("nan")
    metres = float(extent.max()) < METRES_MAX_EXTENT and spacing < METRES_MAX_SPACING
    likely = "m" if metres else "mm"
    dims = " x ".join(f"{v:.3g}" for v in extent)
    advice = "looks like metres; pass --units m" if metres else "consistent with mm"
    sentence = f"extent {dims}, spacing {spacing:.2g}, noise {noise:.2g}: {advice}"
    return UnitsHint(likely, tuple(float(v) for v in extent), spacing, noise, sentence)
