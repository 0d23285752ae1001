"""One least-squares calibration: the base model plus effect components (shaped like lmfit's ``Minimizer``).

:class:`LeastSquares` owns the problem (the nominal layout, the readings, their weights, the
sensors whose parameters are free, and the components of the effect registry added to the
base model) and its methods follow the maths: :meth:`~LeastSquares.predict` (the readings of
the model at the parameters ``x``), :meth:`~LeastSquares.residual` and
:meth:`~LeastSquares.jacobian` (whitened, analytic), :meth:`~LeastSquares.solve` and
:meth:`~LeastSquares.covariance`. The base calibration (:func:`metrology.calibration.estimators.lsq`:
one sensor, no component) and the diagnosis' extended fits
(:func:`metrology.diagnosis.fit.fit`) are both this object.

The parameters ``x`` are the chart errors ``(x, y, z, a, b)`` of each free sensor (around the
nominal layout, :mod:`metrology.core.model`) then each component's values. A per-pose
component (:class:`~metrology.core.effects.PoseError`) is profiled out exactly (variable
projection): its basis does not depend on ``x``, so for any ``x`` its best values are a fixed
linear map of the residual.
"""

from __future__ import annotations

import numpy as np

from metrology.calibration.kept import Kept, content_key
from metrology.core.effects import ExtendedModel
from metrology.core.model import direction_basis, direction_from_tangent, jacobian_raw, readings, vector_norm

__all__ = ["LeastSquares", "gauss_newton", "geometry", "clear_held", "RIGID_GAUGE_WEIGHT", "ABSORBED_COLUMN_RTOL",
           "ABSORBED_RTOL", "INVALID_RESIDUAL"]

#: weight of the rigid-head gauge rows (whitened residual units per unit of the normalised mode)
RIGID_GAUGE_WEIGHT = 1e3
#: a column whose norm the per-pose projection leaves below this share of its own is absorbed (zeroed)
ABSORBED_COLUMN_RTOL = 1e-8
#: singular values of the projected base Jacobian below this share of the largest are held
ABSORBED_RTOL = 1e-3
#: the residual of a reading the model cannot place (beam parallel to or behind the plane), so
#: that a solver stepping there steps back
INVALID_RESIDUAL = 1e6

#: Gauss-Newton (:func:`gauss_newton`, and the batched folds of ``diagnosis.foldfit``): at most this
#: many steps; stop when the cost changes by less than this share of itself; the shortest step halving tries
GN_MAX_ITER = 30
GN_TOL = 1e-10
GN_MIN_STEP = 1e-4


def geometry(nominal, theta):
    """Zero points ``(n, 3)`` mm TCS and unit directions ``(n, 3)`` TCS of the chart errors
    ``theta (n, 5)`` around ``nominal``."""
    zero = nominal.zero + theta[:, :3]
    u = direction_from_tangent(nominal.direction, theta[:, 3:])
    return zero, u


def _project_per_pose(Bw, X, A):
    """Remove per-pose common modes: ``X - Bw e`` with ``e`` the weighted least-squares fit of
    each pose's rows of ``X`` on ``Bw`` under the gauge ``A^T e = 0``.

    Bw : (p, s) float, the per-pose column (zero where no reading); X : (p, s) or (p, s, k);
    A : (p, g) float, the gauge modes (for pose errors: the plane normal in each TCS, since a
    translation of every zero point by ``v`` is the per-pose error ``e_p = -N_p . v``).
    Returns (projected X, e (p,) or (p, k)).
    """
    bb = np.maximum(np.sum(Bw * Bw, axis=1), 1e-300)  # (p,)
    squeeze = X.ndim == 2
    Xk = X[..., None] if squeeze else X
    br = np.einsum("ps,psk->pk", Bw, Xk)  # (p, k)
    AW = A / bb[:, None]  # W^-1 A
    lam = np.linalg.solve(A.T @ AW, AW.T @ br)  # (g, k)
    e = (br - A @ lam) / bb[:, None]
    out = Xk - Bw[..., None] * e[:, None, :]
    return (out[..., 0], e[:, 0]) if squeeze else (out, e)


