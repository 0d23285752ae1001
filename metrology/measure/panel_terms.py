"""What the panel adds to a hole's budget with its local surface known: the uncertainty of its shape
operator and the head's spin about the tool axis (within ``+-spin`` in the cell's convention, shaped as
:data:`metrology.measure.spin.SPIN_BOUND_MODEL`, or not known: a bound over every spin), as
:class:`metrology.measure.budget.Source` entries, and what they
do to the redundant reading's misfit (:func:`metrology.measure.surface.surface_hole_normals`).

The heights move with an error ``delta K`` of the shape operator by ``sigma rho 1/2 (Tq)^T delta K (Tq)``
(:func:`shape_basis`: per component of ``delta K`` in an orthonormal basis of the tangent plane's
symmetric tensors); the spin turns ``K``: ``delta K = delta psi (W K - K W)``, ``W`` the cross matrix of
``m``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.sym2 import eig2
from metrology.measure.budget import PANEL_SHAPE, SPIN, SPIN_READ, Kind, Source, angle_gradient
from metrology.measure.magnitude import SPREAD_VARIANCE

__all__ = ["PanelTerms", "panel_sources", "free_spin", "shape_basis"]


@dataclass(frozen=True)
class PanelTerms:
    """What the panel adds to the budget, per hole.

    Attributes
    ----------
    u_shape : (h,) float, 1/mm, standard uncertainty of each component of the shape operator
        (mesh fit, position error along the surface, form tolerance; combined)
    spin : float or (h,) float, rad, the head's spin about the tool axis relative to the panel is
        within ``+-spin``; 0 where the robot's commanded pose gives it
    spin_kind : Kind, what is known of the spin within ``+-spin`` (:attr:`~metrology.measure.budget.Kind.UNIFORM`,
        ``ARCSINE`` or ``EDGE``: any distribution; :data:`metrology.measure.spin.SPIN_BOUND_MODEL` on the convention)
    free : bool, the head's spin is not known at all (no pose, and no convention that holds): the
        shape's isotropic part (its mean curvature, the same at every spin) is fitted and its deviatoric
        part, of known size ``(k1 - k2) / 2`` and unknown direction, enters as a bound over every spin
        (:data:`metrology.measure.budget.SPIN`, a :attr:`~metrology.measure.budget.Kind.BOUND`); ``spin``
        and the CAD beyond second order are not used
    """

    u_shape: np.ndarray
    spin: float | np.ndarray = 0.0
    free: bool = False
    spin_kind: Kind = Kind.UNIFORM


def _tangent_basis(mx, my, mz):
    """Two unit vectors spanning the plane square to the unit ``m``, by components: ``(t1, t2)``, each a
    tuple of three (h,) arrays (``mx, my, mz`` (h,) arrays)."""
    use_x = np.abs(mx) < 0.9  # the reference e_x, else e_y
    rm = np.where(use_x, mx, my)  # ref . m
    ax, ay, az = use_x - rm * mx, ~use_x - rm * my, -rm * mz
    f = 1.0 / np.sqrt(ax * ax + ay * ay + az * az)
    ax, ay, az = ax * f, ay * f, az * f
    return (ax, ay, az), (my * az - mz * ay, mz * ax - mx * az, mx * ay - my * ax)  # m x t1


def shape_basis(fit, g2, axis):
    """The heights' change ``(n, N)`` (sensor-major) per unit change of each of the three components
    of the shape operator in an orthonormal basis of the tangent plane's symmetric tensors (``t1 t1``,
    ``t2 t2``, ``(t1 t2 + t2 t1) / sqrt 2``), ``sigma rho 1/2 (Tq)^T delta K (Tq)``: a list of 3."""
    ok = fit.ok
    m = fit.normal
    t1, t2 = _tangent_basis(*(np.where(ok, m[:, i], e) for i, e in enumerate((0.0, 0.0, 1.0))))
    sc = -axis[2] * np.sqrt(1.0 + g2)  # sigma rho
    qx, qy, qz = fit.q.transpose(2, 1, 0)  # (n, N) each, mm
    a1 = qx * t1[0] + qy * t1[1] + qz * t1[2]  # (n, N), mm
    a2 = qx * t2[0] + qy * t2[1] + qz * t2[2]
    h = 0.5 * sc
    return [h * a1 * a1, h * a2 * a2, (sc / np.sqrt(2.0)) * a1 * a2]


def free_spin(fit, g2, axis, dev, A0, A1, basis=None):
    """The spin's :class:`Source` where it is not known (``PanelTerms.free``): the shape's deviatoric part
    ``dev (N,)`` 1/mm, ``(k1 - k2) / 2``, at an unknown angle: ``delta K = dev (cos 2t B1 + sin 2t B2)``
    (``B1 = t1 t1 - t2 t2``, ``B2 = t1 t2 + t2 t1``) tilts by ``dev (cos 2t v1 + sin 2t v2)``: the angle's
    worst case that ellipse's major semi-axis (the length of the tilt's change), a bound; the 2-D spread ``dev^2 / 2 (v1 v1^T + v2 v2^T)`` (t uniform);
    and the most it moves the redundant reading's misfit, ``dev |(q.dh1, q.dh2)|`` (N,) mm (n = 4, else None);
    ``basis`` :func:`shape_basis` of the same fit where the caller has it."""
    b = shape_basis(fit, g2, axis) if basis is None else basis
    dh = (b[0] - b[1], np.sqrt(2.0) * b[2])  # (n, N): the heights' change per unit B1, B2
    v = [((A0 * h).sum(0), (A1 * h).sum(0)) for h in dh]
    M = ((v[0][0] ** 2 + v[1][0] ** 2), (v[0][0] * v[0][1] + v[1][0] * v[1][1]), (v[0][1] ** 2 + v[1][1] ** 2))
    # the angle moves by at most the tilt's change, |dg| <= dev sqrt(l1(M)): the ellipse's major semi-axis (not
    # its projection on the angle's gradient: the change is not small beside the angle)
    half = dev * np.sqrt(np.maximum(eig2(*M)[0], 0.0)) / (1.0 + fit.g[:, 0] ** 2 + fit.g[:, 1] ** 2)
    f = 0.5 * dev * dev
    C = np.stack([M[0] * f, M[1] * f, M[2] * f], axis=1)
    rho = None
    if fit.null is not None:
        qv = fit.null.T
        rho = dev * np.hypot((qv * dh[0]).sum(0), (qv * dh[1]).sum(0))
    return Source(SPIN, C, Kind.BOUND, half), rho


def panel_sources(fit, g2, axis, terms, A0, A1, basis=None):
    """The panel's sources (its shape's uncertainty, normal; the head's spin within ``+-spin``, shaped as
    ``terms.spin_kind``; the spin read, empty here: :func:`metrology.measure.spin.panel_normals` fills it) and the
    variance the spin gives the redundant reading's misfit (N,) mm^2 (0 without a spin; the uniform's: the convention's
    test takes the misfit's reach to the spin's ends apart, ``spin._within_reach``); ``basis`` :func:`shape_basis` of
    the same fit where the caller has it."""
    N = len(g2)
    kind = Kind.UNIFORM if terms is None else terms.spin_kind
    C_shape, C_spin = np.zeros((N, 3)), np.zeros((N, 3))
    a_spin = np.zeros(N)
    rho_var = 0.0
    if terms is not None:
        uK2 = np.broadcast_to(np.asarray(terms.u_shape, float).reshape(-1), (N,)) ** 2
        # delta K in an orthonormal basis of the tangent plane's tensors
        for dh in shape_basis(fit, g2, axis) if basis is None else basis:
            v0, v1 = (A0 * dh).sum(0), (A1 * dh).sum(0)
            C_shape[:, 0] += v0 * v0 * uK2
            C_shape[:, 1] += v0 * v1 * uK2
            C_shape[:, 2] += v1 * v1 * uK2
        spin = np.broadcast_to(np.asarray(terms.spin, float), (N,))
        if np.any(spin > 0) and not terms.free:  # delta K = delta psi (W K - K W), W the cross matrix of m
            m = fit.normal
            sc = (-axis[2] * np.sqrt(1.0 + g2))[:, None]  # sigma rho
            W = np.zeros((N, 3, 3))
            W[:, 0, 1], W[:, 0, 2], W[:, 1, 2] = -m[:, 2], m[:, 1], -m[:, 0]
            W[:, 1, 0], W[:, 2, 0], W[:, 2, 1] = m[:, 2], -m[:, 1], m[:, 0]
            dK = W @ fit.Kt - fit.Kt @ W
            dh = sc * 0.5 * np.einsum("hni,hij,hnj->hn", fit.q, dK, fit.q)
            v = np.einsum("hin,hn->hi", fit.A[:, :2, :], dh)
            f = spin ** 2 / 3.0
            fk = spin ** 2 * SPREAD_VARIANCE[kind.value]  # the 2-D spread of the spin's variance as its kind
            C_spin[:, 0], C_spin[:, 1], C_spin[:, 2] = (v[:, 0] * v[:, 0] * fk, v[:, 0] * v[:, 1] * fk,
                                                        v[:, 1] * v[:, 1] * fk)
            c0, c1 = angle_gradient(fit.g[:, 0], fit.g[:, 1])
            a_spin = np.abs(c0 * v[:, 0] + c1 * v[:, 1]) * spin  # rad, the angle at the spin's end
            if fit.null is not None:  # the spin turns the shape's twist: the redundant reading sees it
                rho_var = (fit.null * dh).sum(1) ** 2 * f
    return (Source(PANEL_SHAPE, C_shape), Source(SPIN, C_spin, kind, a_spin),
            Source(SPIN_READ, np.zeros((N, 3)), Kind.UNIFORM, np.zeros(N)), rho_var)
