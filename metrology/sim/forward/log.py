"""Production hole logs with known truth, from the physics: ``metro simulate-log``.

Per hole (panel frame, mm; see :mod:`.panels`; TCS conventions in :mod:`.log_spec`):

1. A drill point ``P`` uniform over the panel's patch, its true outward normal ``n``.
2. The tool axis, tilted from the normal by the true angle ``theta`` (uniform on ``angle_rad``) at
   a uniform azimuth ``phi``: its outward direction is
   ``m = cos(theta) n + sin(theta) (cos(phi) e1 + sin(phi) e2)`` (``e1`` the panel's ``x`` made
   square to ``n``, ``e2 = n x e1``), and the TCS's ``k`` maps to ``a = -m`` (toward the panel).
3. The head's rotation ``tcs2panel = Q(-e_z -> a) F Rz(psi)``: ``F`` turns ``k`` onto ``-e_z``
   (the identity when ``s = -1``, ``diag(1, -1, -1)`` when ``s = +1``), ``Rz(psi)`` is the spin
   (uniform on ``[-spin, spin]`` per hole, default 0, or :attr:`LogSpec.spin_path` along the log,
   so that the TCS ``x, y`` stay near the panel's
   ``x, y``), and ``Q(v -> w)`` is the smallest rotation taking ``v`` to ``w`` (Rodrigues). The
   TCS origin is ``O = P - D a``: the tool axis meets the panel at ``P`` at the stand-off ``D``
   (:attr:`LogSpec.standoff_distance_mm`).
4. Readings: each true beam (zero ``O + R E_i``, direction ``R u_i``) is cast at the panel in closed
   form, plus offset, noise, gross errors, rounding, range (:mod:`.log_spec`).
5. The cell's adjustment, as a cell does it with the layout *it* has (``cell_layout``): projection
   points ``S_i = E_i + d_i u_i`` (TCS) of the readings it has, the least-squares plane through
   them (its normal is the eigenvector of the scatter matrix's smallest eigenvalue, found by
   inverse iteration from ``k`` written with the adjugate, so a rank-deficient 3-point scatter
   works as well), the normal ``n_c`` turned toward the head, and a rotation ``G = Q(k ->
   -n_c)`` of the head about the drill point: ``tcs2panel' = tcs2panel G``, ``O' = P - D a'``. A
   hole with fewer than 3 readings keeps its attitude (``adjusted`` False).
   The controller is pluggable (:attr:`LogSpec.controller`): ``controller(layout, d, shape) ->
   (normal, ok)`` with ``layout`` the cell's layout, ``d (h, n)`` mm its readings (NaN blank),
   ``shape (h, 3, 3)`` 1/mm TCS the CAD surface's shape operator at the hole (positive where the
   surface bends away from the head), computed from the CAD panel (:attr:`LogSpec.cad`, not the
   truth) at the nominal point and turned into the TCS with the commanded pose,
   ``R_c^T S R_c``; it returns the unit normal ``(h, 3)`` TCS toward the head and ``ok (h,)``.
   A controller with ``wants_temperature`` True is also given ``temp_c (h,)`` deg C, the head's
   temperature (for a layout's temperature coefficient). The default is :class:`MicroPlane` (the plane above). The cell turns the drill onto
   ``-normal``; where ``ok`` is False, or the normal is not finite or does not face the head, it
   keeps its attitude (``adjusted`` False). The controller is the thing under
   test: it may come from anywhere (``metro simulate-log --controller metro`` plugs in the
   measurement's own, from :mod:`metrology.jobs.simulate_log`); the physics here imports none.
6. The readings after (same offset, fresh noise and gross errors), and the truth: the angles
   before and after (``atan2(|a x n|, -a.n)``), the true normal in the TCS before and after.

With a hole table (:attr:`LogSpec.table`, :mod:`.holes`), step 1-3 become: the fleet's hole ``g``
(counted over the cells in order) is drilled at the table's row ``g mod m`` (pass ``g // m``, which
is also the log's ``panel``); the commanded pose puts the tool axis on the table's feed ``f``
through its nominal point ``N``: ``tcs2panel_c = Q(-e_z -> f) F Rz(psi)``, ``O_c = N - D f``. The
robot is off that attitude by ``theta`` (``angle_rad``) at azimuth ``phi`` about ``f``: the axis
is ``a = cos(theta) f + sin(theta) (cos(phi) e1 + sin(phi) e2)``, ``tcs2panel = Q(-e_z -> a) F
Rz(psi)`` and ``O = N - D a`` (it turns about the commanded tool point). The readings see the true
panel (which may lie off its CAD, :mod:`.shapes`); the adjusted head turns about ``N`` again,
``O' = N - D a'``; the drilled point is where the axis meets the true panel. The true angles are
taken at the points the axis meets before and after. The commanded pose ``(tcs2panel_c, O_c)``
is logged (:mod:`.log_write`); without a table the commanded pose is the pose before the
adjustment.

Randomness: hole ``j`` of cell ``c`` is drawn in block ``b = j // BLOCK_HOLES`` from the stream
``SeedSequence(seed, spawn_key=(c, b))``; a block is always drawn whole, so a log is the same
whatever the chunk size, and a shorter log is a prefix of a longer one.
"""

