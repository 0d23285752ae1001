"""A layout's head terms in ``metro normals``: drawn into the ray-cast readings, removed before the normal.

The true head's terms act on the distances the beams travel (:func:`with_terms`): the offsets come
from the caller (``metro normals`` takes them from the forward simulator's physics,
:func:`metrology.sim.head_terms.properties_from_terms`), given each beam's true distance and its
incidence angle on the face it hit (:func:`beam_incidence`). The estimating layout's terms are
removed from the readings before the micro-plane or micro-sphere is fitted (:func:`corrected`) by the
one implementation ``metro measure`` uses (:func:`metrology.core.effects.apply.remove_terms`). A temperature coefficient needs each reading's temperature,
which ``normals`` has not: refused (:func:`check_terms`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["beam_incidence", "with_terms", "corrected", "check_terms"]


def check_terms(layout, source, what="metro normals") -> None:
    """Refuse (ValueError, one line) a layout whose terms need a covariate ``what`` does not give: a
    temperature coefficient needs the column ``temperature_c``."""
    if layout is None or layout.effects is None or "temperature_c" not in layout.effects.needs():
        return
    labels = ", ".join(c.label for c in layout.effects.components if c.name == "drift")
    raise ValueError(f"{source}: the layout's temperature coefficient ({labels}) needs the temperature of every "
                     f"reading (the column temperature_c, deg C), which {what} does not have")


def beam_incidence(caster, layout, R, tri) -> np.ndarray:
    """``(m, n)`` rad: each beam's incidence angle on the face ``tri (m, n)`` it hit (NaN on a miss),
    the head at rotations ``R (m, 3, 3)`` (TCS to panel)."""
    dirs = np.einsum("mij,nj->mni", R, layout.direction)
    out = np.full(tri.shape, np.nan)
    hit = tri >= 0
    v = caster.triangles[tri[hit]]
    fn = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    u = dirs[hit] / np.linalg.norm(dirs[hit], axis=1, keepdims=True)
    out[hit] = np.arccos(np.clip(np.abs(np.sum(fn * u, axis=1)), 0.0, 1.0))
    return out


def with_terms(d, offsets, caster, layout, R, tri):
    """The distances ``d (m, n)`` mm plus the true head's terms: ``offsets(d, incidence)`` (each ``(m, n)``,
    mm and rad) or ``d`` unchanged when ``offsets`` is None."""
    if offsets is None:
        return d
    off = offsets(np.where(np.isfinite(d), d, 0.0), beam_incidence(caster, layout, R, tri))
    return d + np.where(np.isfinite(off), off, 0.0)


def corrected(layout, d) -> np.ndarray:
    """``(m, n)`` mm: the readings ``d`` with ``layout``'s terms removed (``d`` itself without terms), by
    :func:`metrology.core.effects.apply.remove_terms`, as ``metro measure`` removes them: each beam's
    incidence from the pose's micro-plane of the raw readings; a pose with fewer than 3 readings (no plane,
    no incidence) has its term-bearing readings blanked. A temperature coefficient is refused before
    (:func:`check_terms`)."""
    if layout.effects is None:
        return d
    from metrology.core.effects.apply import remove_terms

    return remove_terms(layout, d, None, "metro normals").d
