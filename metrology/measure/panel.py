"""Each hole's local surface, from the CAD panel and its hole table (``metro measure --panel
PANEL --points HOLES.csv``), or from the hole table alone (``--points``).

**The hole table** (CSV or Parquet, as CAD/CAM exports it): ``hole_id,x,y,z,i,j,k``: the nominal
drill point (mm, the panel's frame) and the drill's feed direction into the panel; joined to the
log by ``hole_id``.

**From the panel** (:func:`metrology.panel.holes.panel_surfaces`, joined here by
:func:`metrology.jobs.measure_panel.panel_hole_surfaces`): the drill point is snapped onto the mesh (a STEP
file is tessellated with 1 um chords, :func:`metrology.panel.mesh.load_panel`); the CAD's normal
there (the mesh's reference normal, turned toward the head: against the feed) gives the local
frame ``(e1, e2, n)``, ``e1`` the panel's ``x`` made square to ``n`` (the cell's convention, as
the forward simulator's step 3). :data:`RING_SAMPLES` rays along ``-n`` on rings of the head's
footprint (``1/3, 2/3, 1`` times :data:`FOOTPRINT_MARGIN` x the footprint radius, and the
centre) sample the surface's heights ``w(s, t)``; a full quartic through the mesh's own vertices
near the point (a cubic through the ray-cast heights where it has too few) gives the Hessian ``H``
at the point, its gradient and its terms beyond second order (:mod:`metrology.measure.beyond`). The shape
operator is ``K = -H`` (positive where the surface bends away from the head). Its standard
uncertainty per component (``u_shape``, 1/mm) combines

- the fit: its residual (vertex noise; form beyond the fit's order) through the fit's
  covariance;
- the drill point's position error along the surface ``delta_s`` (``--position-error-mm``): the
  cubic's ``|grad K|`` times ``delta_s``, uniform over the disc (``/ 3``);
- a stated form tolerance ``t`` (``--form-tolerance-mm``, default 0: the panel is its CAD): a
  form error of ``+-t`` over the footprint is a curvature change of up to ``2 t / rho^2``, uniform.

**From the hole table alone** (:func:`surfaces_from_table`): each hole's shape operator from the
change of the nominal normals (``n = -feed``) to its :data:`NEIGHBOURS` nearest holes,
``n_j - n_i = K (p_j - p_i)`` in the tangent plane (least squares, 3 unknowns); its residual gives
``u_shape``.

**Into the TCS**: where the log carries the robot's commanded pose (``pose_*`` columns), by that
pose (:meth:`HoleSurfaces.shape_pose`), the head's spin known (no spin term in U95). Without it
(:meth:`HoleSurfaces.shape_tcs`) metro takes the cell's convention (the forward simulator's, metrology/sim/forward/log.py step 3): the head's
``tcs2panel = Q(-e_z -> a) F`` with ``a = -n`` and ``F = diag(1, -s, -s)`` (TCS ``x, y`` near the
panel's ``x, y``); the head's spin about the tool axis beyond that is within ``+-spin``
(``--spin-deg``), carried into U95 (:class:`metrology.measure.surface.PanelTerms`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from metrology.core.frames import embed_shape, principal_curvatures, tangent_frame
from metrology.core.sym3 import smallest_rotation

__all__ = ["HoleTable", "HoleSurfaces", "SurfaceSource", "TableNormals", "read_hole_table", "surfaces_from_table", "FOOTPRINT_MARGIN", "NEIGHBOURS"]

#: the sampled disc's radius over the head's footprint radius (the spots move out on a tilted head)
FOOTPRINT_MARGIN = 1.25
#: a hole table's feed i,j,k is a unit vector to this (CAM writes 6+ digits); beyond it the row is refused
FEED_UNIT_TOL = 1e-3
#: neighbours whose nominal normals give a hole's curvature without a panel
NEIGHBOURS = 6
#: without a panel, a hole whose footprint leaves more than this beyond the second order the table gives (mm: a
#: sphere of its largest curvature, ``|k|^3 rho^4 / 8``, four times the reading noise; R ~200 mm under a 27 mm
#: footprint) is not measured: only the CAD carries those terms (issue 53; ``--panel``)
TABLE_REMAINDER_MM = 0.02
#: the entries (00, 01, 02, 11, 12, 22) of a symmetric 3 x 3 matrix
_SIX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


@dataclass(frozen=True)
class HoleTable:
    """A hole table.

    Attributes
    ----------
    ids : tuple of str; point : (m, 3) float, mm, panel frame; feed : (m, 3) float, unit, panel frame
    source : str; line : callable, row -> how an error names it
    """

    ids: tuple
    point: np.ndarray
    feed: np.ndarray
    source: str
    csv: bool = True

    def line(self, row: int) -> str:
        return f"line {row + 2}" if self.csv else f"row {row + 1}"


def read_hole_table(path) -> HoleTable:
    """Read ``hole_id,x,y,z,i,j,k`` (CSV with a header, or Parquet). One-line ValueError naming the
    file, row and value: missing columns, non-numbers, NaN, a zero-length feed, duplicate ids."""
    path = str(path)
    if path.lower().endswith((".parquet", ".pq")):
        import pyarrow.parquet as pq

        try:
            t = pq.read_table(path)
        except Exception as exc:  # noqa: BLE001 - pyarrow raises many kinds
            raise ValueError(f"{path}: cannot read the hole table as Parquet ({exc})") from None
        cols = {c.lower(): c for c in t.column_names}
        missing = [c for c in ("hole_id", "x", "y", "z", "i", "j", "k") if c not in cols]
        if missing:
            raise ValueError(f"{path}: hole table lacks column(s) {', '.join(missing)} (expected hole_id,x,y,z,i,j,k)")
        ids = [str(v) if v is not None else "" for v in t.column(cols["hole_id"]).to_pylist()]
        vals = np.stack([t.column(cols[c]).to_numpy(zero_copy_only=False).astype(float) for c in "xyzijk"], axis=1)
        return _checked(path, ids, vals, csv=False)
    from metrology.io.export import read_csv_rows

    rows = read_csv_rows(path, "hole table")
    rows = [(n, r) for n, r in enumerate(rows, start=1) if r and not all(c.strip() == "" for c in r)
            and not r[0].strip().startswith("#")]
    if not rows:
        raise ValueError(f"{path}: an empty hole table (expected a header hole_id,x,y,z,i,j,k and a row per hole)")
    head = [c.strip().lower() for c in rows[0][1]]
    missing = [c for c in ("hole_id", "x", "y", "z", "i", "j", "k") if c not in head]
    if missing:
        raise ValueError(f"{path}: line {rows[0][0]}: header lacks {', '.join(missing)} (expected hole_id,x,y,z,i,j,k)")
    at = [head.index(c) for c in ("hole_id", "x", "y", "z", "i", "j", "k")]
    ids, vals = [], []
    for lineno, r in rows[1:]:
        if len(r) < len(head):
            raise ValueError(f"{path}: line {lineno}: {len(r)} columns, the header has {len(head)}")
        ids.append(r[at[0]].strip())
        v = []
        for name, j in zip("xyzijk", at[1:]):
            try:
                v.append(float(r[j]))
            except ValueError:
                raise ValueError(f"{path}: line {lineno}: {name} = {r[j]!r} is not a number") from None
        vals.append(v)
    if not ids:
        raise ValueError(f"{path}: no holes (a header only)")
    return _checked(path, ids, np.array(vals, float), csv=True, lines=[n for n, _ in rows[1:]])


def _checked(path, ids, vals, csv, lines=None) -> HoleTable:
    def where(r):
        return f"line {lines[r]}" if lines is not None else f"row {r + 1}"

    for r, h in enumerate(ids):
        if h == "":
            raise ValueError(f"{path}: {where(r)}: hole_id is empty")
    bad = np.flatnonzero(~np.all(np.isfinite(vals), axis=1))
    if bad.size:
        r = int(bad[0])
        raise ValueError(f"{path}: {where(r)}: hole {ids[r]}: NaN or infinite value in x,y,z,i,j,k "
                         f"({', '.join(f'{v:g}' for v in vals[r])})")
    feed = vals[:, 3:]
    norm = np.linalg.norm(feed, axis=1)
    zero = np.flatnonzero(~(norm > 1e-9))
    if zero.size:
        r = int(zero[0])
        raise ValueError(f"{path}: {where(r)}: hole {ids[r]}: feed direction i,j,k is zero-length")
    off = np.flatnonzero(np.abs(norm - 1.0) > FEED_UNIT_TOL)
    if off.size:  # a unit vector by the table's contract: another length is a column out of place, not a scale
        r = int(off[0])
        raise ValueError(f"{path}: {where(r)}: hole {ids[r]}: feed direction i,j,k has length {norm[r]:.6g}, expected "
                         f"a unit vector (within {FEED_UNIT_TOL:g}; {off.size} row(s) so)")
    seen = {}
    for r, h in enumerate(ids):
        if h in seen:
            raise ValueError(f"{path}: {where(r)}: duplicate hole_id {h!r} (also {where(seen[h])})")
        seen[h] = r
    return HoleTable(tuple(ids), vals[:, :3].copy(), feed / norm[:, None], path, csv)


@dataclass(frozen=True)
class HoleSurfaces:
    """Each hole's local surface (panel frame).

    Attributes
    ----------
    ids : tuple of str
    normal : (m, 3) float, unit, panel frame, the CAD's normal at the hole, toward the head
    shape : (m, 3, 3) float, 1/mm, panel frame, the shape operator (positive bending away from the head)
    k : (m, 2) float, 1/mm, the principal curvatures (k1 >= k2)
    u_shape : (m,) float, 1/mm, standard uncertainty of each component of ``shape``
    problem : (m,) object, "" or why the hole cannot be measured (its footprint runs off the panel)
    source : str, where the curvature came from (named in the verdict and the JSON)
    spin : float, rad, the head's spin about the tool axis relative to the panel is within +-spin
    spin_stated : bool, ``spin`` was stated (``--spin-deg``): a hole without a pose and without a redundant
        reading takes the cell's convention; else its spin is not known (:mod:`metrology.measure.spin`)
    point : (m, 3) float, mm, panel frame, the table's nominal drill point, or None
    frame : (m, 2, 3) float, unit, panel frame, the local axes ``e1, e2`` of ``higher``, or None
    higher : (m, 9) float, the CAD surface's height along ``normal`` beyond second order, or None: the
        coefficients of ``s^3/6, s^2 t/2, s t^2/2, t^3/6`` (1/mm^2) and ``s^4/24, s^3 t/6, s^2 t^2/4,
        s t^3/6, t^4/24`` (1/mm^3), ``s, t`` mm along ``e1, e2`` from the drill point; where the footprint is
        large against the radius, (m, 39): degrees 5 to 8 after them (:mod:`metrology.panel.footprint`)
    u_height : (m,) float, mm, or None: the height over the footprint that no term carries (a term of U95:
        :mod:`metrology.measure.remainder`)
    """

    ids: tuple
    normal: np.ndarray
    shape: np.ndarray
    k: np.ndarray
    u_shape: np.ndarray
    problem: np.ndarray
    source: str
    spin: float = 0.0
    point: np.ndarray | None = None
    frame: np.ndarray | None = None
    higher: np.ndarray | None = None
    spin_stated: bool = True
    u_height: np.ndarray | None = None
    _tcs: dict = field(default_factory=dict, compare=False, repr=False)

    def rows(self, hole_ids):
        """Each log row's index into the table (``hole_ids`` a pyarrow string array), -1 where absent."""
        import pyarrow as pa
        import pyarrow.compute as pc

        idx = pc.index_in(hole_ids, value_set=pa.array(self.ids, pa.string()))
        return np.asarray(pc.fill_null(idx, -1).to_numpy(zero_copy_only=False), dtype=np.int64)

    def shape_tcs(self, rows, s: float):
        """(h, 3, 3) float, 1/mm, TCS: the shape operators of table rows ``rows`` under the cell's
        convention (module docstring); ``s`` the drill axis's sign (``s e_z``)."""
        if s not in self._tcs:  # once per table and axis sign: every batch of the log takes its rows
            R = tcs2panel_nominal(self.normal, s)  # (m, 3, 3)
            self._tcs[s] = np.einsum("hji,hjk,hkl->hil", R, self.shape, R)
        return self._tcs[s][rows]

    def shape_pose(self, rows, tcs2panel, s: float):
        """(h, 3, 3) float, 1/mm, TCS: the shape operators of table rows ``rows`` under the robot's
        commanded pose ``tcs2panel`` ((h, 3, 3), columns the TCS axes in the panel frame), turned
        square to the drill axis ``s e_z`` by the smallest rotation taking the CAD's normal there
        (as :func:`metrology.measure.surface.fit_surface` takes it: it turns it onto the fitted
        tangent plane; the pose's spin about the tool axis is kept).

        ``Q T^T S T Q^T`` (``T`` the pose, ``S`` the shape in the panel frame, ``Q`` that rotation): its
        entries are ``p_i^T S p_j`` with ``p_i = T Q^T e_i`` (panel frame); entry by entry over the holes
        (no batched 3 x 3 products). Where the CAD's normal does not face the head (``s n_z >= -1e-6`` in
        the TCS) ``T^T S T`` as it is."""
        if "entries" not in self._tcs:  # once per table: each entry a contiguous array to gather from
            self._tcs["entries"] = [np.ascontiguousarray(self.shape[:, i, j]) for i, j in _SIX] + \
                [np.ascontiguousarray(self.normal[:, i]) for i in range(3)]
        e = self._tcs["entries"]
        s00, s01, s02, s11, s12, s22, n0, n1, n2 = (x[rows] for x in e)
        T = np.asarray(tcs2panel, float)
        Tt = np.ascontiguousarray(T.reshape(-1, 9).T)  # (9, h): each entry contiguous (read three times)
        r = [[Tt[3 * j + i] for i in range(3)] for j in range(3)]  # r[j][i] = T_ji
        ntx, nty, ntz = (r[0][i] * n0 + r[1][i] * n1 + r[2][i] * n2 for i in range(3))  # the CAD's normal, TCS
        sg = -s
        ok = sg * ntz > 1e-6
        # Q: the smallest rotation taking sg e_z onto (-nt_x, -nt_y, nt_z) (that taking nt onto sg e_z,
        # mirrored about the axis): I + [v]x + f [v]x^2, v = sg e_z x m = (sg nt_y, -sg nt_x, 0)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):  # NaN where not ok: replaced below
            q = smallest_rotation(sg * nty, -sg * ntx, 0.0, sg * ntz)
            p = [[q[k][0] * r[j][0] + q[k][1] * r[j][1] + q[k][2] * r[j][2] for j in range(3)] for k in range(3)]

            def sp(v):  # S v
                return (s00 * v[0] + s01 * v[1] + s02 * v[2], s01 * v[0] + s11 * v[1] + s12 * v[2],
                        s02 * v[0] + s12 * v[1] + s22 * v[2])

            a = [sp(v) for v in p]
            K = np.empty((len(ntz), 3, 3))
            for i, j in _SIX:
                K[:, i, j] = p[i][0] * a[j][0] + p[i][1] * a[j][1] + p[i][2] * a[j][2]
                if i != j:
                    K[:, j, i] = K[:, i, j]
        bad = np.flatnonzero(~ok)
        if bad.size:  # T^T S T, not turned
            Tb = T[bad]
            Sb = np.stack([s00[bad], s01[bad], s02[bad], s01[bad], s11[bad], s12[bad], s02[bad], s12[bad], s22[bad]],
                          axis=1).reshape(-1, 3, 3)
            K[bad] = np.einsum("hji,hjk,hkl->hil", Tb, Sb, Tb)
        return K

    def higher_tcs(self, rows, s: float, tcs2panel=None):
        """``(axes (h, 2, 3) unit TCS, higher (h, 9), tcs2panel (h, 3, 3))`` of table rows ``rows``: the
        local axes ``e1, e2`` of :attr:`higher` in the TCS of the commanded pose ``tcs2panel`` ((h, 3, 3),
        or the cell's convention where None) and that pose; None without :attr:`higher`."""
        if self.higher is None or self.frame is None:
            return None
        R = tcs2panel_nominal(self.normal[rows], s) if tcs2panel is None else tcs2panel
        if "frame" not in self._tcs:  # once per table: each component a contiguous array to gather from
            self._tcs["frame"] = np.ascontiguousarray(self.frame.reshape(-1, 6).T)
        F = [x[rows] for x in self._tcs["frame"]]  # F[3 k + j]: e_k's component j
        axes = np.empty((2, 3, len(F[0])))
        Rt = np.ascontiguousarray(R.reshape(-1, 9).T)  # (9, h): each entry contiguous
        for k in range(2):  # R^T e_k entry by entry over the holes (not an einsum with inner dims of 3)
            for i in range(3):
                axes[k, i] = Rt[i] * F[3 * k] + Rt[3 + i] * F[3 * k + 1] + Rt[6 + i] * F[3 * k + 2]
        return axes.transpose(2, 0, 1), self.higher[rows], R  # (h, 2, 3), a view: each component contiguous