def _project_per_pose_multi(Bw, X, Bpinv=None):
    """Remove each pose's own columns: ``X - Bw e`` with ``e = Bw_p^+ X_p`` per pose.

    Bw : (p, s, m) float, each pose's columns (zero where no reading); X : (p, s) or (p, s, k);
    Bpinv : (p, m, s) float, ``pinv(Bw)`` if already computed. The directions these share with
    the base geometry (a rigid motion of the whole head) are left to the solver's
    rank-revealing step. Returns (projected X, e (p, m) or (p, m, k)).
    """
    squeeze = X.ndim == 2
    Xk = X[..., None] if squeeze else X
    Bpinv = np.linalg.pinv(Bw, rcond=1e-10) if Bpinv is None else Bpinv
    e = Bpinv @ Xk  # (p, m, k)
    out = Xk - Bw @ e
    return (out[..., 0], e[..., 0]) if squeeze else (out, e)


def _absorbed_modes(Jp) -> np.ndarray:
    """``(g, nb)``: the unit directions of the base parameters that per-pose values absorb, from
    the base Jacobian ``Jp (rows, nb)`` with each pose's own columns projected out.

    A per-pose offset and two tilts absorb a rigid motion of the whole head exactly (6
    directions), and more: any change of the geometry whose reading changes are, pose by pose,
    an affine function of the spot positions (a scaling of the zero points, for one). On the
    bundled 100-pose data set (``metrology/data/measured``) 8 directions are exactly absorbed and
    4 more only to 1e-4 of the largest singular value; with the 6 rigid-head directions alone
    held, the fit wandered 21 mm along the others. All of them are held (gauge rows).
    """
    if Jp.shape[1] == 0:
        return np.zeros((0, 0))
    _, sv, vt = np.linalg.svd(Jp, full_matrices=False)
    return vt[sv < ABSORBED_RTOL * sv[0]]


#: held readings (:func:`_held_readings`) kept, least recently used dropped first
HELD_READINGS_KEPT = 512
_HELD = Kept(HELD_READINGS_KEPT)


def _held_readings(nominal, theta0, normal, offset):
    """``(p, n)`` mm, read-only: every sensor's readings at the chart errors ``theta0 (n, 5)`` on
    the planes ``normal (p, 3)``, ``offset (p,)`` (TCS). Every candidate posed on one fold starts
    from the same ``theta0``: kept by the content of the inputs (a hit is what the call computes)."""
    def compute():
        d = readings(*geometry(nominal, theta0), normal, offset)[0]
        d.flags.writeable = False
        return d

    return _HELD.get(content_key(nominal.zero, nominal.direction, theta0, normal, offset), compute)


def clear_held() -> None:
    """Forget the kept held readings (:func:`_held_readings`; a new data set's diagnosis)."""
    _HELD.clear()


