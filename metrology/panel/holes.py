"""Each drill point's local surface on a CAD panel: its shape operator from the mesh, for
``metro measure --panel`` (:mod:`metrology.measure.panel` has the method and the conventions).

The drill point is snapped onto the mesh; the CAD's normal there (the mesh's reference normal,
turned toward the head: against the feed) gives the local frame ``(e1, e2, n)``, ``e1`` the
panel's ``x`` made square to ``n``. :data:`RING_SAMPLES` rays along ``-n`` on three rings of the
head's footprint (``1/3, 2/3, 1`` times :data:`FOOTPRINT_MARGIN` x its radius) and the centre
sample the heights ``w(s, t)`` (and tell a footprint that runs off the panel); the shape comes from
a full quartic fitted to the mesh's own vertices near the point (:data:`VERTEX_K`; they lie on the
CAD surface, a facet is a chord of it), or where the mesh has too few there, a full cubic fitted to
the ray-cast heights (10 terms, one design matrix for every hole): its Hessian ``H`` and gradient,
the shape operator ``K = -H`` (positive where the surface bends away from the head), its terms
beyond second order (``higher``, for :mod:`metrology.measure.beyond`). ``u_shape`` (1/mm, per
component) combines the fit's residual through its covariance, ``|grad K| position_mm / 3`` and a
stated form tolerance ``2 t / rho^2 / sqrt(3)``.

Where the panel is a STEP read with its B-rep (the ``step-exact`` extra: ``panel.surface`` a
:class:`metrology.panel.brep.BRepSurface`), the normal and the shape operator come from the exact
face at the drill point instead (:meth:`~metrology.panel.brep.BRepSurface.local_surface`: the point
projected on the face, its second fundamental form ``Hess`` along the normal turned toward the head,
``K = -Hess`` in the same frame ``(e1, e2, n)``); the cubic fit still gives the curvature's gradient
(the position term) and the footprint's edge check, and ``u_shape`` has no faceting term. Where the
footprint needs terms beyond the quartic (:mod:`metrology.panel.footprint`), the quartic and degrees 5-8
come from the faces' own points over the disc (:meth:`~metrology.panel.brep.BRepSurface.disc_points`;
a STEP's tessellation has no vertex near a tight crest), their residual the hole's ``u_height``.
"""

from __future__ import annotations

import math

import numpy as np

from metrology.core.frames import embed_shape, principal_curvatures, tangent_frame

__all__ = ["panel_surfaces", "RING_SAMPLES", "FOOTPRINT_MARGIN", "POINT_OFF_MM", "FEED_MIN_COS", "UNIT_RATIO",
           "VERTEX_K", "VERTEX_REACH", "VERTEX_MIN"]

#: rays per ring of the footprint sampled on the panel (3 rings and the centre: 37 samples)
RING_SAMPLES = 12
#: the sampled disc's radius over the head's footprint radius (the spots move out on a tilted head)
FOOTPRINT_MARGIN = 1.25
#: a drill point farther than this from the panel is not on it (mm): the table does not fit the panel
POINT_OFF_MM = 0.5
#: a hole table of 3+ holes spanning less than the panel's extent over this is not in mm (metres?)
UNIT_RATIO = 300.0
#: holes whose rays are cast together (memory: about 37 x 200 bytes a hole)
CHUNK_HOLES = 4096
#: a feed direction must be within acos(this) = 60 deg of the panel's normal (into the panel)
FEED_MIN_COS = 0.5
#: the curvature is fitted to the mesh's own vertices (on the CAD surface; a facet is a chord, below a
#: convex surface by up to k L^2 / 8: on the bundled 10 mm meshes the ray-cast heights gave the
#: nacelle's shape operator 4e-5 1/mm off, 3x its u_shape, and a 3-sensor ring 92 % coverage), a full
#: quartic (the cubic's Hessian takes the quartic's terms: 4e-6 1/mm on the nacelle, the quartic's
#: 1e-8): the VERTEX_K nearest within VERTEX_REACH x the sampled disc's radius, ...
VERTEX_K = 40
VERTEX_REACH = 2.0
#: ... at least VERTEX_MIN of them (the quartic's 15 terms and 10 to spare), else the ray-cast heights
#: (a mesh coarse for the footprint)
VERTEX_MIN = 25
#: up to this many holes x faces, the rays and closest points are trimesh's own (double precision, an r-tree;
#: :data:`metrology.panel.rays.AUTO_ORDER` otherwise, Open3D first): loading Open3D's library costs 0.45-0.5 s
#: CPU, trimesh's engine 1.3 ms a hole on the bundled 1250-face wing (Open3D's 0.14 ms after that import), so a
#: table of 25 holes paid the import 8x what trimesh's rays cost; the break-even there (~390 holes, 490 000 holes
#: x faces) taken at 30 %: meshes of more faces give a ray more candidates. Measured (eng_cost, 25-2000 holes):
#: benchmarks/results/measure_panel_speed_issue49_r6.md
DOUBLE_ENGINE_WORK = 150_000


