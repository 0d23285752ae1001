"""Effects of the set-up and of single readings: datum form, pose error, outliers (registry entries)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from metrology.core.effects.base import Component

__all__ = ["PlaneForm", "PoseError", "Outliers"]


@dataclass(frozen=True)
class PlaneForm(Component):
    """Datum form ``w = b_s s + b_t t + b_ss s^2 + b_st s t + b_tt t^2`` (s, t in units of
    ``radius_mm`` from the datum centre, along the plane's axes in the tracker frame).

    The datum's deviation from the plane it was given as, along the plane normal, at the
    spot; the reading changes by ``w / (N.u)``. The quadratic part is the datum's bow,
    saddle and twist; the linear part a tilt of the datum under the spots against the plane
    fitted to the cloud (which the cloud's own extent and the centre's choice leave). A
    constant part is the plane's offset, absorbed by the zero points.

    ``order`` sets the polynomial: 1 is the tilt alone (``b_s, b_t``: the datum plane's own
    uncertainty, a nuisance, never form), 2 adds bow, saddle and twist, 3 adds the four cubic
    terms (``b_sss, b_sst, b_stt, b_ttt``). The diagnosis tests form *beyond* the plane: order 2
    or 3 against order 1 (the tilt carried as a nuisance parameter in both).

    ``order=0`` is the datum *as scanned*: the deviation ``w_scan`` of the tracker's datum cloud
    from its plane at each spot (:attr:`Covariates.scan_w`), times a gain ``scan_gain`` (1 when the
    readings see the surface the tracker scanned), with the tilt as nuisance: any form, however
    high its order, with one parameter. Offered only when the datum cloud covers every spot.
    """

    radius_mm: float = 100.0
    order: int = 2

    name = "plane_form"
    advice = "spots over the whole datum, each region seen at several tilts"
    size_meaning = "bow b_ss mm at 100 mm (b_st = 0.3, b_tt = -0.5 of it)"
    plot_key = "spot_s_mm"
    #: the quadratic part (bow, saddle, twist): what the datum cloud is compared on
    key_params = ("b_ss_mm", "b_st_mm", "b_tt_mm")
    setup = True
    detectable_meaning = "peak-to-valley of the scanned datum form"

    @classmethod
    def candidates_for_setup(cls, names, cov, flags=None):
        out = [cls((), names=names), cls((), names=names, order=3)]
        if cov.scan_w is not None and np.all(np.isfinite(cov.scan_w)):
            out.append(cls((), names=names, order=0))
        return out

    @classmethod
    def hidden(cls, i, size):
        return cls((), [0.0, 0.0, size, 0.3 * size, -0.5 * size])

    _NAMES = ("b_s_mm", "b_t_mm", "b_ss_mm", "b_st_mm", "b_tt_mm", "b_sss_mm", "b_sst_mm", "b_stt_mm", "b_ttt_mm")

    def __post_init__(self):
        if self.order not in (0, 1, 2, 3):
            raise ValueError(f"plane_form order must be 0 (as scanned), 1, 2 or 3, got {self.order}")
        super().__post_init__()

    @property
    def param_names(self):
        if self.order == 0:
            return ("b_s_mm", "b_t_mm", "scan_gain")
        return self._NAMES[:{1: 2, 2: 5, 3: 9}[self.order]]

    @property
    def param_units(self):
        return ("mm", "mm", "1") if self.order == 0 else ("mm",) * len(self.param_names)

    @property
    def label(self):
        return self.name + {0: "@scan", 1: "@tilt", 2: "", 3: "@cubic"}[self.order]

    def size(self, C, d0, cov):
        """The form as scanned (``order=0``): the scan's peak-to-valley over the cloud beyond its
        best plane times the gain the readings see; none for the polynomial members."""
        if self.order != 0 or not np.isfinite(cov.scan_ptp_mm):
            return super().size(C, d0, cov)
        g, se_g = abs(float(self.values[2])), float(np.sqrt(max(C[2, 2], 0.0)))
        se_ptp = float(getattr(cov, "scan_ptp_se_mm", 0.0) or 0.0)
        return {"value": g * cov.scan_ptp_mm, "stderr": float(np.hypot(se_g * cov.scan_ptp_mm, g * se_ptp)),
                "unit": "mm", "meaning": "peak-to-valley of the scanned datum form over the cloud (beyond its best "
                                        "plane), times the gain the readings see"}

    def detectable_direction(self):
        return np.eye(self.n_params)[self.param_names.index("scan_gain")] if self.order == 0 else None

    def nuisance(self) -> "PlaneForm | None":
        """The datum's tilt alone (order 1): what form is tested against (None for the tilt itself)."""
        if self.order == 1:
            return None
        return replace(self, order=1, values=None, stderr=None)

    #: total degrees tried for the smooth surface fitted to the datum cloud (:meth:`scan_surface`)
    SCAN_DEGREES = (2, 3, 4, 5, 6, 7, 8)

    @staticmethod
    def _cv_degree(st, w, design, folds):
        """``(degree, degrees)``: the degree of :data:`SCAN_DEGREES` with the smallest
        ``folds``-fold cross-validated squared error (1 when the cloud is too small for any), and
        the degrees the cloud allows. Every degree's columns are a
        subset of the largest's, so each fold's normal equations are summed once over the
        cloud and the folds' fits are solved from them (the Legendre columns on the box are
        well conditioned; a cloud of 10^5 points costs one design matrix, not 70 fits)."""
        degs = [d for d in PlaneForm.SCAN_DEGREES if (d + 1) * (d + 2) // 2 * 10 <= len(w)]
        if not degs:
            return 1, [1]
        top = degs[-1]
        V = design(st, top)
        # columns of degree d: i + j <= d among the top degree's (i, j) in its column order
        ij = [(i, j) for i in range(top + 1) for j in range(top + 1) if i + j <= top]
        fold = np.arange(len(w)) % folds
        G = np.stack([V[fold == k].T @ V[fold == k] for k in range(folds)])
        b = np.stack([V[fold == k].T @ w[fold == k] for k in range(folds)])
        ww = np.array([w[fold == k] @ w[fold == k] for k in range(folds)])
        Gs, bs = G.sum(axis=0), b.sum(axis=0)
        best = None
        for deg in degs:
            cols = np.array([c for c, (i, j) in enumerate(ij) if i + j <= deg])
            err = 0.0
            for k in range(folds):
                Gt = (Gs - G[k])[np.ix_(cols, cols)]
                c = np.linalg.lstsq(Gt, (bs - b[k])[cols], rcond=None)[0]
                Gk = G[k][np.ix_(cols, cols)]
                err += float(c @ Gk @ c - 2.0 * c @ b[k][cols] + ww[k])
            if best is None or err < best[0]:
                best = (err, deg)
        return best[1], degs

    @staticmethod
    def scan_surface(points, plane_normal, plane_offset, centre, folds=5):
        """The datum's deviation from its plane as the tracker scanned it: a smooth surface.

        One least-squares surface over the whole cloud, 2-D Legendre polynomials over the
        cloud's bounding box, of the total degree in :data:`SCAN_DEGREES` with the smallest
        ``folds``-fold cross-validated error (at least 10 points per coefficient). It follows
        form up to that order and averages the tracker noise over the whole scan (a local fit
        of a few tens of points leaves several um of the tracker's noise in the surface).

        points : (m, 3) float, mm, tracker frame; plane_normal : (3,) unit; plane_offset : mm;
        centre : (3,) mm, tracker frame. Returns ``(w, box)``: ``w(st)`` a function of in-plane
        positions ``(..., 2)`` mm from ``centre`` giving mm (NaN outside the box), with
        ``w.stderr(st)`` its standard error (mm), ``w.degree`` its total degree and
        ``w.neighbour()`` the surface of the next degree the cloud allows (the one below at the
        top; None if there is none), and ``box`` ``(lo (2,), hi (2,))`` mm.
        """
        from numpy.polynomial import legendre

        from metrology.core.plane import plane_basis

        P = np.asarray(points, float)
        n = np.asarray(plane_normal, float)
        st = (P - np.asarray(centre, float)) @ plane_basis(n).T
        w = P @ n + float(plane_offset)
        lo, hi = st.min(axis=0), st.max(axis=0)
        mid, half = 0.5 * (lo + hi), np.maximum(0.5 * (hi - lo), 1e-9)

        def design(xy, deg):
            x = (xy - mid) / half
            V = legendre.legvander2d(x[:, 0], x[:, 1], [deg, deg])
            return V[:, [i * (deg + 1) + j for i in range(deg + 1) for j in range(deg + 1) if i + j <= deg]]

        deg, degs = PlaneForm._cv_degree(st, w, design, folds)
        return PlaneForm._surface(st, w, design, deg, degs, lo, hi, half)

    @staticmethod
    def _surface(st, w, design, deg, degs, lo, hi, half):
        """The height function of :meth:`scan_surface` at the total degree ``deg`` (``degs`` the
        degrees the cloud allows, for ``height.neighbour``)."""
        V = design(st, deg)
        coef = np.linalg.lstsq(V, w, rcond=None)[0]
        s2 = float(np.sum((V @ coef - w) ** 2)) / max(len(w) - V.shape[1], 1)
        cov_coef = np.linalg.pinv(V.T @ V, rcond=1e-12, hermitian=True) * s2

        def height(st_query, grow=0.0):
            """Height (mm) at ``st_query (..., 2)`` mm; NaN outside the box widened by ``grow``
            times its half-widths on each side (0: the box; beyond it the surface extrapolates)."""
            q = np.asarray(st_query, float)
            flat = q.reshape(-1, 2)
            ok = np.all(np.isfinite(flat), axis=1) & np.all((flat >= lo - grow * half) & (flat <= hi + grow * half), axis=1)
            out = np.full(len(flat), np.nan)
            if np.any(ok):
                out[ok] = design(flat[ok], deg) @ coef
            return out.reshape(q.shape[:-1])

        def stderr(st_query):
            """Standard error (mm) of ``height`` at ``st_query (..., 2)`` (the tracker's noise
            through the fit; NaN outside the box)."""
            q = np.asarray(st_query, float)
            flat = q.reshape(-1, 2)
            ok = np.all(np.isfinite(flat), axis=1) & np.all((flat >= lo) & (flat <= hi), axis=1)
            out = np.full(len(flat), np.nan)
            if np.any(ok):
                D = design(flat[ok], deg)
                out[ok] = np.sqrt(np.maximum(np.einsum("ik,kl,il->i", D, cov_coef, D), 0.0))
            return out.reshape(q.shape[:-1])

        def neighbour():
            """The surface of the next degree the cloud allows (the one below at the top; None
            when there is no other): how much a figure of the surface owes to the degree chosen."""
            up = [d for d in degs if d > deg]
            down = [d for d in degs if d < deg]
            other = up[0] if up else (down[-1] if down else None)
            return None if other is None else PlaneForm._surface(st, w, design, other, (), lo, hi, half)[0]

        height.stderr = stderr
        height.degree = deg
        height.neighbour = neighbour
        return height, (lo, hi)

    def monomials(self, st_mm):
        """``(..., k)``: ``s, t, s^2, s t, t^2`` (and ``s^3, s^2 t, s t^2, t^3`` at order 3; ``s, t``
        at order 1) at in-plane positions ``st_mm (..., 2)`` mm."""
        s, t = st_mm[..., 0] / self.radius_mm, st_mm[..., 1] / self.radius_mm
        cols = [s, t, s * s, s * t, t * t, s**3, s * s * t, s * t * t, t**3]
        return np.stack(cols[:self.n_params], axis=-1)

    def height(self, st_mm):
        """``w (...)`` mm: the datum's deviation along its normal at ``st_mm (..., 2)`` mm."""
        return self.monomials(st_mm) @ self.values

    def basis(self, d0, cov):
        if self.order == 0:
            st = cov.spot_st / self.radius_mm
            return np.stack([st[..., 0], st[..., 1], cov.scan_w], axis=-1) * cov.inv_nu[..., None]
        return self.monomials(cov.spot_st) * cov.inv_nu[..., None]

    @classmethod
    def from_cloud(cls, points, plane_normal, plane_offset, centre, radius_mm=100.0, names=()):
        """The datum's form measured by the tracker, as a component (values and stderr).

        Least squares of the points' signed distance to the plane on ``1`` and
        :meth:`monomials`, in the axes the readings' component uses
        (:func:`~metrology.simulation.plane_basis` of the normal, from ``centre``): an
        independent measurement of the surface the beams see. Its quadratic part (bow,
        saddle, twist) must agree with a ``plane_form`` fitted to the readings; the constant
        is the plane's offset (dropped), the linear part the cloud's tilt against the plane
        given (zero when that plane was fitted to this cloud).

        Parameters
        ----------
        points : (m, 3) float, mm, tracker frame, m >= 7
        plane_normal : (3,) float, unit, tracker frame; plane_offset : float, mm
        centre : (3,) float, mm, tracker frame (as in :func:`metrology.diagnosis.covariates_for`)
        radius_mm : float, the unit of ``s, t``

        Returns
        -------
        form : PlaneForm, values with stderr
        cov : (5, 5) float, covariance of the values, ``s^2 (A^T A)^-1`` with ``s`` the
            residual scatter (which also takes up any form beyond quadratic)
        """
        from metrology.core.plane import plane_basis

        P = np.asarray(points, float)
        if P.ndim != 2 or P.shape[1] != 3 or len(P) < 7:
            raise ValueError(f"datum cloud: need (m >= 7, 3) points, got shape {P.shape}")
        n = np.asarray(plane_normal, float)
        w = P @ n + float(plane_offset)
        form = cls((), names=tuple(names), radius_mm=radius_mm)
        A = np.concatenate([np.ones((len(P), 1)), form.monomials((P - np.asarray(centre, float)) @ plane_basis(n).T)],
                           axis=1)
        coef, *_ = np.linalg.lstsq(A, w, rcond=None)
        r = w - A @ coef
        C = np.linalg.pinv(A.T @ A) * (float(r @ r) / max(len(w) - 6, 1))
        C5 = C[1:, 1:]
        return form.with_values(coef[1:], np.sqrt(np.maximum(np.diag(C5), 0.0))), C5


@dataclass(frozen=True)
class PoseError(Component):
    """Per-pose TCS position error ``e_p`` along the datum normal (tracker, robot settling):
    the reading of every sensor of pose ``p`` changes by ``e_p / (N.u)``, a common mode.
    ``n_poses`` parameters with the gauge ``sum_p e_p N_p = 0`` (``N_p`` the plane normal in the
    TCS of pose ``p``): moving every zero point by ``v`` is exactly the per-pose error
    ``-N_p . v``. The diagnosis profiles the values out of its fit (variable projection, with
    that gauge); the row of :meth:`constraint` (``sum e_p = 0``) serves a direct joint fit."""

    n_poses: int = 0
    tilts: bool = False
    hold: bool = True

    name = "pose_error"
    per_pose = True
    advice = "repeated poses, or more sensors per pose"
    size_meaning = "1-sigma TCS position error per axis, mm"
    plot_term = False
    setup = True
    detectable_meaning = "RMS change of a reading by a per-pose rigid error (offset and tilts), any split"

    @classmethod
    def candidates_for_setup(cls, names, cov, flags=None):
        out = [cls((), names=names, n_poses=cov.n_poses)]
        if cov.inv_nu.shape[1] >= 4:  # 3 readings a pose are all taken by an offset and two tilts
            out.append(cls((), names=names, n_poses=cov.n_poses, tilts=True))
        return out
    #: weight of the gauge row (per mm of sum), large against 1/sigma
    GAUGE_WEIGHT = 1e4
    #: lever (mm) of the tilt columns: a tilt is given as the displacement at this distance
    RADIUS_MM = 100.0

    @property
    def per_pose_columns(self) -> int:
        """Parameters per pose: the offset along the datum normal, and with ``tilts`` the two
        tilts of the datum seen from the TCS (mm at :attr:`RADIUS_MM` from the datum centre)."""
        return 3 if self.tilts else 1

    @property
    def gauge_dof(self) -> int:
        """Directions shared with the base geometry: a translation of every zero point (3), and
        with ``tilts`` a rotation of the whole head (3 more; the fit holds the base parameters
        off these six, :func:`metrology.diagnosis.fit.fit`)."""
        return 6 if self.tilts else 3

    @property
    def holds_base(self) -> bool:
        """The fit holds the base geometry at the base calibration (``tilts`` and ``hold``): an
        offset and two tilts a pose leave one reading in four to the geometry, which then drifts
        along every combination those poses leave weak (millimetres of zero point, measured) and
        predicts held-out poses badly. The diagnosis scores the candidate so, and refits the
        named cause with the geometry free (``hold=False``, the rigid-head gauge fixed)."""
        return self.tilts and self.hold

    def geometry_member(self):
        """The offset member: the rigid member holds the geometry where the offset member's fit,
        given the same causes, puts it (it profiles out the error's common mode)."""
        return replace(self, tilts=False, values=None, stderr=None) if self.holds_base else None

    def for_joint_fit(self):
        """Refitted with the geometry free (the rigid-head gauge fixed)."""
        return replace(self, values=None, stderr=None, hold=False)

    @property
    def label(self):
        return self.name + ("@rigid" if self.tilts else "")

    @property
    def n_params(self) -> int:  # as len(param_names), without making a name for every pose
        return self.n_poses * self.per_pose_columns

    @property
    def param_names(self):
        if not self.tilts:
            return tuple(f"e{j}_mm" for j in range(self.n_poses))
        return tuple(f"{q}{j}_mm" for j in range(self.n_poses) for q in ("e", "ts", "tt"))

    @property
    def param_units(self):
        return ("mm",) * self.n_params

    def select(self, idx):
        k = len(np.arange(self.n_poses)[idx])
        m = self.per_pose_columns
        v = np.asarray(self.values).reshape(self.n_poses, m)[idx].ravel()
        return replace(self, n_poses=k, values=v, stderr=None)

    def pose_columns(self, cov):
        """``(p, n, m)``: each pose's own columns (``m`` = :attr:`per_pose_columns`)."""
        if not self.tilts:
            return cov.inv_nu[..., None]
        st = cov.spot_st / self.RADIUS_MM
        return np.stack([cov.inv_nu, st[..., 0] * cov.inv_nu, st[..., 1] * cov.inv_nu], axis=-1)

    def basis(self, d0, cov):
        p, n = d0.shape
        m = self.per_pose_columns
        B = np.zeros((p, n, p, m))
        B[np.arange(p), :, np.arange(p), :] = self.pose_columns(cov)
        return B.reshape(p, n, p * m)

    def constraint(self, values):
        m = self.per_pose_columns
        row = np.zeros((1, self.n_params))
        row[0, ::m] = self.GAUGE_WEIGHT
        return row @ np.asarray(values, float), row

    def describe(self):
        out = super().describe()
        v = np.asarray(self.values).reshape(self.n_poses, self.per_pose_columns)[:, 0]
        out["params"] = {"sigma_mm": {"value": float(np.std(v, ddof=1)) if len(v) > 1 else 0.0, "unit": "mm",
                                      "stderr": None}}
        return out


@dataclass(frozen=True)
class Outliers(Component):
    """Gross readings: one free term ``g_j`` (mm) per flagged reading, which is the same as
    leaving the reading out. ``flags`` is the ``(p, n)`` boolean mask of flagged readings."""

    flags: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), bool))

    name = "outliers"
    advice = "the flagged poses repeated"
    size_meaning = "3 gross readings of +-size mm"
    plot_term = False
    drops_readings = True
    detectable_meaning = "one gross reading"

    @classmethod
    def candidates_for_sensor(cls, i, names, cov):
        return []  # one candidate for all flagged readings: candidates_for_setup

    @classmethod
    def candidates_for_setup(cls, names, cov, flags=None):
        if flags is None or not np.any(flags):
            return []
        return [cls(tuple(sorted(set(np.argwhere(flags)[:, 1].tolist()))), names=names, flags=flags)]

    @property
    def cells(self):
        return np.argwhere(self.flags)

    @property
    def param_names(self):
        return tuple(f"g_p{p}_{self.names[i] if self.names else i}_mm" for p, i in self.cells)

    @property
    def param_units(self):
        return ("mm",) * len(self.cells)

    def select(self, idx):
        return replace(self, flags=self.flags[idx], values=None, stderr=None)

    def describe(self):
        """The flagged readings (pose, sensor, gross value with its standard error) and their count."""
        out = super().describe()
        stderr = np.full(len(self.cells), np.nan) if self.stderr is None else self.stderr
        out["flagged"] = [{"pose": int(pp), "sensor": self.names[i], "gross_mm": float(v), "stderr": float(s)}
                          for (pp, i), v, s in zip(self.cells, self.values, stderr)]
        out["params"] = {"count": {"value": len(self.cells), "unit": "1", "stderr": None}}
        return out

    def basis(self, d0, cov):
        p, n = d0.shape
        cells = self.cells
        B = np.zeros((p, n, len(cells)))
        B[cells[:, 0], cells[:, 1], np.arange(len(cells))] = 1.0
        return B