from __future__ import annotations

import math
from typing import Iterator

import numpy as np

from metrology.sim.forward.log_spec import HoleChunk, LogSpec

__all__ = ["simulate_log", "simulate_cell", "plane_normal", "rotation_taking_axis", "cell_sizes", "cell_name",
           "BLOCK_HOLES", "MicroPlane", "rotation_vector"]

#: holes drawn from one random stream (fixed: changing it changes every log)
BLOCK_HOLES = 8192
#: inverse iteration of the cell's plane fit stops when no normal moves more than this (unit vector,
#: sum of |components|); production sets converge in 2-3 steps (lambda_1 / lambda_2 ~ (3 um / 50 mm)^2)
STEP_TOL = 1e-15
MAX_INVERSE_STEPS = 60


def cell_name(index: int) -> str:
    """``"C<index + 1>"``."""
    return f"C{index + 1}"


def cell_sizes(holes: int, cells: int) -> list:
    """Holes per cell: ``holes`` split as evenly as possible, the first cells one more."""
    if cells < 1 or holes < 0:
        raise ValueError(f"need at least 1 cell and 0 holes, got {cells} cells, {holes} holes")
    return [holes // cells + (c < holes % cells) for c in range(cells)]


def rotation_taking_axis(s: float, w):
    """Smallest rotations ``(h, 3, 3)`` taking ``s e_z`` (``s = +-1``) to unit ``w (h, 3)``.

    Rodrigues: ``Q = I + K + K^2 / (1 + c)`` with ``K`` the cross matrix of ``s e_z x w`` and
    ``c = s w_z``; defined for ``w`` not opposite to ``s e_z``.
    """
    wx, wy, wz = w[:, 0], w[:, 1], w[:, 2]
    kx, ky, c = -s * wy, s * wx, s * wz
    f = 1.0 / (1.0 + c)
    Q = np.empty((len(w), 3, 3))
    Q[:, 0, 0] = 1.0 - ky * ky * f
    Q[:, 0, 1] = kx * ky * f
    Q[:, 0, 2] = ky
    Q[:, 1, 0] = kx * ky * f
    Q[:, 1, 1] = 1.0 - kx * kx * f
    Q[:, 1, 2] = -kx
    Q[:, 2, 0] = -ky
    Q[:, 2, 1] = kx
    Q[:, 2, 2] = 1.0 - (kx * kx + ky * ky) * f
    return Q


def plane_normal(points, valid, s: float):
    """The cell's least-squares plane through the projection points it has.

    Parameters
    ----------
    points : (h, n, 3) float, mm, TCS
    valid : (h, n) bool, the readings the cell has
    s : float, the tool axis is ``s e_z``

    Returns
    -------
    normal : (h, 3) float, unit, TCS, turned toward the head (``normal . k < 0``); NaN where not ok
    ok : (h,) bool, at least 3 points, not collinear
    """
    w = valid.astype(float)
    ones = np.ones(w.shape[1])
    cnt = w @ ones
    p = np.where(valid[..., None], points, 0.0)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    inv = 1.0 / np.maximum(cnt, 1.0)
    x = (x - ((x @ ones) * inv)[:, None]) * w  # sums over the sensors as products with ones (BLAS, fast)
    y = (y - ((y @ ones) * inv)[:, None]) * w
    z = (z - ((z @ ones) * inv)[:, None]) * w
    a00, a11, a22 = (x * x) @ ones, (y * y) @ ones, (z * z) @ ones
    a01, a02, a12 = (x * y) @ ones, (x * z) @ ones, (y * z) @ ones
    # adjugate (cofactors) of the symmetric scatter matrix: adj(A) = det(A) A^-1, defined at rank 2
    b00, b11, b22 = a11 * a22 - a12 * a12, a00 * a22 - a02 * a02, a00 * a11 - a01 * a01
    b01, b02, b12 = a02 * a12 - a01 * a22, a01 * a12 - a02 * a11, a01 * a02 - a00 * a12
    vx, vy, vz = 0.0 * b00, 0.0 * b00, np.full_like(b00, s)
    for _ in range(MAX_INVERSE_STEPS):  # inverse iteration from k: each step divides the error by lambda_2 / lambda_1
        wx, wy, wz = b00 * vx + b01 * vy + b02 * vz, b01 * vx + b11 * vy + b12 * vz, b02 * vx + b12 * vy + b22 * vz
        norm = np.sqrt(wx * wx + wy * wy + wz * wz)
        with np.errstate(invalid="ignore", divide="ignore"):
            wx, wy, wz = wx / norm, wy / norm, wz / norm
        step = np.abs(wx - vx) + np.abs(wy - vy) + np.abs(wz - vz)
        vx, vy, vz = wx, wy, wz
        if not np.any(step > STEP_TOL):  # NaN (a degenerate set) does not hold the loop
            break
    scale = np.sqrt(b00 * b00 + b11 * b11 + b22 * b22)  # the adjugate's size, to judge a collinear set
    ok = (cnt >= 3) & np.isfinite(vz) & (norm > 1e-12 * scale * scale)
    flip = np.where(s * vz > 0, -1.0, 1.0)  # adj(A) is positive semi-definite: v.k >= 0; the normal faces the head
    normal = np.stack([vx * flip, vy * flip, vz * flip], axis=-1)
    return np.where(ok[:, None], normal, np.nan), ok


class MicroPlane:
    """The cell's micro-plane controller: the least-squares plane through the spots it has
    (:func:`plane_normal`); it needs no shape."""

    name = "microplane"
    wants_shape = False

    def __call__(self, layout, d, shape=None):
        from metrology.sim.forward.log_spec import tool_axis_sign

        valid = np.isfinite(d)
        S = layout.zero + np.where(valid, d, 0.0)[..., None] * layout.direction
        return plane_normal(S, valid, tool_axis_sign(layout))


def rotation_vector(R):
    """Rotation vectors ``(h, 3)`` rad (axis times angle, angle in [0, pi]) of rotations ``R (h, 3, 3)``.

    Through the unit quaternion by Shepperd's method (the largest of ``1 + tr``, ``1 + 2 R_ii - tr`` is
    the pivot, so rotations near pi, as a head facing down the panel's ``-z`` is, stay exact), then
    ``2 atan2(|v|, w) v / |v|``.
    """
    R = np.asarray(R, float)
    tr = R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2]
    piv = np.argmax(np.stack([tr, R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], axis=1), axis=1)
    q = np.empty((len(R), 4))  # w, x, y, z
    for k in range(4):
        m = piv == k
        if not m.any():
            continue
        r = R[m]
        if k == 0:
            t = np.sqrt(1.0 + tr[m]) * 2
            q[m] = np.stack([t / 4, (r[:, 2, 1] - r[:, 1, 2]) / t, (r[:, 0, 2] - r[:, 2, 0]) / t,
                             (r[:, 1, 0] - r[:, 0, 1]) / t], axis=1)
        else:
            i, j, l = k - 1, k % 3, (k + 1) % 3
            t = np.sqrt(1.0 + 2 * r[:, i, i] - tr[m]) * 2
            qi = np.empty((len(r), 4))
            qi[:, 0] = (r[:, l, j] - r[:, j, l]) / t
            qi[:, 1 + i] = t / 4
            qi[:, 1 + j] = (r[:, j, i] + r[:, i, j]) / t
            qi[:, 1 + l] = (r[:, l, i] + r[:, i, l]) / t
            q[m] = qi
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)  # w >= 0: the angle in [0, pi]
    v = np.sqrt(q[:, 1] ** 2 + q[:, 2] ** 2 + q[:, 3] ** 2)
    angle = 2 * np.arctan2(v, q[:, 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(v > 1e-12, angle / v, 2.0)  # small angles: angle / v -> 2 / w
    return q[:, 1:] * scale[:, None]


def _spin(rng, spec, hole):
    """(h,) rad, the head's spin about the tool axis at the cell's holes ``hole (h,)``: ``spec.spin_path(hole)`` where
    given (a spin constant over the run, or drifting with it), else uniform on ``[-spin, spin]`` per hole."""
    if spec.spin_path is not None:
        return np.asarray(spec.spin_path(hole), float)
    h = len(hole)
    return rng.uniform(-spec.spin_rad, spec.spin_rad, size=h) if spec.spin_rad > 0 else np.zeros(h)


def _head(a, flip, psi):
    """``tcs2panel = Q(-e_z -> a) F Rz(psi)`` for tool axes ``a (h, 3)`` (toward the panel)."""
    R = rotation_taking_axis(-1.0, a) * flip
    if np.any(psi != 0):
        M, cp, sp = R.copy(), np.cos(psi)[:, None], np.sin(psi)[:, None]
        R[:, :, 0] = cp * M[:, :, 0] + sp * M[:, :, 1]
        R[:, :, 1] = -sp * M[:, :, 0] + cp * M[:, :, 1]
    return R


def _tangent_axes(n):
    """``e1`` (the panel's ``x`` made square to unit ``n (h, 3)``) and ``e2 = n x e1``."""
    e1 = np.stack([1.0 - n[:, 0] ** 2, -n[:, 0] * n[:, 1], -n[:, 0] * n[:, 2]], axis=-1)
    e1 /= np.sqrt(e1[:, 0] ** 2 + e1[:, 1] ** 2 + e1[:, 2] ** 2)[:, None]
    return e1, _cross(n, e1)


class _Geometry:
    """What every hole of a spec shares: the layouts' arrays, the stand-off, the axis sign."""

    def __init__(self, spec: LogSpec):
        self.spec = spec
        self.s = spec.axis_sign
        self.D = spec.standoff_distance_mm
        self.E, self.u = spec.true_layout.zero, spec.true_layout.direction
        self.Ec, self.uc = spec.cell_layout.zero, spec.cell_layout.direction
        self.sigma = spec.sigma_mm
        self.lo, self.hi = spec.true_layout.range_mm[:, 0], spec.true_layout.range_mm[:, 1]
        self.flip = np.array([1.0, -self.s, -self.s])  # F = diag(1, -s, -s) (as columns): F (s e_z) = -e_z
        self.hole_s = 3600.0 / spec.holes_per_hour
        self.controller = spec.controller if spec.controller is not None else MicroPlane()
        self.table = spec.table
        if self.table is not None:  # the cell's CAD at each table row: normal and shape (panel frame)
            self.cad_normal = spec.cad.normal_at(self.table.points)
            self.cad_shape = spec.cad.shape_at(self.table.points)

    def adjust(self, R, d, shape_of, temp=None):
        """Step 5: the controller's normal from the readings ``d``; the head turned onto ``-normal``.
        ``shape_of()`` gives the CAD shape operators in the TCS (asked only when the controller wants them);
        ``temp (h,)`` deg C the head's temperature, passed as ``temp_c`` to a controller that wants it
        (``wants_temperature``: a layout with a temperature coefficient)."""
        shape = shape_of() if getattr(self.controller, "wants_shape", True) else None
        if getattr(self.controller, "wants_temperature", False):
            nc, ok = self.controller(self.spec.cell_layout, d, shape, temp_c=temp)
        else:
            nc, ok = self.controller(self.spec.cell_layout, d, shape)
        nc = np.asarray(nc, float)
        # the cell refuses a normal that is not finite or does not face the head (n . k < 0): it keeps its attitude
        ok = np.asarray(ok, bool) & np.all(np.isfinite(nc), axis=1) & (nc[:, 2] * self.s < 0)
        k_new = np.where(ok[:, None], -nc, np.array([0.0, 0.0, self.s]))
        if not isinstance(self.controller, MicroPlane):  # a foreign controller's normal, made unit
            k_new = k_new / np.linalg.norm(k_new, axis=1, keepdims=True)
        R2 = np.matmul(R, rotation_taking_axis(self.s, k_new))
        return R2, ok

    def cast(self, R, O):
        """True distances ``(h, n)`` mm of the true beams of heads at ``tcs2panel`` ``R (h, 3, 3)``, ``O (h, 3)``."""
        h = len(R)
        rows = R.reshape(3 * h, 3)  # one BLAS product for all holes: (3h, 3) @ (3, n)
        zero = (rows @ self.E.T).reshape(h, 3, -1) + O[:, :, None]
        beam = (rows @ self.u.T).reshape(h, 3, -1)
        return self.spec.panel.intersect(zero.transpose(0, 2, 1), beam.transpose(0, 2, 1))

    def distances(self, R, O, offset, temp):
        """``(t_true (h, n) mm, offset (h, n) mm)``: the true distances of heads at ``R``, ``O`` and the
        offsets of the readings, the faults' ``offset`` plus the head's sensor properties at them
        (:mod:`.properties`: characteristic, incidence bias, temperature ``temp (h,)`` deg C)."""
        t = self.cast(R, O)
        props = self.spec.properties
        if props is None:
            return t, offset
        angle = None
        if props.needs_incidence:  # the true incidence of each beam on the panel at its spot
            beam = np.einsum("hij,nj->hni", R, self.u)
            spot = O[:, None, :] + np.einsum("hij,nj->hni", R, self.E) + np.where(np.isfinite(t), t, 0.0)[..., None] * beam
            m = self.spec.panel.normal_at(spot)
            angle = np.arccos(np.clip(np.abs(np.einsum("hni,hni->hn", beam, m)), 0.0, 1.0))
        return t, offset + props.offsets(t, angle, temp)

    def read(self, rng, t_true, offset):
        """Readings ``(h, n)`` mm from true distances: offset, noise, gross errors, rounding, range."""
        spec = self.spec
        d = t_true + offset + rng.standard_normal(t_true.shape, dtype=np.float32) * self.sigma
        gross = np.zeros(t_true.shape, bool)
        if spec.gross_rate > 0:  # drawn only when asked (a clean log draws less)
            gross = rng.random(t_true.shape, dtype=np.float32) < spec.gross_rate
            size = rng.uniform(*spec.gross_mm, size=t_true.shape) * rng.choice([-1.0, 1.0], size=t_true.shape)
            d = np.where(gross, d + size, d)
        if spec.resolution_mm > 0:  # the sensor's output step; then to 10 decimals, so 48.0789 is logged as such
            d = np.round(np.round(d / spec.resolution_mm) * spec.resolution_mm, 10)
        with np.errstate(invalid="ignore"):
            d = np.where((d >= self.lo) & (d <= self.hi), d, np.nan)
        return d, gross & np.isfinite(t_true)

    def block(self, seed: int, cell_index: int, b: int) -> HoleChunk:
        """The ``BLOCK_HOLES`` holes of block ``b`` of cell ``cell_index``."""
        spec, h, s = self.spec, BLOCK_HOLES, self.s
        rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed, spawn_key=(cell_index, b))))
        hole = np.arange(b * h, (b + 1) * h, dtype=np.int64)
        P = spec.panel.sample(rng, h, spec.patch_half_mm)
        theta = rng.uniform(*spec.angle_rad, size=h)
        phi = rng.uniform(0.0, 2 * math.pi, size=h)
        psi = _spin(rng, spec, hole)
        time_s = np.round(spec.start_time_s + (hole + 0.4 * rng.random(h)) * self.hole_s, 3)  # logged to the ms
        t_mean, t_swing, t_sigma = spec.temperature_c
        temp = (t_mean + t_swing * np.sin(2 * math.pi * (time_s % 86400.0) / 86400.0 - 0.75 * math.pi)
                + t_sigma * rng.standard_normal(h))
        # the tool axis: outward m at angle theta from n; a = -m toward the panel
        n = spec.panel.normal_at(P)
        e1, e2 = _tangent_axes(n)
        ct, st = np.cos(theta)[:, None], np.sin(theta)[:, None]
        a = -(ct * n + st * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2))
        R = _head(a, self.flip, psi)  # Q(-e_z -> a) F Rz(psi)
        O = P - self.D * a
        offset = self._offset(cell_index, hole, time_s)
        d, gross = self.read(rng, *self.distances(R, O, offset, temp))
        # the cell's adjustment, with its own layout (the commanded pose is the pose before it)
        R2, ok = self.adjust(R, d, lambda: _to_tcs(R, spec.cad.shape_at(P)), temp)
        a2 = R2[:, :, 2] * s
        O2 = P - self.D * a2
        d2, gross2 = self.read(rng, *self.distances(R2, O2, offset, temp))
        return HoleChunk(
            cell=cell_name(cell_index), sensors=spec.sensors, hole=hole, time_s=time_s, temperature_c=temp,
            panel=hole // spec.holes_per_panel, d=d, d_after=d2, drill_point=P,
            true_angle=_angle(a, n), true_after=_angle(a2, n),
            normal_tcs=np.einsum("hji,hj->hi", R, n), normal_after_tcs=np.einsum("hji,hj->hi", R2, n),
            offset=offset, gross=gross, gross_after=gross2, adjusted=ok, pose_rotvec=rotation_vector(R),
            pose_origin=O, nominal=np.full((h, 3), np.nan), cad_angle=np.full(h, np.nan),
            cad_offset=np.full(h, np.nan))

    def table_block(self, seed: int, cell_index: int, b: int, first: int) -> HoleChunk:
        """Block ``b`` of cell ``cell_index`` drilled at the hole table's points (module docstring);
        ``first`` is the fleet index of the cell's first hole."""
        spec, h, s, tab = self.spec, BLOCK_HOLES, self.s, self.table
        rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed, spawn_key=(cell_index, b))))
        hole = np.arange(b * h, (b + 1) * h, dtype=np.int64)
        g = first + hole
        row, lap = g % tab.m, g // tab.m
        N, f = tab.points[row], tab.feed[row]
        theta = rng.uniform(*spec.angle_rad, size=h)
        phi = rng.uniform(0.0, 2 * math.pi, size=h)
        psi = _spin(rng, spec, hole)
        time_s = np.round(spec.start_time_s + (hole + 0.4 * rng.random(h)) * self.hole_s, 3)
        t_mean, t_swing, t_sigma = spec.temperature_c
        temp = (t_mean + t_swing * np.sin(2 * math.pi * (time_s % 86400.0) / 86400.0 - 0.75 * math.pi)
                + t_sigma * rng.standard_normal(h))
        Rc = _head(f, self.flip, psi)  # the commanded pose
        Oc = N - self.D * f
        e1, e2 = _tangent_axes(f)
        ct, st = np.cos(theta)[:, None], np.sin(theta)[:, None]
        a = ct * f + st * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
        R = _head(a, self.flip, psi)
        O = N - self.D * a
        offset = self._offset(cell_index, hole, time_s)
        d, gross = self.read(rng, *self.distances(R, O, offset, temp))
        R2, ok = self.adjust(R, d, lambda: _to_tcs(Rc, self.cad_shape[row]), temp)
        a2 = R2[:, :, 2] * s
        O2 = N - self.D * a2
        d2, gross2 = self.read(rng, *self.distances(R2, O2, offset, temp))
        panel = spec.panel
        P1 = O + panel.intersect(O, a)[:, None] * a
        P2 = O2 + panel.intersect(O2, a2)[:, None] * a2
        n1, n2 = panel.normal_at(P1), panel.normal_at(P2)
        nc = self.cad_normal[row]
        lead = 20.0  # the true surface along the CAD's normal at the nominal point
        t = panel.intersect(N + lead * nc, -nc)
        point_ids = np.asarray(tab.ids, dtype=object)[row]
        ids = np.where(lap == 0, point_ids, point_ids + "#" + (lap + 1).astype(str).astype(object))
        return HoleChunk(
            cell=cell_name(cell_index), sensors=spec.sensors, hole=hole, time_s=time_s, temperature_c=temp,
            panel=lap.astype(np.int64), d=d, d_after=d2, drill_point=P2,
            true_angle=_angle(a, n1), true_after=_angle(a2, n2),
            normal_tcs=np.einsum("hji,hj->hi", R, n1), normal_after_tcs=np.einsum("hji,hj->hi", R2, n2),
            offset=offset, gross=gross, gross_after=gross2, adjusted=ok, pose_rotvec=rotation_vector(Rc),
            pose_origin=Oc, ids=ids.astype(str), point_ids=point_ids.astype(str), nominal=N, cad_angle=_angle(-nc, n2), cad_offset=lead - t)

    def _offset(self, cell_index, hole, time_s):
        spec = self.spec
        off = np.zeros((len(hole), len(spec.sensors)))
        for i, fault in spec.offsets_for(cell_name(cell_index)):
            if hasattr(fault, "rate_mm"):
                t0 = spec.start_time_s + fault.start_hole * self.hole_s
                off[:, i] += fault.offset(hole, time_s, t0)
            else:
                off[:, i] += fault.offset(hole)
        return off


