"""The k folds of one single-sensor fit solved as one problem: a batched Gauss-Newton.

A k-fold refits the same model on k training sets. Where the model frees one sensor's chart
errors and components of that sensor only (no per-pose values, no constraint rows), the folds
are k independent problems of the same parameter layout: :class:`FoldBatch` stacks them (fold
``f`` is row ``f`` of every array), computes their readings, residuals and Jacobians with one
numpy call each, and :meth:`FoldBatch.solve` runs :func:`~metrology.calibration.engine.gauss_newton`'s
iteration on all of them at once, each fold with its own step halving and its own convergence.
The minimum of each fold is the one its own fit finds (to the solver's tolerance).
"""

from __future__ import annotations

import numpy as np

from metrology.calibration.engine import GN_MAX_ITER, GN_MIN_STEP, GN_TOL, INVALID_RESIDUAL, LeastSquares
from metrology.core.model import jacobian_raw, readings

__all__ = ["FoldBatch"]


class FoldBatch:
    """The problems ``problems`` (one :class:`LeastSquares` per fold) as one stacked problem.

    Attributes
    ----------
    i : int, the free sensor; pm : int, the most training poses of a fold; ok : (k, pm) bool,
    the readings fitted (False on a shorter fold's padding); x0 : (k, nx) float, each fold's start
    """

    def __init__(self, problems: list[LeastSquares]):
        self.problems = problems
        p0 = problems[0]
        self.i = int(p0.S[0])
        k = len(problems)
        self.pm = pm = max(p.obs.n_poses for p in problems)
        pad = [pm - p.obs.n_poses for p in problems]

        def stack(rows):  # (k, pm, ...) with each fold's rows padded by its first
            return np.stack([np.concatenate([r, np.repeat(r[:1], q, axis=0)]) for r, q in zip(rows, pad)])

        self.normal = stack([p.obs.normal for p in problems]).reshape(k * pm, 3)
        self.offset = stack([p.obs.offset for p in problems]).reshape(k * pm)
        real = np.arange(pm)[None, :] < np.array([pm - q for q in pad])[:, None]  # not padding
        self.ok = stack([p.ok[:, 0] for p in problems]) & real
        self.dS = np.where(self.ok, stack([p.dS[:, 0] for p in problems]), 0.0)
        self.sig = float(p0.sig[0])
        self.fixed = [None if B is None else stack([p.fixed[j][:, self.i] for p in problems])
                      for j, B in enumerate(p0.fixed)]
        self.x0 = np.stack([p.x0 for p in problems])
        self._last = (None, None)  # residual and jacobian ask at one X: the prediction made once

    @staticmethod
    def applies(problems) -> bool:
        """Whether ``problems`` are folds of one single-sensor fit (one free sensor, its five
        chart errors free, no per-pose values, no gauge or constraint rows)."""
        p0 = problems[0]

        def simple(p):
            return (len(p.S) == 1 and p.S[0] == p0.S[0] and p.nb == 5 and p.e_columns is None and p.G is None
                    and p.x0.shape == p0.x0.shape and [type(c) for c in p.free] == [type(c) for c in p0.free]
                    and all(len(c.constraint(c.values)[0]) == 0 for c in p.free))

        return len(problems) > 1 and all(simple(p) for p in problems)

    def _diag(self, A):
        """Fold ``f``'s own rows of ``A (k pm, k, ...)`` (every fold's geometry on every fold's
        poses): ``(k, pm, ...)``."""
        k = len(self.problems)
        A = A.reshape(k, self.pm, k, *A.shape[2:])
        return A[np.arange(k), :, np.arange(k)]

    def _predict(self, X):
        """``(d0 (k, pm) mm, [basis (k, pm, kj)], d0 in each fold's (p, n) frame)`` at ``X (k, nx)``."""
        key = X.tobytes()
        if self._last[0] == key:
            return self._last[1]
        p0, i = self.problems[0], self.i
        zero = p0.nominal.zero[i] + X[:, :3]
        w = p0.u0S[0] + X[:, 3:5] @ p0.basis0[0]
        d0 = self._diag(readings(zero, w, self.normal, self.offset)[0])
        full = []
        if any(B is None for B in self.fixed):
            for f, p in enumerate(self.problems):
                d = p.d_full0.copy()
                d[:, i] = d0[f, :p.obs.n_poses]
                full.append(d)
        bases = []
        for j, B in enumerate(self.fixed):
            if B is None:
                B = self._stack_rows([p.free[j].basis(d, p.cov)[:, i] for d, p in zip(full, self.problems)])
            bases.append(B)
        self._last = (key, (d0, bases, full))
        return self._last[1]

    def _stack_rows(self, rows):
        out = np.zeros((len(rows), self.pm) + rows[0].shape[1:])
        for f, r in enumerate(rows):
            out[f, :len(r)] = r
        return out

    def _values(self, X):
        out, j = [], 5
        for kj in self.problems[0].k_comp:
            out.append(X[:, j:j + kj])
            j += kj
        return out

    def residual(self, X):
        """``(k, pm)``: each fold's whitened residuals (zero where no reading)."""
        d0, bases, _ = self._predict(X)
        f = np.zeros_like(d0)
        for B, v in zip(bases, self._values(X)):
            f += np.einsum("fpc,fc->fp", B, v)
        R = np.where(self.ok, (self.dS - d0 - f) / self.sig, 0.0)
        return np.nan_to_num(R, nan=INVALID_RESIDUAL)

    def jacobian(self, X):
        """``(k, pm, nx)``: each fold's ``d residual / d x`` (as :meth:`LeastSquares.jacobian`)."""
        p0, i = self.problems[0], self.i
        d0, bases, full = self._predict(X)
        u = p0.u0n[0] + X[:, 3:5] @ p0.basis_n[0]
        J6 = self._diag(jacobian_raw(p0.nominal.zero[i] + X[:, :3], u, self.normal, self.offset))  # (k, pm, 6)
        J0 = np.concatenate([J6[..., :3], J6[..., 3:] @ p0.basis_n[0].T], axis=-1)
        g = np.ones_like(d0)
        for j, (c, v) in enumerate(zip(p0.free, self._values(X))):
            if c.uses_d0:  # each fold's own component (its state of the fold's poses, if any)
                g += self._stack_rows([p.free[j].d_dd0(vf, d, p.cov)[:, i] for vf, d, p in zip(v, full, self.problems)])
        Jr = -np.concatenate([J0 * g[..., None]] + bases, axis=-1) / self.sig
        return np.where(self.ok[..., None], Jr, 0.0)

    def solve(self, max_iter=GN_MAX_ITER, tol=GN_TOL):
        """``(k, nx)``: each fold's minimum, by :func:`~metrology.calibration.engine.gauss_newton`'s
        iteration (linear loss) on every fold still moving."""
        X = self.x0.copy()
        R = self.residual(X)
        cost = np.sum(R * R, axis=1)
        live = np.ones(len(X), bool)
        for _ in range(max_iter):
            J = self.jacobian(X)
            scale = np.sqrt(np.sum(J * J, axis=1))  # (k, nx)
            scale = np.where(scale > 0, scale, 1.0)
            step = -(np.linalg.pinv(J / scale[:, None, :], rcond=1e-12) @ R[..., None])[..., 0] / scale
            t = np.ones(len(X))
            Xn, Rn, cn = X.copy(), R.copy(), cost.copy()
            todo = live.copy()
            while todo.any():
                Xt = X + t[:, None] * step
                Rt = self.residual(Xt)
                ct = np.sum(Rt * Rt, axis=1)
                Xn[todo], Rn[todo], cn[todo] = Xt[todo], Rt[todo], ct[todo]
                settled = (ct <= cost) | (t < GN_MIN_STEP) | (ct - cost <= tol * np.maximum(cost, 1e-300))
                todo &= ~settled
                t = np.where(todo, 0.5 * t, t)
            done = np.abs(cost - cn) <= tol * np.maximum(cost, 1e-300)
            take = live & (cn <= cost)
            X[take], R[take], cost[take] = Xn[take], Rn[take], cn[take]
            live &= ~(done | (cn > cost))
            if not live.any():
                break
        return X
