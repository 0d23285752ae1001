"""Beams that hit the smooth surface a mesh tessellates, not its facets.

A CAD panel exported as a mesh approximates a designed surface; its facets sag below it by
the chord error (``w^2 kappa / 8``). A micro-sphere through four spots on facets amplifies
that sag like reading noise (by ~30 on a Table 6 head, whose spots are nearly concyclic).
:class:`SmoothCaster` moves each hit onto Phong tessellation's surface (Boubekeur and Alexa,
2008) built on the crease-aware corner normals of :meth:`metrology.panel.mesh.Panel.corner_normals`:
``p* = p + alpha (sum_k b_k pi_k(p) - p)``, ``pi_k(p)`` the projection of the flat hit ``p``
onto the tangent plane at corner ``k``. With ``alpha = 1/2`` the offset is the sag of a
sphere or a cylinder through the corners to leading order (``(R^2 - |p|^2) / R`` is twice
the sag), so the residual falls from ``O(h^2 kappa)`` to ``O(h^3 kappa^2)``. Inside a planar
region the corner normals are the face's own and nothing moves; across a crease nothing is
smoothed.
"""

from __future__ import annotations

import numpy as np

#: the Phong shape factor that reproduces a sphere's and a cylinder's sag to leading order
PHONG_ALPHA = 0.5

__all__ = ["SmoothCaster", "PHONG_ALPHA"]


class SmoothCaster:
    """A ray caster (:class:`metrology.panel.rays.RayCaster`) whose hits lie on the smooth surface.

    Everything but :meth:`cast` is the wrapped caster's (its engine, triangles, closest
    points); ``beams`` says what the beams hit.

    Parameters
    ----------
    caster : RayCaster, of ``panel.mesh``
    panel : Panel, whose crease-aware corner normals define the surface
    """

    beams = f"smooth: Phong tessellation (alpha {PHONG_ALPHA:g}) on the crease-aware corner normals"

    def __init__(self, caster, panel):
        self._caster = caster
        self._panel = panel

    def __getattr__(self, name):
        return getattr(self._caster, name)

    def cast(self, origins, directions):
        """First hits on the smooth surface: as :meth:`RayCaster.cast`, the distance ``t``
        moved along the ray to the smooth surface (the face and barycentric coordinates are
        those of the facet hit)."""
        origins = np.asarray(origins, float).reshape(-1, 3)
        directions = np.asarray(directions, float).reshape(-1, 3)
        tri, t, bary = self._caster.cast(origins, directions)
        hit = np.flatnonzero((tri >= 0) & np.isfinite(t))
        if len(hit) == 0:
            return tri, t, bary
        d, b = directions[hit], bary[hit]
        p = origins[hit] + t[hit, None] * d
        cn = self._panel.corner_normals(tri[hit])  # (h, 3 corners, 3)
        P = self._caster.triangles[tri[hit]]  # (h, 3 corners, 3)
        proj = p[:, None, :] - np.sum((p[:, None, :] - P) * cn, axis=2, keepdims=True) * cn
        delta = PHONG_ALPHA * (np.einsum("hk,hkj->hj", b, proj) - p)
        n = np.einsum("hk,hkj->hj", b, cn)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        cos = np.sum(d * n, axis=1)
        ok = np.abs(cos) > 1e-6  # a grazing beam keeps its facet hit
        t = t.copy()
        t[hit[ok]] += np.sum(delta[ok] * n[ok], axis=1) / cos[ok]
        return tri, t, bary