def panel_surfaces(panel, table, footprint_mm: float, position_mm: float = 0.5, form_mm: float = 0.0,
                   display: str | None = None) -> dict:
    """Each hole's local surface from a loaded :class:`metrology.panel.mesh.Panel` (module docstring).

    ``table``: a hole table (``ids``, ``point (m, 3)`` mm, ``feed (m, 3)`` unit, ``source``,
    ``line(row)``: :class:`metrology.measure.panel.HoleTable`). Returns a dict: ``normal (m, 3)``
    unit toward the head, ``shape (m, 3, 3)`` 1/mm, ``k (m, 2)`` 1/mm, ``u_shape (m,)`` 1/mm,
    ``frame (m, 2, 3)`` unit (``e1, e2``), ``higher (m, 9)`` the height along ``n`` beyond second order
    (:class:`metrology.measure.panel.HoleSurfaces`; ``(m, 39)`` with degrees 5-8 where the footprint needs
    them, :mod:`metrology.panel.footprint`), ``u_height (m,)`` mm the height no term carries, ``problem (m,)`` object, ``source`` str (panel frame).

    Raises ValueError (one line, naming the table's row) when a drill point is off the panel or its
    feed does not point into it. A hole whose sampled footprint runs off the panel gets a
    ``problem`` (measured ``not_measured`` with it)."""
    from metrology.panel.rays import RayCaster

    import trimesh

    shown = display or panel.source
    ext_t = float(np.ptp(table.point, axis=0).max()) if len(table.point) > 1 else 0.0
    ext_p = float(np.ptp(np.asarray(panel.mesh.vertices), axis=0).max())
    if len(table.point) >= 3 and ext_t * UNIT_RATIO < ext_p:
        raise ValueError(f"{table.source}: its {len(table.point)} holes span {ext_t:.4g} and the panel {shown} "
                         f"{ext_p:.4g}: the hole table is not in mm (metres?); x,y,z must be mm in the panel's frame")
    caster = RayCaster(panel.mesh, "trimesh" if len(table.point) * len(panel.mesh.faces) <= DOUBLE_ENGINE_WORK
                       else "auto")
    tri, snapped = caster.closest(table.point)
    dist = np.linalg.norm(snapped - table.point, axis=1)
    off = np.flatnonzero(dist > POINT_OFF_MM)
    if off.size:
        r = int(off[np.argmax(dist[off])])
        hint = ""
        if ext_t > 0 and (ext_p / ext_t > 100 or ext_t / ext_p > 100):
            hint = (f"; the table spans {ext_t:g} and the panel {ext_p:g}: one of them is not in mm (metres?)")
        raise ValueError(f"{table.source}: {table.line(r)}: hole {table.ids[r]} at ({', '.join(f'{v:g}' for v in table.point[r])}) "
                         f"is {dist[r]:.3g} mm off the panel {shown} (more than {POINT_OFF_MM:g} mm; {off.size} such "
                         f"holes): the hole table does not fit this panel{hint}")
    bary = trimesh.triangles.points_to_barycentric(np.asarray(panel.mesh.triangles)[tri], snapped)
    bary = np.clip(bary, 0.0, 1.0)
    bary /= bary.sum(1, keepdims=True)
    nm, _, _ = panel.reference_normal_at(tri, bary)
    cosf = -(nm * table.feed).sum(1)  # the feed into the panel: against the normal toward the head
    side = np.sign(np.median(cosf))
    if side == 0:
        side = 1.0
    n = nm * side  # toward the head, for the table's side
    hess = None
    local = getattr(panel.surface, "local_surface", None)  # a STEP's B-rep (the step-exact extra)
    if local is not None:
        nb, hess = local(table.point, margin_mm=POINT_OFF_MM)
        gone = np.flatnonzero(~np.isfinite(nb).all(1))
        if gone.size:
            r = int(gone[0])
            raise ValueError(f"{table.source}: {table.line(r)}: hole {table.ids[r]} at "
                             f"({', '.join(f'{v:g}' for v in table.point[r])}) is on no face of the panel {shown}'s "
                             f"B-rep ({gone.size} such holes): the hole table does not fit this panel")
        flip = np.where((nb * n).sum(1) < 0, -1.0, 1.0)  # the face's orientation turned to the table's side
        n, hess = nb * flip[:, None], hess * flip[:, None, None]
    c = -(n * table.feed).sum(1)
    bad = np.flatnonzero(c < FEED_MIN_COS)
    if bad.size:
        r = int(bad[0])
        ang = math.degrees(math.acos(max(-1.0, min(1.0, float(c[r])))))
        raise ValueError(f"{table.source}: {table.line(r)}: hole {table.ids[r]}: feed direction "
                         f"({', '.join(f'{v:.4g}' for v in table.feed[r])}) is {ang:.1f} deg from the panel's inward "
                         f"normal (at most {math.degrees(math.acos(FEED_MIN_COS)):.0f}): it does not point into the "
                         f"panel{' (the other holes feed from the other side)' if ang > 90 else ''}")
    e1, e2 = tangent_frame(n)
    rho = FOOTPRINT_MARGIN * footprint_mm
    st = [(0.0, 0.0)] + [(rho * f * math.cos(a), rho * f * math.sin(a)) for f in (1 / 3, 2 / 3, 1.0)
                          for a in (2 * math.pi * (np.arange(RING_SAMPLES) + 0.5 * (f != 1 / 3)) / RING_SAMPLES)]
    st = np.array(st)  # (p, 2)
    H = 4.0 * rho + 50.0  # rays start this far out along n
    P = snapped
    w = np.empty((len(P), len(st)))  # heights along n over the tangent plane
    for a in range(0, len(P), CHUNK_HOLES):  # the rays of a few thousand holes at a time: bounded memory
        b = slice(a, a + CHUNK_HOLES)
        origins = (P[b, None, :] + st[None, :, 0, None] * e1[b, None, :] + st[None, :, 1, None] * e2[b, None, :]
                   + H * n[b, None, :])
        dirs = np.broadcast_to(-n[b, None, :], origins.shape)
        _, t, _ = caster.cast(origins.reshape(-1, 3), np.ascontiguousarray(dirs).reshape(-1, 3))
        w[b] = (H - t).reshape(-1, len(st))
    miss = ~np.isfinite(w)
    s_, t_ = st[:, 0], st[:, 1]
    X = _cubic_design(s_, t_)
    XtX_inv = np.linalg.inv(X.T @ X)
    pinv = XtX_inv @ X.T
    coef = np.where(miss.any(1)[:, None], np.nan, np.nan_to_num(w) @ pinv.T)
    res = np.nan_to_num(w) - coef @ X.T
    dof = len(st) - X.shape[1]
    s2 = (res * res).sum(1) / dof
    var_h = s2[:, None] * np.diag(XtX_inv)[None, 3:6]
    u_fit = np.sqrt(var_h.mean(1))
    Hl = np.stack([np.stack([coef[:, 3], coef[:, 4]], 1), np.stack([coef[:, 4], coef[:, 5]], 1)], axis=1)
    Kl = -Hl
    higher = np.concatenate([coef[:, 6:10], np.zeros((len(P), 5))], axis=1)  # the ray-cast fit: no quartic
    if hess is None:  # the mesh's vertices where it has enough of them near the point (VERTEX_K)
        vcoef, vu, vok = _vertex_cubic(panel, P, n, e1, e2, rho)
        use = vok & ~miss.any(1)
        coef[use], u_fit[use], higher[use] = vcoef[use, :10], vu[use], vcoef[use, 6:]
        Hl = np.stack([np.stack([coef[:, 3], coef[:, 4]], 1), np.stack([coef[:, 4], coef[:, 5]], 1)], axis=1)
        Kl = -Hl
        # over a footprint large against the radius: the remainder beyond the quartic (metrology.panel.footprint)
        from metrology.panel.footprint import remainder_terms

        extra, u_height = remainder_terms(panel, P, n, e1, e2, rho, np.where(use[:, None], vcoef, np.nan),
                                          principal_curvatures(np.where(miss.any(1)[:, None, None], 0.0, Kl)))
        if extra is not None:
            higher = np.concatenate([higher, extra], axis=1)
        # the curvature a missing sample's reason names: the vertices' where the rays missed
        Kv = -np.stack([np.stack([vcoef[:, 3], vcoef[:, 4]], 1), np.stack([vcoef[:, 4], vcoef[:, 5]], 1)], axis=1)
        Kr = np.where(vok[:, None, None], Kv, Kl)
    else:  # the B-rep: beyond second order from its own faces' points over the disc, where the footprint needs it
        higher, u_height = _brep_beyond(panel.surface, P, n, e1, e2, rho, hess, higher, miss.any(1))
        E = np.stack([e1, e2], axis=1)  # the curvature a missing sample's reason names: the B-rep's own
        Kr = -np.einsum("mai,mij,mbj->mab", E, hess, E)
    c1, c2, c3, c4 = coef[:, 6], coef[:, 7], coef[:, 8], coef[:, 9]
    grad = np.sqrt(c1 * c1 + c2 * c2 + 2 * (c2 * c2 + c3 * c3) + c3 * c3 + c4 * c4)  # |dK/ds|_F, 1/mm^2
    u_pos = grad * position_mm / 3.0
    u_form = 2.0 * form_mm / (rho * rho) / math.sqrt(3.0)
    coarse = 0 if hess is not None else int((~vok & ~miss.any(1)).sum())  # holes on the ray-cast heights
    src = (f"panel {shown} (mesh, a quartic fitted to its vertices near each hole"
           + (f"; {coarse} from the ray-cast heights: too few vertices there)" if coarse else ")"))
    if hess is not None:  # the exact surface: no faceting; the gradient (position term) from the cubic fit
        E = np.stack([e1, e2], axis=1)  # (m, 2, 3)
        Kl = np.where(miss.any(1)[:, None, None], np.nan, -np.einsum("mai,mij,mbj->mab", E, hess, E))
        u_fit = 0.0
        src = f"panel {shown} (B-rep (exact STEP faces); the curvature's gradient from a cubic fit over the footprint)"
    u = np.sqrt(u_fit ** 2 + u_pos ** 2 + u_form ** 2)
    problem = np.full(len(P), "", dtype=object)
    kmax = np.abs(principal_curvatures(np.nan_to_num(Kr))).max(1)
    for r in np.flatnonzero(miss.any(1)):
        problem[r] = (f"the head's footprint (radius {rho:.0f} mm) reaches past the crest of the surface's radius "
                      f"{1.0 / kmax[r]:.0f} mm here ({int(miss[r].sum())} of {len(st)} samples miss the panel): its "
                      f"local surface cannot represent the spots" if kmax[r] * rho >= 1.0 else
                      f"the head's footprint (radius {rho:.0f} mm) runs off the panel's edge at this hole "
                      f"({int(miss[r].sum())} of {len(st)} samples miss the panel)")
    Kl = np.where(miss.any(1)[:, None, None], 0.0, Kl)
    k = principal_curvatures(Kl)
    k[miss.any(1)] = np.nan  # unknown there (the hole is not measured)
    higher = np.where(np.isfinite(higher), higher, 0.0)
    return {"normal": n, "shape": embed_shape(Kl, e1, e2), "k": k, "u_shape": np.where(np.isfinite(u), u, 0.0),
            "frame": np.stack([e1, e2], axis=1), "higher": higher, "u_height": u_height,
            "problem": problem, "source": src}


