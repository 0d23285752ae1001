"""Normals and shape operators of a height field ``z = f(x, y)`` by central differences.

The shape operator (panel frame, 1/mm) of ``F = z - f`` is ``S = P H P / |grad F|`` with
``H = -hess f`` (embedded in 3 x 3) and ``P = I - n n^T``, ``n = (-f_x, -f_y, 1) / |.|`` the outward
normal (the head's side): positive where the surface bends away from the head (a sphere seen
from outside ``+1/R``, a barrel seen from inside ``-1/R``).

Steps :data:`GRAD_STEP_MM` for the gradient, :data:`HESS_STEP_MM` for the Hessian: truncation
``h^2 f3 / 6`` and ``h^2 f4 / 12`` (``f3``, ``f4`` the third and fourth derivatives) stays under
1e-6 of the slope and curvature of panels with radii above 100 mm.
"""

from __future__ import annotations

import numpy as np

__all__ = ["shape_from_height", "GRAD_STEP_MM", "HESS_STEP_MM"]

#: central-difference steps of the gradient and the Hessian (mm)
GRAD_STEP_MM = 1e-3
HESS_STEP_MM = 0.5


def _grad(f, x, y, h=GRAD_STEP_MM):
    return (f(x + h, y) - f(x - h, y)) / (2 * h), (f(x, y + h) - f(x, y - h)) / (2 * h)


def shape_from_height(f, x, y):
    """Outward unit normals ``(m, 3)`` and shape operators ``(m, 3, 3)`` (1/mm, panel frame) of the
    surface ``z = f(x, y)`` at ``x, y (m,)`` mm (module docstring)."""
    x, y = np.asarray(x, float).ravel(), np.asarray(y, float).ravel()
    fx, fy = _grad(f, x, y)
    h = HESS_STEP_MM
    f0 = f(x, y)
    fxx = (f(x + h, y) - 2 * f0 + f(x - h, y)) / h ** 2
    fyy = (f(x, y + h) - 2 * f0 + f(x, y - h)) / h ** 2
    fxy = (f(x + h, y + h) - f(x + h, y - h) - f(x - h, y + h) + f(x - h, y - h)) / (4 * h * h)
    g = np.stack([-fx, -fy, np.ones_like(fx)], axis=-1)
    w = np.linalg.norm(g, axis=-1)
    n = g / w[:, None]
    H = np.zeros((len(x), 3, 3))
    H[:, 0, 0], H[:, 1, 1], H[:, 0, 1], H[:, 1, 0] = -fxx, -fyy, -fxy, -fxy
    P = np.eye(3) - n[:, :, None] * n[:, None, :]
    S = P @ H @ P / w[:, None, None]
    return n, S