def tcs2panel_nominal(n, s: float):
    """(h, 3, 3): the head's rotation with its tool axis on ``a = -n`` (``n (h, 3)`` unit, toward the
    head), no spin: ``Q(-e_z -> a) F``, ``F = diag(1, -s, -s)`` (columns)."""
    a = -np.asarray(n, float)
    q = smallest_rotation(a[:, 1], -a[:, 0], 0.0, -a[:, 2])  # -e_z x a, and the cosine
    Q = np.empty((len(a), 3, 3))
    for i in range(3):
        for j in range(3):
            Q[:, i, j] = q[i][j]
    return Q * np.array([1.0, -s, -s])


class SurfaceSource(Protocol):
    """Where each hole's local surface comes from: the CAD panel (a mesh, or a STEP B-rep's faces:
    :class:`metrology.jobs.measure_panel.CadPanel`) or the hole table alone (:class:`TableNormals`)."""

    def surfaces(self, table: HoleTable, footprint_mm: float, form_mm: float, spin: float) -> "HoleSurfaces":
        """The local surface of every hole of ``table`` (footprint radius and form tolerance mm, spin rad)."""


@dataclass(frozen=True)
class TableNormals:
    """The hole table alone: each hole's curvature from its neighbours' nominal normals."""

    def surfaces(self, table: HoleTable, footprint_mm: float, form_mm: float, spin: float) -> "HoleSurfaces":
        return surfaces_from_table(table, footprint_mm, form_mm, spin)


