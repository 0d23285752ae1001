"""The exact reference of a STEP panel: its B-rep, evaluated by OpenCASCADE (``cadquery-ocp-novtk``).

Optional (the ``step-exact`` extra). Where it is installed and the panel is a STEP file,
the reference normal at a point is the normal of the designed face there: the point is
projected onto the surface of each face near it (``GeomAPI_ProjectPointOnSurf``), the face
that holds it (``BRepClass_FaceClassifier``) and is nearest is kept, and its normal comes
from ``BRepGProp_Face.Normal`` (face orientation included), its second fundamental form from the
face's derivatives (:meth:`BRepSurface.local_surface`). No tessellation enters.
"""

from __future__ import annotations

import numpy as np


def ocp_available() -> bool:
    """Whether OpenCASCADE's Python binding (OCP) can be imported here."""
    try:
        import OCP.STEPControl  # noqa: F401
    except ImportError:
        return False
    return True


#: points of a hole's disc in :meth:`BRepSurface.disc_points` (a sunflower spiral: even, on no line; the local quartic's
#: 40 nearest then span 0.26 of the disc's radius, as a 2 mm mesh's vertices do under a 31 mm disc)
DISC_POINTS = 570


class BRepSurface:
    """A STEP file's B-rep as the panel's reference surface (same interface as
    :class:`metrology.panel.surfaces.ParametricSurface`: :meth:`normal`).

    Parameters
    ----------
    path : str, a STEP file
    scale : float, mm of the panel per mm of OpenCASCADE's model (OCC reads STEP into mm;
        1 unless ``--units`` overrides the file's unit)

    Attributes
    ----------
    reference_name : str, how reports name this reference
    n_faces : int
    """

    reference_name = "B-rep (exact STEP faces, OpenCASCADE)"

    def __init__(self, path, scale=1.0):
        from OCP.Bnd import Bnd_Box
        from OCP.BRepBndLib import BRepBndLib
        from OCP.IFSelect import IFSelect_RetDone
        from OCP.STEPControl import STEPControl_Reader
        from OCP.TopAbs import TopAbs_FACE
        from OCP.TopExp import TopExp_Explorer
        from OCP.TopoDS import TopoDS

        reader = STEPControl_Reader()
        if reader.ReadFile(str(path)) != IFSelect_RetDone:
            raise ValueError(f"{path}: OpenCASCADE cannot read this STEP file")
        reader.TransferRoots()
        shape = reader.OneShape()
        self.scale = float(scale)
        self._faces, lo, hi = [], [], []
        ex = TopExp_Explorer(shape, TopAbs_FACE)
        while ex.More():
            face = TopoDS.Face(ex.Current()) if hasattr(TopoDS, "Face") else TopoDS.Face_s(ex.Current())
            box = Bnd_Box()
            BRepBndLib.Add_s(face, box)
            a, b = box.CornerMin(), box.CornerMax()
            self._faces.append(face)
            lo.append([a.X(), a.Y(), a.Z()])
            hi.append([b.X(), b.Y(), b.Z()])
            ex.Next()
        if not self._faces:
            raise ValueError(f"{path}: the STEP file has no faces")
        self._lo, self._hi = np.array(lo, float), np.array(hi, float)
        self.n_faces = len(self._faces)

    def _locate(self, p, m):
        """The face holding ``p`` (OCC units), nearest first, and the point's ``(u, v)`` on its
        surface; ``None`` where no face is near (module docstring)."""
        from OCP.BRep import BRep_Tool
        from OCP.BRepClass import BRepClass_FaceClassifier
        from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf
        from OCP.TopAbs import TopAbs_OUT
        from OCP.gp import gp_Pnt

        cand = np.flatnonzero(np.all((p >= self._lo - m) & (p <= self._hi + m), axis=1))
        best = (np.inf, None)
        P = gp_Pnt(*p)
        for k in cand:
            face = self._faces[k]
            proj = GeomAPI_ProjectPointOnSurf(P, BRep_Tool.Surface_s(face))
            if not proj.NbPoints():
                continue
            d = proj.LowerDistance()
            if d >= best[0]:
                continue
            inside = BRepClass_FaceClassifier(face, proj.NearestPoint(), 1e-6).State() != TopAbs_OUT
            if inside or best[1] is None:
                best = (d if inside else np.inf, (face, proj.LowerDistanceParameters()))
        return best[1]

    def normal(self, points, margin_mm=0.05):
        """Exact unit normals of the designed faces at (or nearest to) ``points``.

        Parameters
        ----------
        points : (m, 3) float, mm, panel frame, on or within ``margin_mm`` of the panel
        margin_mm : float, mm, how far outside a face's bounding box a point may be

        Returns
        -------
        n : (m, 3) float, unit, panel frame, the face's orientation (align it with the
            mesh's outside where a side matters); NaN where no face is near
        """
        return self.local_surface(points, margin_mm)[0]

    def local_surface(self, points, margin_mm=0.05):
        """The designed face's normal and second fundamental form at (or nearest to) ``points``.

        The point is located as by :meth:`normal`; at its ``(u, v)`` the face's adaptor gives the
        derivatives ``S_u, S_v, S_uu, S_uv, S_vv`` (``BRepAdaptor_Surface.D2``), and the second
        fundamental form ``II_ab = S_ab . n`` (``n`` the face's normal, orientation included) is
        written as the 3 x 3 tangent tensor ``Hess = J+^T II J+`` (``J = [S_u S_v]``,
        ``J+ = (J^T J)^-1 J^T``): the height of the surface along ``n`` over its tangent plane is
        ``w(t) = t^T Hess t / 2`` to second order.

        Parameters
        ----------
        points : (m, 3) float, mm, panel frame
        margin_mm : float, mm, as in :meth:`normal`

        Returns
        -------
        n : (m, 3) float, unit, panel frame, the face's orientation; NaN where no face is near
        hess : (m, 3, 3) float, 1/mm, panel frame, the second fundamental form along ``n``
            (flip its sign with ``n``); NaN where no face is near
        """
        from OCP.BRepAdaptor import BRepAdaptor_Surface
        from OCP.BRepGProp import BRepGProp_Face
        from OCP.gp import gp_Pnt, gp_Vec

        pts = np.asarray(points, float).reshape(-1, 3) / self.scale
        out = np.full(pts.shape, np.nan)
        hess = np.full((len(pts), 3, 3), np.nan)
        m = margin_mm / self.scale
        for i, p in enumerate(pts):
            hit = self._locate(p, m)
            if hit is None:
                continue
            face, (u, v) = hit
            at, vec = gp_Pnt(), gp_Vec()
            BRepGProp_Face(face).Normal(u, v, at, vec)
            n = np.array([vec.X(), vec.Y(), vec.Z()])
            n /= np.linalg.norm(n)
            d = [gp_Vec() for _ in range(5)]
            BRepAdaptor_Surface(face).D2(u, v, gp_Pnt(), *d)
            su, sv, suu, svv, suv = (np.array([w.X(), w.Y(), w.Z()]) for w in d)
            J = np.stack([su, sv], axis=1)  # (3, 2)
            II = np.array([[suu @ n, suv @ n], [suv @ n, svv @ n]])
            Jp = np.linalg.solve(J.T @ J, J.T)  # (2, 3)
            out[i] = n
            hess[i] = Jp.T @ II @ Jp / self.scale
        return out, hess

    def disc_points(self, P, n, e1, e2, rho: float, count: int = DISC_POINTS):
        """Points of the designed faces over each hole's disc: ``count`` points of the tangent plane
        (``P + s e1 + t e2``, ``|(s, t)| <= rho``, a sunflower spiral) each projected onto the nearest face that holds
        it (as :meth:`normal` locates a point), then moved in the tangent plane by what the projection took from its
        ``(s, t)`` and projected again (on R 50 a point at 31 mm lands at 26.5, then at 29); points no face holds
        are left out.

        Parameters
        ----------
        P : (m, 3) float, mm, panel frame, the drill points; n, e1, e2 : (m, 3) unit, their local frames
        rho : float, mm, the disc's radius
        count : int, points per disc

        Returns
        -------
        list of m (k_i, 3) float, mm, panel frame: each hole's points (a sampling of the surface, as a mesh's
        vertices are; one hole's alone, so no two holes' samplings mix in a fit)
        """
        from OCP.BRepGProp import BRepGProp_Face
        from OCP.gp import gp_Pnt, gp_Vec

        k = np.arange(count)
        r, a = rho * np.sqrt((k + 0.5) / count), k * np.pi * (3.0 - np.sqrt(5.0))  # the golden angle
        st0 = np.stack([r * np.cos(a), r * np.sin(a)], 1) / self.scale
        m = rho / self.scale

        def onto(q):  # the face point nearest q (OCC units), or None
            hit = self._locate(q, m)
            if hit is None:
                return None
            face, (u, v) = hit
            at = gp_Pnt()
            BRepGProp_Face(face).Normal(u, v, at, gp_Vec())
            return np.array([at.X(), at.Y(), at.Z()])

        out = []
        for i in range(len(P)):
            E = np.stack([e1[i], e2[i]])  # (2, 3)
            p0 = P[i] / self.scale
            pts = []
            for st in st0:
                q = p0 + st @ E
                x = onto(q)
                if x is None:
                    continue
                x = onto(q + (st - E @ (x - p0)) @ E)  # once more, its (s, t) put back
                if x is not None:
                    pts.append(x)
            out.append(np.asarray(pts, float).reshape(-1, 3) * self.scale)
        return out