def _cubic_design(s_, t_):
    """The full cubic's 10 columns at local coordinates ``s_, t_`` (mm, any shape): ``(..., 10)``."""
    return np.stack([np.ones_like(s_), s_, t_, 0.5 * s_ * s_, s_ * t_, 0.5 * t_ * t_, s_ ** 3 / 6, s_ * s_ * t_ / 2,
                     s_ * t_ * t_ / 2, t_ ** 3 / 6], axis=-1)


def _brep_beyond(surface, P, n, e1, e2, rho, hess, higher, miss):
    """``(higher, u_height)`` on a STEP's B-rep: where the footprint needs terms beyond the quartic (the remainder a
    sphere of the hole's largest curvature leaves at ``rho``, :data:`metrology.panel.footprint.NEEDED_MM`), the
    quartic and degrees 5-8 fitted to points of the faces themselves over the disc (``surface.disc_points``), as the
    mesh path fits them to its vertices; elsewhere ``higher`` (the ray-cast cubic's) and no remainder."""
    from types import SimpleNamespace

    from metrology.panel.footprint import NEEDED_MM, extra_exponents, remainder_terms

    E = np.stack([e1, e2], axis=1)
    k = principal_curvatures(np.nan_to_num(-np.einsum("mai,mij,mbj->mab", E, hess, E)))
    need = np.flatnonzero((np.abs(k).max(1) ** 5 * rho ** 6 / 16.0 > NEEDED_MM) & ~miss)
    u_height = np.zeros(len(P))
    if need.size == 0 or not hasattr(surface, "disc_points"):
        return higher, u_height
    higher = higher.copy()
    full = np.zeros((len(P), len(extra_exponents())))
    for i, pts in zip(need, surface.disc_points(P[need], n[need], e1[need], e2[need], rho)):
        one = slice(i, i + 1)  # each hole on its own points (two holes' samplings mixed leave lines of equal t)
        cloud = SimpleNamespace(mesh=SimpleNamespace(vertices=pts))
        vcoef, _, vok = _vertex_cubic(cloud, P[one], n[one], e1[one], e2[one], rho)
        extra, u_one = remainder_terms(cloud, P[one], n[one], e1[one], e2[one], rho,
                                       np.where(vok[:, None], vcoef, np.nan), k[one])
        if vok[0]:
            higher[i] = vcoef[0, 6:]
        if extra is not None:
            full[i] = extra[0]
        u_height[i] = u_one[0]
    return np.concatenate([higher, full], axis=1), u_height