def surfaces_from_table(table: HoleTable, footprint_mm: float, form_mm: float = 0.0, spin: float = 0.0) -> HoleSurfaces:
    """Each hole's local surface from the nominal normals of its neighbours in the table (no panel)."""
    from scipy.spatial import cKDTree

    m = len(table.ids)
    n = -table.feed
    e1, e2 = tangent_frame(n)
    Kl = np.zeros((m, 2, 2))
    u = np.zeros(m)
    problem = np.full(m, "", dtype=object)
    if m < 4:
        raise ValueError(f"{table.source}: {m} holes: the curvature from neighbouring normals needs at least 4 "
                         f"(give --panel, or --min-radius-mm without --points)")
    kk = min(NEIGHBOURS, m - 1)
    _, nb = cKDTree(table.point).query(table.point, k=kk + 1)
    nb = nb[:, 1:]
    dp = table.point[nb] - table.point[:, None, :]  # (m, k, 3)
    dn = n[nb] - n[:, None, :]
    ds, dt = (dp * e1[:, None]).sum(2), (dp * e2[:, None]).sum(2)
    ns, nt = (dn * e1[:, None]).sum(2), (dn * e2[:, None]).sum(2)
    # unknowns (k11, k12, k22): ns = k11 ds + k12 dt; nt = k12 ds + k22 dt
    A = np.zeros((m, 2 * kk, 3))
    A[:, :kk, 0], A[:, :kk, 1] = ds, dt
    A[:, kk:, 1], A[:, kk:, 2] = ds, dt
    b = np.concatenate([ns, nt], axis=1)
    M = np.einsum("mpi,mpj->mij", A, A)
    ok = np.linalg.cond(M) < 1e8
    Ms = np.where(ok[:, None, None], M, np.eye(3))
    x = np.linalg.solve(Ms, np.einsum("mpi,mp->mi", A, b)[..., None])[..., 0]
    r = b - np.einsum("mpi,mi->mp", A, x)
    s2 = (r * r).sum(1) / max(2 * kk - 3, 1)
    var = s2[:, None] * np.diagonal(np.linalg.inv(Ms), axis1=1, axis2=2)
    u_fit = np.sqrt(var.mean(1))
    rho = FOOTPRINT_MARGIN * footprint_mm
    u_form = 2.0 * form_mm / (rho * rho) / math.sqrt(3.0)
    Kl[:, 0, 0], Kl[:, 0, 1], Kl[:, 1, 0], Kl[:, 1, 1] = x[:, 0], x[:, 1], x[:, 1], x[:, 2]
    for i in np.flatnonzero(~ok):
        problem[i] = "its neighbours in the hole table lie on a line: no curvature from their normals"
    kmax = np.abs(principal_curvatures(np.where(ok[:, None, None], Kl, 0.0))).max(1)
    for i in np.flatnonzero(ok & (kmax ** 3 * rho ** 4 / 8.0 > TABLE_REMAINDER_MM)):
        problem[i] = (f"a radius of {1.0 / kmax[i]:.0f} mm under the head's footprint (radius {rho:.0f} mm) leaves "
                      f"{1e3 * kmax[i] ** 3 * rho ** 4 / 8.0:.0f} um beyond the second order the hole table gives (at "
                      f"most {1e3 * TABLE_REMAINDER_MM:g}): give the panel (--panel), whose CAD carries it")
    Kl[~ok] = 0.0
    u = np.sqrt(u_fit ** 2 + u_form ** 2)
    return HoleSurfaces(table.ids, n, embed_shape(Kl, e1, e2), principal_curvatures(Kl),
                        np.where(np.isfinite(u), u, 0.0), problem,
                        f"hole table {table.source} (the nominal normals of each hole's {kk} nearest neighbours)", spin)