class LeastSquares:
    """The least-squares problem of the base model plus ``components`` on ``obs``.

    Parameters
    ----------
    nominal : SensorLayout, the chart's centre
    obs : Observations
    sigma : (n,) float, mm, reading noise used as weights (whitened residuals ``r / sigma``)
    components : sequence of Component (values are the starting point)
    sensors : sequence of int or None, the sensors whose base parameters are free and whose
        readings are fitted (default: every sensor if a component is of the set-up, else the
        components' sensors, else all)
    theta0 : (n, 5) float or None, start (and the fixed values of the other sensors)
    cov : Covariates or None, same poses as ``obs`` (needed with components)

    Attributes
    ----------
    S : (s,) int, the free sensors; ok : (p, s) bool, their readings; nb : int, base
    parameters (0 when a component holds the base at ``theta0``); x0 : (nb + k,) float, start;
    free : components fitted by value; per_pose : the profiled component or None;
    e_columns : (p, s, m) float or None, its whitened per-pose columns
    """

    def __init__(self, nominal, obs, sigma, components=(), sensors=None, theta0=None, cov=None):
        self.nominal, self.obs, self.cov = nominal, obs, cov
        n = nominal.n
        self.comps = comps = tuple(components)
        ExtendedModel(nominal, comps)  # name clashes raise
        if sensors is None:
            sensors = range(n) if not comps or any(not c.sensors for c in comps) else {i for c in comps for i in c.sensors}
        self.S = S = np.array(sorted(sensors), int)
        self.theta0 = np.zeros((n, 5)) if theta0 is None else np.array(theta0, float)
        self.ok = np.isfinite(obs.d)[:, S]
        self.dS = np.where(self.ok, obs.d[:, S], 0.0)
        self.sig = np.asarray(sigma, float)[S]
        prof = [c for c in comps if c.per_pose]
        if len(prof) > 1:
            raise ValueError("at most one per-pose component per fit")
        self.per_pose = prof[0] if prof else None
        self.free = [c for c in comps if not c.per_pose]
        self.k_comp = [c.n_params for c in self.free]
        # a per-pose rigid error (offset and two tilts a pose) leaves one reading in four to the
        # geometry; scored, it holds the base parameters at ``theta0`` (the base calibration)
        self.hold = any(c.holds_base for c in comps)
        self.nb = 0 if self.hold else 5 * len(S)
        self.x0 = np.concatenate([np.zeros(0) if self.hold else self.theta0[S].ravel()] + [c.values for c in self.free])
        self._last = (None, None)  # the last prediction's x (bytes) and value: residual and jacobian ask at one x
        self._last_r = (None, None)  # the same for the residual matrix (the solver, the result and its dof ask)
        self._charts()
        self._per_pose_columns()

    def _charts(self):
        """What does not change with ``x``: the readings of the sensors held at ``theta0``, the
        chart bases, and the basis of every term that does not depend on ``d0``."""
        nominal, S = self.nominal, self.S
        self.d_full0 = _held_readings(nominal, self.theta0, self.obs.normal, self.obs.offset)
        self.u0S = nominal.direction[S]
        self.basis0 = direction_basis(self.u0S)
        self.u0n = self.u0S / vector_norm(self.u0S, axis=1, keepdims=True)  # the Jacobian's chart (as jacobian_tangent)
        self.basis_n = direction_basis(self.u0n)
        self.fixed = [None if c.uses_d0 else c.basis(self.d_full0, self.cov) for c in self.free]

    def _per_pose_columns(self):
        """The profiled component's whitened columns and, with several values a pose, the gauge
        rows holding the geometry they absorb (:func:`_absorbed_modes`)."""
        self.e_columns, self._Bpinv, self.G = None, None, None
        self.n_gauge = 0
        c = self.per_pose
        if c is None:
            return
        Bw = c.pose_columns(self.cov)[:, self.S, :] / self.sig[None, :, None]
        self.e_columns = Bw = np.where(self.ok[..., None], Bw, 0.0)  # (p, s, m)
        self._Bpinv = np.linalg.pinv(Bw, rcond=1e-10) if Bw.shape[2] > 1 else None
        self.n_gauge = c.gauge_dof
        if c.per_pose_columns > 1 and not self.hold:
            self.G = _absorbed_modes(self.jacobian(self.x0)[:, :self.nb]) * RIGID_GAUGE_WEIGHT
            self.n_gauge = len(self.G)

    # -- the model ---------------------------------------------------------------------------
    def unpack(self, x):
        """``(theta (n, 5), [values of each free component])`` of the parameters ``x``."""
        th = self.theta0.copy()
        if not self.hold:
            th[self.S] = x[:self.nb].reshape(-1, 5)
        vals, j = [], self.nb
        for k in self.k_comp:
            vals.append(x[j:j + k])
            j += k
        return th, vals

    def predict(self, x):
        """``(theta, values, d0 (p, n) mm, f (p, n) mm, bases)``: the base readings and the
        components' terms at ``x`` (the held sensors at ``theta0``)."""
        key = x.tobytes()
        if self._last[0] == key:
            return self._last[1]
        th, vals = self.unpack(x)
        S = self.S
        w = self.u0S + np.einsum("nk,nkj->nj", th[S, 3:], self.basis0)
        d0s, _ = readings(self.nominal.zero[S] + th[S, :3], w, self.obs.normal, self.obs.offset)
        d0 = self.d_full0.copy()
        d0[:, S] = d0s
        f = np.zeros(d0.shape)  # (np.zeros_like's float64 C-order array, at a tenth of its cost)
        bases = [c.basis(d0, self.cov) if B is None else B for c, B in zip(self.free, self.fixed)]
        for B, v in zip(bases, vals):
            f += B @ np.asarray(v, float)  # Component.evaluate: every catalogued term is linear in its values
        self._last = (key, (th, vals, d0, f, bases))
        return self._last[1]

    def _project(self, X):
        if self.e_columns.shape[2] == 1:  # an offset a pose: the gauge of the zero points, exactly
            return _project_per_pose(self.e_columns[..., 0], X, self.obs.normal)
        return _project_per_pose_multi(self.e_columns, X, self._Bpinv)

    def residual_matrix(self, x):
        """``(R (p, s), e)``: whitened residuals of the free sensors (zero where no reading) with
        the per-pose values ``e`` profiled out (None without)."""
        key = x.tobytes()
        if self._last_r[0] == key:
            return self._last_r[1]
        _, _, d0, f, _ = self.predict(x)
        R = np.where(self.ok, (self.dS - d0[:, self.S] - f[:, self.S]) / self.sig, 0.0)
        e = None
        if self.e_columns is not None:
            R, e = self._project(R)
        self._last_r = (key, (R, e))
        return R, e

    def residual(self, x):
        """The whitened residual vector: the readings, then the components' and the gauge's rows."""
        R, _ = self.residual_matrix(x)
        vals = self.predict(x)[1]
        extra = [c.constraint(v)[0] for c, v in zip(self.free, vals)]
        if self.G is not None:
            extra.append(self.G @ (x[:self.nb] - self.x0[:self.nb]))
        r = R[self.ok]
        if not np.isfinite(r).all():  # (np.nan_to_num costs ~30 us a call, its check ~5 us)
            r = np.nan_to_num(r, copy=False, nan=INVALID_RESIDUAL)
        return np.concatenate([r] + extra)

    def jacobian(self, x):
        """``d residual / d x`` (analytic): rows as :meth:`residual`'s."""
        th, vals, d0, f, bases = self.predict(x)
        S, ok, nb = self.S, self.ok, self.nb
        # jacobian_tangent with its chart computed once
        J6 = jacobian_raw(self.nominal.zero[S] + th[S, :3], self.u0n + np.einsum("nk,nkj->nj", th[S, 3:], self.basis_n),
                          self.obs.normal, self.obs.offset)
        J0 = np.concatenate([J6[..., :3], np.einsum("pnj,nkj->pnk", J6[..., 3:], self.basis_n)], axis=-1)  # (p, s, 5)
        if any(c.uses_d0 for c in self.free):  # (else the factor is one)
            g = np.ones(d0.shape)
            for c, v in zip(self.free, vals):
                if c.uses_d0:
                    g += c.d_dd0(v, d0, self.cov)
            J0 = J0 * g[:, S, None]
        p, s = ok.shape
        Jb = np.zeros((p, s, nb))
        for a in range(s if nb else 0):
            Jb[:, a, 5 * a:5 * a + 5] = J0[:, a]
        blocks = [Jb] + [B[:, S] for B in bases]  # Component.jacobian: the basis
        Jr = -np.concatenate(blocks, axis=-1) / self.sig[None, :, None]
        Jr = np.where(ok[..., None], Jr, 0.0)
        if self.e_columns is not None:
            n0 = np.sqrt(np.einsum("psk,psk->k", Jr, Jr))
            Jr, _ = self._project(Jr)
            # a column the per-pose values absorb (a datum tilt under an offset and two tilts a
            # pose) is left as rounding noise: zero it, or the column scaling blows it up
            gone = np.sqrt(np.einsum("psk,psk->k", Jr, Jr)) <= ABSORBED_COLUMN_RTOL * n0
            Jr[..., gone] = 0.0
        return np.concatenate([Jr[ok]] + self._constraint_rows(vals, Jr.shape[-1]), axis=0)

    def _constraint_rows(self, vals, width):
        rows, off = [], self.nb
        for c, v, k in zip(self.free, vals, self.k_comp):
            Jc = c.constraint(v)[1]
            if len(Jc):
                Rr = np.zeros((len(Jc), width))
                Rr[:, off:off + k] = Jc
                rows.append(Rr)
            off += k
        if self.G is not None:
            Rr = np.zeros((len(self.G), width))
            Rr[:, :self.nb] = self.G
            rows.append(Rr)
        return rows

    # -- the solution ------------------------------------------------------------------------
    def solve(self, solver="lsq", loss="linear", **least_squares_kw):
        """The parameters ``x`` of the minimum from :attr:`x0`.

        solver : ``"lsq"`` (``scipy.optimize.least_squares``, trf; ``least_squares_kw`` passed on,
        default ``x_scale="jac"``; its result kept as :attr:`result`) or ``"gn"``
        (:func:`gauss_newton`: the same minimum, several times faster on small problems).
        loss : ``"linear"`` or ``"soft_l1"`` (robust; with ``"gn"`` at scale 1, whitened units).
        """
        from scipy.optimize import least_squares

        if loss not in ("linear", "soft_l1"):
            raise ValueError(f"loss must be 'linear' or 'soft_l1', got {loss!r}")
        self.result = None
        if self.x0.size == 0:
            return self.x0
        if solver == "lsq":
            kw = {"x_scale": "jac"} | ({} if loss == "linear" else {"loss": loss, "f_scale": 1.0}) | least_squares_kw
            self.result = least_squares(self.residual, self.x0, jac=self.jacobian, method="trf", **kw)
            return self.result.x
        if solver == "gn":
            # with the base held (nb = 0) every term is linear in the values (the readings of the
            # held geometry fixed, the per-pose projection and the constraint rows linear): the
            # residual is affine in ``x`` and one step is the minimum (a second finds rounding)
            affine = self.nb == 0 and loss == "linear"
            return gauss_newton(self.residual, self.jacobian, self.x0, loss, max_iter=1 if affine else 30)
        raise ValueError(f"solver must be 'lsq' or 'gn', got {solver!r}")

    def dof(self, x) -> int:
        """Readings of the free sensors less the free parameters (the profiled per-pose values
        less their gauge, the components' constraint rows given back)."""
        vals = self.predict(x)[1]
        R, e = self.residual_matrix(x)
        k = self.nb + sum(self.k_comp) - sum(len(c.constraint(v)[0]) for c, v in zip(self.free, vals))
        if e is not None:
            k += e.size - (0 if self.hold else self.n_gauge)
        return int(R[self.ok].size - k)

    def covariance(self, x, s2, J=None):
        """``s2 (J^T J)^-1`` at ``x`` (``J`` the whitened Jacobian, default :meth:`jacobian`) from
        the column-scaled normal equations; an absorbed (zero) column has no information."""
        J = self.jacobian(x) if J is None else J
        scale = np.linalg.norm(J, axis=0)
        scale = np.where(scale > 0, scale, 1.0)
        Js = J / scale
        return np.linalg.pinv(Js.T @ Js, rcond=1e-12, hermitian=True) / np.outer(scale, scale) * s2

    def per_pose_variance(self):
        """``(p, m)``: the profiled values' variance per unit ``s2`` (reading noise only)."""
        Bw = self.e_columns
        BtB = np.einsum("psm,psq->pmq", Bw, Bw)
        return np.diagonal(np.linalg.pinv(BtB, rcond=1e-10, hermitian=True), axis1=1, axis2=2)