def _vertex_cubic(panel, P, n, e1, e2, rho):
    """The heights over the tangent plane up to the cubic, from a full quartic fitted to the mesh's vertices near each
    point: the :data:`VERTEX_K` nearest within ``VERTEX_REACH rho`` (mm). A mesh's vertices lie on the
    CAD surface, its facets are chords of it (a height sampled on a facet is off the surface by up to
    ``k L^2 / 8``, a bias the cubic takes into its curvature).

    ``P (m, 3)`` mm panel frame, ``n, e1, e2 (m, 3)`` the local frame. Returns ``coef (m, 15)`` (the
    quartic's terms: the ray-cast fit's 10 columns, then ``s^4/24, s^3 t/6, s^2 t^2/4, s t^3/6, t^4/24``), ``u_fit (m,)`` 1/mm (the residual through the fit's covariance, mean of
    the Hessian's 3 components) and ``ok (m,)`` (at least :data:`VERTEX_MIN` vertices and a well-posed fit)."""
    from scipy.spatial import cKDTree

    V = np.asarray(panel.mesh.vertices, float)
    tree = getattr(panel, "_vertex_tree", None)
    if tree is None:  # once per panel
        tree = panel._vertex_tree = cKDTree(V)
    m = len(P)
    k = min(VERTEX_K, len(V))
    coef = np.full((m, 15), np.nan)
    u_fit = np.full(m, np.nan)
    ok = np.zeros(m, bool)
    for a in range(0, m, CHUNK_HOLES):
        b = slice(a, a + CHUNK_HOLES)
        dist, idx = tree.query(P[b], k=k, distance_upper_bound=VERTEX_REACH * rho)
        dist, idx = dist.reshape(len(dist), -1), idx.reshape(len(idx), -1)
        have = np.isfinite(dist)
        q = V[np.where(have, idx, 0)] - P[b, None, :]  # (c, k, 3)
        # scaled by the neighbours' own reach, not the footprint's: a well-conditioned design whatever the mesh's
        # step against the footprint (over rho, a 2 mm mesh under a 50 mm disc had cond > 1e12: the ray-cast cubic)
        r0 = np.maximum(np.where(have, dist, 0.0).max(1), 1e-9)[:, None]  # (c, 1), mm
        s_ = (q * e1[b, None, :]).sum(2) / r0
        t_ = (q * e2[b, None, :]).sum(2) / r0
        w = (q * n[b, None, :]).sum(2)
        X = np.concatenate([_cubic_design(s_, t_), np.stack([s_ ** 4 / 24, s_ ** 3 * t_ / 6, s_ * s_ * t_ * t_ / 4,
                                                             s_ * t_ ** 3 / 6, t_ ** 4 / 24], axis=-1)], axis=-1)
        X = X * have[..., None]
        XtX = np.einsum("cpi,cpj->cij", X, X)
        cnt = have.sum(1)
        good = (cnt >= VERTEX_MIN) & (np.linalg.cond(XtX) < 1e12)
        inv = np.linalg.inv(np.where(good[:, None, None], XtX, np.eye(15)))
        cf = np.einsum("cij,cpj,cp->ci", inv, X, np.where(have, w, 0.0))
        res = np.where(have, w - np.einsum("cpi,ci->cp", X, cf), 0.0)
        s2 = (res * res).sum(1) / np.maximum(cnt - 15, 1)
        scale = r0 ** np.array([0, 1, 1, 2, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4, 4], float)
        coef[b] = cf / scale  # back to mm
        u_fit[b] = np.sqrt(s2 * np.diagonal(inv, axis1=1, axis2=2)[:, 3:6].mean(1)) / r0[:, 0] ** 2
        ok[b] = good
    return coef, u_fit, ok