def _to_tcs(R, S):
    """Shape operators ``S (h, 3, 3)`` panel frame into the TCS of heads at ``tcs2panel`` ``R``: ``R^T S R``."""
    return np.einsum("hji,hjk,hkl->hil", R, S, R)


def _cross(a, b):
    """Row-wise ``a x b`` of ``(h, 3)`` arrays (numpy's cross is slow on many short rows)."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=-1)


def _angle(a, n):
    """Angle (rad) between the outward tool axis ``-a (h, 3)`` and the normal ``n (h, 3)``."""
    c = _cross(a, n)
    sin = np.sqrt(c[:, 0] ** 2 + c[:, 1] ** 2 + c[:, 2] ** 2)
    return np.arctan2(sin, -(a[:, 0] * n[:, 0] + a[:, 1] * n[:, 1] + a[:, 2] * n[:, 2]))


def simulate_cell(spec: LogSpec, seed: int, cell_index: int, holes: int,
                  chunk_holes: int = BLOCK_HOLES, first: int = 0) -> Iterator[HoleChunk]:
    """The holes ``0 .. holes - 1`` of cell ``cell_index`` (0-based; named ``C<index + 1>``), in chunks
    of ``chunk_holes`` (the last one shorter). The holes do not depend on ``chunk_holes``. With a hole
    table, ``first`` is the fleet index of the cell's first hole (its table row is ``first mod m``)."""
    if chunk_holes < 1:
        raise ValueError(f"chunk size must be at least 1 hole, got {chunk_holes}")
    geo = _Geometry(spec)
    cache = {}
    for start in range(0, holes, chunk_holes):
        stop = min(start + chunk_holes, holes)
        parts = []
        for b in range(start // BLOCK_HOLES, (stop - 1) // BLOCK_HOLES + 1):
            if b not in cache:
                cache.clear()
                cache[b] = (geo.block(seed, cell_index, b) if spec.table is None
                            else geo.table_block(seed, cell_index, b, first))
            lo = max(start - b * BLOCK_HOLES, 0)
            hi = min(stop - b * BLOCK_HOLES, BLOCK_HOLES)
            parts.append(cache[b].slice(lo, hi))
        yield parts[0] if len(parts) == 1 else HoleChunk.concat(parts)


def simulate_log(spec: LogSpec, seed: int, holes: int, cells: int = 1,
                 chunk_holes: int = BLOCK_HOLES) -> Iterator[HoleChunk]:
    """A fleet's log: ``holes`` holes split over ``cells`` cells (:func:`cell_sizes`), cell after cell,
    each in time order, in chunks of at most ``chunk_holes`` holes (a chunk never spans two cells).

    Every cell has the same head (``spec``); faults act on the cells they name. Memory is bounded by
    the chunk and the block, whatever ``holes``.
    """
    first = 0
    for c, n in enumerate(cell_sizes(holes, cells)):
        yield from simulate_cell(spec, seed, c, n, chunk_holes, first)
        first += n
