"""The exact reference of a STEP panel: its B-rep, evaluated by OpenCASCADE (``cadquery-ocp-novtk``).

Optional (the ``step-exact`` extra). Where it is installed and the panel is a STEP file,
the reference normal at a point is the normal of the designed face there: the point is
projected onto the surface of each face near it (``GeomAPI_ProjectPointOnSurf``), the face
that holds it (``BRepClass_FaceClassifier``) and is nearest is kept, and its normal comes
from ``BRepGProp_Face.Normal`` (face orientation included). No tessellation enters.
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
        from OCP.BRep import BRep_Tool
        from OCP.BRepClass import BRepClass_FaceClassifier
        from OCP.BRepGProp import BRepGProp_Face
        from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf
        from OCP.TopAbs import TopAbs_OUT
        from OCP.gp import gp_Pnt, gp_Vec

        pts = np.asarray(points, float).reshape(-1, 3) / self.scale
        out = np.full(pts.shape, np.nan)
        m = margin_mm / self.scale
        for i, p in enumerate(pts):
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
            if best[1] is None:
                continue
            face, (u, v) = best[1]
            at, vec = gp_Pnt(), gp_Vec()
            BRepGProp_Face(face).Normal(u, v, at, vec)
            out[i] = [vec.X(), vec.Y(), vec.Z()]
        return out / np.linalg.norm(out, axis=1, keepdims=True)
