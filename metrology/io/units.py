"""Length units of a point cloud: scale factors to mm, and a guess from the cloud itself.

A cloud exported in metres and read as mm gives a "noise 0.02654 mm" that looks like a
superb scan. metro cannot know a file's unit, but the cloud's size says something: what
metro measures (datum plates, panels, fuselage sections, cells) lies within the bounds
below, read in mm. The rule (:func:`infer_units`) reads the cloud both ways, as mm and as
metres, and asks of each reading whether it falls inside all three bounds:

- ``extent`` (the largest side of the box holding the 1st to 99th percentile of each
  coordinate: a few stray points do not stretch it) in :data:`EXTENT_MM`;
- ``spacing`` (the median distance of a point to its nearest neighbour, on a contiguous
  patch of :data:`SPACING_PATCH` points) in :data:`SPACING_MM`;
- ``position`` (the distance of the cloud's median point from the frame's origin) at most
  :data:`POSITION_MM_MAX`: a tracker's or an aircraft's frame, not a map projection.

Only one reading plausible -> that unit (``"mm"``: "consistent with mm"; ``"m"``: "looks like
metres; pass --units m"). Both plausible (a 29 m room scan is also a 29 mm part scanned
every 20 µm), neither (UTM coordinates), a cloud with fewer than :data:`MIN_DISTINCT`
distinct points, or no spacing (identical points): ``None``, the evidence is weak and
metro says nothing. Inches are never guessed (their range overlaps mm): pass ``units="in"``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

#: unit name -> mm per unit
MM_PER_UNIT = {"mm": 1.0, "m": 1000.0, "in": 25.4}
#: what metro measures, in mm: a part from 2 mm (a sensor spot's patch) to 100 m (a hangar cell) across
EXTENT_MM = (2.0, 1e5)
#: scanned with spots from 1 µm (a confocal line) to 200 mm (tracker points on a fuselage) apart
SPACING_MM = (1e-3, 200.0)
#: in a frame whose origin is within 200 m (a tracker's range; an aircraft's frame from its nose)
POSITION_MM_MAX = 2e5
#: fewer distinct points than this: no judgement (a handful of corners is not a sampled surface)
MIN_DISTINCT = 20
#: the spacing is measured on this many points nearest (max norm) to the cloud's middle point
SPACING_PATCH = 2000
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
    likely : str or None
        ``"mm"``, ``"m"``, or ``None`` when the evidence is weak (both readings plausible,
        neither, or too few distinct points): then nothing is said.
    extent : (3,) float, file units
        Sides of the box holding the 1st to 99th percentile of each coordinate.
    spacing : float, file units
        Median nearest-neighbour distance on a contiguous patch (NaN under 2 points).
    position : float, file units
        Distance of the cloud's median point from the frame's origin.
    noise : float, file units
        RMS distance of the points to their best-fit (total least squares) plane.
    sentence : str
        One line for a user, e.g. ``"extent 0.42 x 0.30 x 0.01, spacing 0.0011, noise 2.7e-05:
        looks like metres; pass --units m"``.
    """

    likely: str | None
    extent: tuple
    spacing: float
    position: float
    noise: float
    sentence: str

    def to_dict(self) -> dict:
        return asdict(self)


def _spacing(points) -> float:
    """Median nearest-neighbour distance (zero distances, duplicates, skipped) on the
    ``SPACING_PATCH`` points nearest (in the max norm) to the cloud's middle point: a
    contiguous patch keeps the local density (a thinning would not). Brute force in numpy:
    no k-d tree, whose import alone takes longer than this."""
    P = points
    if len(P) > SPACING_PATCH:  # in chunks: memory of one float32 per point, not of the cloud
        mid = P[len(P) // 2]
        d = np.empty(len(P), dtype=np.float32)
        for a in range(0, len(P), 1 << 18):  # column by column: a reduction along axis 1 is 10 x slower
            block, out = P[a : a + (1 << 18)], d[a : a + (1 << 18)]
            out[:] = np.abs(block[:, 0] - mid[0])
            np.maximum(out, np.abs(block[:, 1] - mid[1]), out=out)
            np.maximum(out, np.abs(block[:, 2] - mid[2]), out=out)
        kth = np.partition(d, SPACING_PATCH - 1)[SPACING_PATCH - 1]
        P = P[np.flatnonzero(d <= kth)[: 4 * SPACING_PATCH]]
    d = median_nearest_distance(P)
    return d if np.isfinite(d) else 0.0


def median_nearest_distance(points) -> float:
    """Median distance of each of ``points (m, 3)`` to its nearest other point (zero distances,
    duplicates, skipped; NaN under 2 distinct points). Brute force in blocks of 500 rows: for a patch
    of a cloud or a hole table (thousands of points, not millions)."""
    P = np.asarray(points, float)
    if len(P) < 2:
        return float("nan")
    P = P - P.mean(axis=0)
    sq = np.einsum("ij,ij->i", P, P)
    nn = np.empty(len(P))
    for a in range(0, len(P), 500):
        d2 = sq[a : a + 500, None] + sq[None, :] - 2.0 * (P[a : a + 500] @ P.T)
        d2[d2 <= 1e-12 * np.maximum(sq[a : a + 500, None], 1e-300)] = np.inf  # itself and duplicates
        nn[a : a + 500] = d2.min(axis=1)
    nn = nn[np.isfinite(nn)]
    return float(np.sqrt(np.median(nn))) if len(nn) else float("nan")


def _plausible(extent, spacing, position, mm) -> bool:
    """The cloud read with ``mm`` mm per unit is something metro measures (module rule)."""
    return (EXTENT_MM[0] <= extent * mm <= EXTENT_MM[1] and SPACING_MM[0] <= spacing * mm <= SPACING_MM[1]
            and position * mm <= POSITION_MM_MAX)


def infer_units(points) -> UnitsHint:
    """Guess the unit of ``points (n, 3) float, file units`` from extent, spacing and position (module rule).

    Returns
    -------
    UnitsHint
    """
    P = np.asarray(points, dtype=float)
    sub = P[:: max(1, len(P) // _SAMPLE)]
    if len(sub):
        lo, hi = np.percentile(sub, [1, 99], axis=0)
        extent, position = hi - lo, float(np.linalg.norm(np.median(sub, axis=0)))
    else:
        extent, position = np.zeros(3), 0.0
    spacing = _spacing(P)
    c = sub - sub.mean(axis=0) if len(sub) else sub
    noise = float(np.linalg.svd(c, compute_uv=False)[-1] / np.sqrt(len(c))) if len(c) >= 3 else float("nan")
    e = float(extent.max())
    distinct = len(np.unique(sub[:1000], axis=0)) if len(sub) else 0
    likely = None
    if distinct >= MIN_DISTINCT and spacing > 0 and e > 0:
        as_mm, as_m = _plausible(e, spacing, position, 1.0), _plausible(e, spacing, position, MM_PER_UNIT["m"])
        likely = "mm" if as_mm and not as_m else "m" if as_m and not as_mm else None
    dims = " x ".join(f"{v:.3g}" for v in extent)
    advice = {"m": "looks like metres; pass --units m", "mm": "consistent with mm",
              None: "the size does not tell the unit"}[likely]
    sentence = f"extent {dims}, spacing {spacing:.2g}, noise {noise:.2g}: {advice}"
    return UnitsHint(likely, tuple(float(v) for v in extent), spacing, position, noise, sentence)