def gauss_newton(fun, jac, x0, loss, max_iter=GN_MAX_ITER, tol=GN_TOL):
    """Gauss-Newton with step halving (IRLS weights for ``soft_l1``) on column-scaled normal
    equations; stops when the cost changes by less than ``tol`` relative."""

    def cost_of(r):
        z = r * r
        return float(np.sum(z) if loss == "linear" else np.sum(2 * (np.sqrt(1 + z) - 1)))

    x = np.array(x0, float)
    r = fun(x)
    cost = cost_of(r)
    for _ in range(max_iter):
        J = jac(x)
        if loss == "linear":  # unit weights (what multiplying by ones gave)
            Jw, rw = J, r
        else:
            w = 1.0 / np.sqrt(np.sqrt(1 + r * r))
            Jw, rw = J * w[:, None], r * w
        scale = vector_norm(Jw, axis=0)
        scale = np.where(scale > 0, scale, 1.0)
        Js = Jw / scale
        step = -np.linalg.lstsq(Js, rw, rcond=1e-12)[0] / scale
        t = 1.0
        while True:
            xn = x + t * step
            rn = fun(xn)
            cn = cost_of(rn)
            # a rise within the tolerance is rounding at the minimum: halving would not find a descent
            if cn <= cost or t < GN_MIN_STEP or cn - cost <= tol * max(cost, 1e-300):
                break
            t *= 0.5
        done = abs(cost - cn) <= tol * max(cost, 1e-300)
        if cn <= cost:
            x, r, cost = xn, rn, cn
        if done or cn > cost:
            break
    return x
