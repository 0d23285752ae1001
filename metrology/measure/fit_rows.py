"""Rows of a fit's results: the holes of one way of judging them (the pose, the convention, its spin read, every spin)
put back in hole order, and rule 2's fields kept from the fit at the convention's spin (:mod:`metrology.measure.spin`).
"""

from __future__ import annotations

import numpy as np

from metrology.measure.normals import HoleNormals

__all__ = ["RULE2", "merge", "with_rows", "put", "rows"]


def merge(m, parts):
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


#: HoleNormals fields rule 2 reads: kept from the fit at the convention's spin, with its doubt (the misfit read
#: at the spin found is 0 by construction: the redundant reading is spent on the spin)
RULE2 = ("residual", "residual_z", "signature", "twist", "residual_sd", "residual_noise_sd", "misfit_bound")


def with_rows(e0, r, e):
    """A copy of ``e0`` (PanelFit) with the holes ``r`` from ``e``."""
    out = e0.rows(np.arange(len(e0.correction)))
    out.put(r, e)
    return out


def put(h0, r, h, everything=False):
    """A copy of ``h0`` (HoleNormals) with the holes ``r`` from ``h`` (but its :data:`RULE2` fields unless
    ``everything``)."""
    from metrology.measure.budget import Budget

    fields = {}
    for f in h0.__dataclass_fields__:
        v0, v = getattr(h0, f), getattr(h, f)
        if (f in RULE2 and not everything) or v0 is None or v is None:
            fields[f] = v0
        elif f == "budget":
            tilt = v0.tilt.copy()
            tilt[r] = v.tilt
            srcs = []
            for s0, s in zip(v0.sources, v.sources):
                cov, hw = s0.cov.copy(), None if s0.half_width is None else s0.half_width.copy()
                cov[r] = s.cov
                if hw is not None:
                    hw[r] = s.half_width
                srcs.append(type(s0)(s0.name, cov, s0.kind, hw))
            fields[f] = Budget(tilt, tuple(srcs))
        else:
            a = v0.copy()
            a[r] = v
            fields[f] = a
    return HoleNormals(**fields)


def rows(h, sel):
    """The holes ``sel`` of ``h`` (HoleNormals), its budget's too."""
    return HoleNormals(**{f: None if getattr(h, f) is None else
                          (getattr(h, f).rows(sel) if f == "budget" else getattr(h, f)[sel])
                          for f in h.__dataclass_fields__})
