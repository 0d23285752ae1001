"""The head's spin about the tool axis with the panel known: from the robot's commanded pose, from a
convention the redundant reading does not refute, or not known: never assumed silently.

The local surface's shape operator is put into the TCS by the head's rotation. The commanded pose
(the log's ``pose_*`` columns) gives it whole. Without it metro can take the cell's convention (TCS
``x, y`` near the panel's, the spin within ``+-spin``: ``--spin-deg``), but a cell that turns the
head for reach breaks it, and the curvature then tilts the normal the wrong way. So, per hole
without a pose (rule 1b of :mod:`metrology.measure.rules`):

- **a redundant reading** (4 sensors read): the hole is measured in the convention and its misfit to
  the CAD's surface there (``panel_misfit_z``: the redundant reading's misfit over its standard
  deviation from the noise, the calibration, the panel's terms and the spin within ``+-spin``) tested:
  beyond :data:`SPIN_SIGMAS` the convention does not hold at that hole, and the hole is judged with
  the spin not known; where it holds, **the spin is read from the redundant reading** (:func:`_read_spin`):
  the misfit moves with the spin by ``s = d rho / d psi`` (the shape and the CAD beyond second order
  turned with the head), so ``psi = -rho(0) / s`` (secant steps, within ``+-spin``), and the hole is
  judged at that spin, the spin's doubt its estimate's, ``u_psi = sd(rho) / |s|`` (uniform within
  ``+-`` :data:`SPIN_READ_WIDTH` ``u_psi``), where that is under :data:`SPIN_READ_MAX` of ``+-spin``; the
  spin's term in U95 is taken from the fits at its ends (:func:`_spin_ends`); rule 2 keeps the
  misfit at the convention's spin with its doubt, and allows the most the spin moves it (to its ends);
- **a redundant reading, the convention not stated** (no ``--spin-deg``): the reading can refute the convention,
  never confirm it (its misfit takes the same value at an alias spin): where a spin it admits beyond ``+-spin``
  tilts the normal over :data:`SPIN_ALIAS_SHARE` of U95 otherwise, the spin not known, as with 3 readings;
- **no redundancy** (3 readings): the convention where it is stated (``--spin-deg``), else the spin not
  known;
- **on the convention, the spin not read** (3 readings, or a redundant reading blind to the spin): the
  spin's term is its bound taken as any distribution within it (:data:`SPIN_BOUND_MODEL`: U95 holds
  wherever in the bound the spin sits; docs/spin.md);
- **the spin not known** (:class:`metrology.measure.surface.PanelTerms` ``free``): the shape's
  isotropic part (the mean curvature, the same at every spin) is fitted, and its deviatoric part, of
  known size ``(k1 - k2) / 2`` and unknown direction, enters the budget as a bound over every spin (at a tight
  radius the CAD beyond second order likewise: :mod:`metrology.measure.spin_free`);
  the redundant reading's gross-reading allowance takes the most it moves the misfit.

The reason column says which holes were judged with the spin not known, the summary how many rest on
the convention, and of those how many on its bound (:data:`SPIN_BOUND_SHARE`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from metrology.measure.budget import PANEL_SHAPE, SPIN, SPIN_READ, SURFACE_MODEL, Kind, combine
from metrology.measure.magnitude import SPREAD_VARIANCE
from metrology.measure.fit_rows import merge as _merge
from metrology.measure.fit_rows import put as _put
from metrology.measure.fit_rows import rows as _rows
from metrology.measure.fit_rows import with_rows as _with
from metrology.measure.normals import HoleNormals, concat_normals

if TYPE_CHECKING:
    from metrology.measure.surface import PanelFit

__all__ = ["SPIN_SIGMAS", "DEFAULT_SPIN_DEG", "SPIN_BOUND_MODEL", "SPIN_BOUND_NOTE", "SpinJudged", "panel_normals"]

#: a redundant reading's misfit to the CAD's surface beyond this many of its standard deviations, the
#: head's spin in the cell's convention: the convention does not hold at that hole (two-sided p = 6e-5
#: per hole where it holds: a hole judged with the wider, every-spin U95 by mistake, never a wrong verdict)
SPIN_SIGMAS = 4.0
#: deg: the head's spin about the tool axis beyond the cell's convention where ``--spin-deg`` does not state it
#: and a redundant reading does not refute the convention (a cell's usual orientation error; it cannot confirm it: a
#: second spin fits the same misfit, near 90 deg on a cross of spots on the diagonals: docs/spin.md)
DEFAULT_SPIN_DEG = 2.0
#: the spin read from the redundant reading (:func:`_read_spin`) enters U95 as uniform within +- this many of its
#: standard uncertainties: 0.95 x 2 = 1.9, the 95 % of a normal (1.96) where it is the whole budget; its error comes
#: from the noise in the misfit, which is uncorrelated with the tilt's (the misfit is the readings' part the fit's
#: tilt does not use)
SPIN_READ_WIDTH = 2.0
#: the spin is read (and its term taken from the fits at its ends) where its share of U95, the uniform's half-width,
#: is over this fraction of U95: below, it moves U95 by under 1 % (a uniform of a tenth of U95 beside normal terms)
SPIN_READ_SHARE = 0.1
#: the spin read is used where its doubt (+- SPIN_READ_WIDTH u_psi) is under this fraction of +-spin: a misfit that
#: barely moves with the spin (the Table 2 head on R 50: 2-7 um per deg against its 5 um sd) reads it off by 1-2 deg
#: where the sd said 0.4-0.8: its spots lie on the TCS axes, and a cylinder along an arm turned by psi moves their
#: misfit as cos 2 psi, even in the spin (its curvature x spin is 2.8x its slope), so neither one hole nor a run of
#: them pooled reads it (benchmarks/study_spin_pool.py): there the convention with +-spin is kept
#: (benchmarks/results/tight_radii.md)
SPIN_READ_MAX = 0.25
#: a hole judged with its spin on the convention's bound (not read: no redundant reading, or one blind to the spin,
#: as Table 2's cross on a cylinder along an arm) is counted as resting on the bound where the spin's term holds over
#: this share of its U95^2 (of the angle's variance, budget.combine): the summary names how many, with the fix (log the
#: commanded pose). Such holes are **judged** with that U95, never left `not_measured` for it. Measured on the study's
#: 40 no-pose rows (flat included; 14,400 holes judged, benchmarks/results/tight_radii.md): leaving them `not_measured` would judge
#: 76 % (none of Table 2 on R 50 along, none of the 3-sensor ring on R 50), give 10,745 decisive verdicts at a 1 deg
#: tolerance against 14,031, false FAILs 0 against 0, false CONFORMs 2 against 3; U95 holds either way (92.2-97.8 %).
#: Without the pose the error there is the floor of any estimator that knows only the bound (the pose at the
#: spin's centre gives the same), so refusing those holes buys no accuracy, only fewer verdicts. (Measured with the
#: bound taken as uniform; as any distribution within it, SPIN_BOUND_MODEL, its variance is three times the uniform's
#: and more holes count: Table 2 on R 50 along 410 of 720 against 317, the 3-sensor ring 657 against 332.)
SPIN_BOUND_SHARE = 0.5
#: what U95 takes of a spin known only by its bound (the convention's +-spin, not read: a 3-sensor head, or a redundant
#: reading blind to the spin): :attr:`~metrology.measure.budget.Kind.EDGE`, **any distribution within the bound**, its
#: U95 the least that holds 95 % wherever in the bound the spin sits (the worst case: at a bound; ``a + 1.645 sigma`` where
#: the spin's reach ``a`` dominates). The spin is a cell's systematic (its orientation for a run, or drifting along it),
#: not drawn afresh per hole, and nothing in such a log says where in the bound it sits. Measured on Table 2 and the
#: 3-sensor ring on R 50 along and across without the pose (12 logs x 60 holes a row; benchmarks/results/tight_radii.md,
#: "the U95 on the spin's bound"): uniform (GUM 4.3.7) covers 95.0-97.5 % where the spin is spread (per hole, per log),
#: 90.0-92.8 % on a sine drift, 85.1-89.6 % on a spin held at the bound; arcsine (JCGM 101 6.4.6) 94.0-96.7 % on the
#: drift, 91.8-93.6 % held; EDGE 96.4-98.9 % held or drifting and 98.8-99.3 % spread. No shape meets 95 +- 1.5 % in all
#: four; EDGE is the one at or above 95 % in each, the side a conformity verdict (ISO 14253-1) can take (a U95 too small
#: makes false CONFORMs, one too large fewer decisive verdicts). The spin read keeps its uniform doubt (SPIN_READ)
SPIN_BOUND_MODEL = Kind.EDGE
#: the reason column's note on a hole whose U95 rests on the spin's bound (:data:`SPIN_BOUND_SHARE`): what it assumes
SPIN_BOUND_NOTE = ("U95 rests on the bound of the head's spin (not read): it holds for any spin within the bound, "
                   "wherever it sits (log the robot's commanded pose to know it)")
#: without the pose and with the convention **not stated** (``--spin-deg``), a redundant reading that does not refute it
#: cannot confirm it either: it admits a second spin (``rho = A + B cos 2 psi + C sin 2 psi`` has two roots; near
#: 90 deg on Table 6's diagonal cross) and, on a reading blind to the spin, the whole half-turn
#: (:func:`metrology.measure.spin_alias.alias_reach`). Where the tilt at a spin it admits beyond ``+-spin`` lies farther
#: than this share of U95 from the tilt within ``+-spin``, the hole is judged over every spin, as a 3-sensor head with
#: nothing stated is: a tilt off by 0.1 U95 (0.2 sigma) still covers 94.6 % of a normal's, by 0.25 U95 92 %. Measured
#: on 12 perturbed, calibrated Table 6 heads, free spin, no pose (benchmarks/results/spin_convention_calibrated.md,
#: "After the fix"): the holes left on the convention covered 54.6 % before (R 500)
SPIN_ALIAS_SHARE = 0.1
#: rad: the spin's ends bound what it does within them (the shape turned by psi moves as sin 2 psi: monotone to
#: 45 deg, and within 2 % of linear to 10); beyond this spin the first-order terms alone are taken
SPIN_ENDS_MAX = np.radians(10.0)
#: secant steps of the spin read from the misfit (the misfit is linear in the spin to (2 psi)^2 / 2: 2.4e-3 at 2 deg)
SPIN_READ_STEPS = 2
#: rows per call of the fit (as :data:`metrology.measure.measured.CACHE_ROWS`)
CACHE_ROWS = 16384


@dataclass(frozen=True)
class SpinJudged:
    """Holes measured with the panel known, and how their spin was taken.

    Attributes
    ----------
    normals : HoleNormals of the holes, in order (its ``budget`` None where the two ways were merged)
    extra : PanelFit of the holes
    free : (m,) bool, judged with the spin not known (a U95 over every spin)
    convention : (m,) bool, judged with the spin in the cell's convention (no pose: the convention assumed)
    z : (m,) float, the convention's misfit in sigmas where the test refused it (NaN elsewhere)
    bound : (m,) bool, on the convention with the spin not read, its term over :data:`SPIN_BOUND_SHARE` of U95^2
    alias : (m,) float, rad, where the convention was not stated and its alias judged the hole over every spin
        (:data:`SPIN_ALIAS_SHARE`): the spin admitted whose tilt lies farthest from the convention's (NaN elsewhere)
    alias_reach : (m,) float, rad, that tilt's distance from the convention's (NaN elsewhere)
    stated : bool, the convention was stated (``--spin-deg``)
    """

    normals: HoleNormals
    extra: "PanelFit"
    free: np.ndarray
    convention: np.ndarray
    z: np.ndarray
    bound: np.ndarray
    alias: np.ndarray
    alias_reach: np.ndarray
    stated: bool = True

    def free_reason(self, i: int) -> str:
        """The reason column's words for hole ``i`` judged over every spin (``free[i]``): why, and the fix."""
        if np.isfinite(self.z[i]):
            why = (f"the head's spin is not the cell's convention here (the redundant reading misses the CAD's surface "
                   f"by {self.z[i]:.1f} sigmas at the assumed spin)")
        elif np.isfinite(self.alias[i]):
            why = (f"the cell's convention is not stated (--spin-deg) and the redundant reading cannot tell it from a "
                   f"spin of {np.degrees(self.alias[i]):+.0f} deg, where the curvature tilts the normal "
                   f"{np.degrees(self.alias_reach[i]):.2g} deg otherwise (over {SPIN_ALIAS_SHARE:g} of U95)")
        else:
            why = "the head's spin is not known (no pose_* columns, no --spin-deg, no redundant reading)"
        fix = "log the robot's commanded pose to know it" + (", or state the cell's convention with --spin-deg"
                                                             if np.isfinite(self.alias[i]) else "")
        return f"{why}: judged with a U95 that covers every spin ({fix})"


def _spin_share(h, on) -> np.ndarray:
    """(m,) float, the spin's share of the angle's variance, ``u_spin^2 / u^2`` (:func:`metrology.measure.budget.
    combine`; a spin that moves the tilt across the angle's gradient does not count), at the holes ``on`` (m,) bool
    (the convention's: only they can rest on its bound; a log with the pose combines nothing again), 0 elsewhere and
    where there is no budget."""
    share = np.zeros(len(h.angle))
    k = np.flatnonzero(on)
    if h.budget is None or not k.size:
        return share
    un = combine(h.budget if k.size == len(share) else h.budget.rows(k))
    with np.errstate(invalid="ignore", divide="ignore"):
        share[k] = np.nan_to_num((un.of(SPIN) / un.u) ** 2)
    return share


def _fit(sub, dd, shape, u_shape, spin, higher, free=False):
    """:func:`metrology.measure.surface.surface_hole_normals` in slices of :data:`CACHE_ROWS` rows."""
    from metrology.measure.surface import PanelFit, PanelTerms, surface_hole_normals

    def part(s):
        return surface_hole_normals(sub, dd[s], shape[s], PanelTerms(u_shape[s], spin[s], free, SPIN_BOUND_MODEL),
                                    beyond=None if higher is None or free else higher.rows(s))

    parts = [part(slice(i, i + CACHE_ROWS)) for i in range(0, len(dd), CACHE_ROWS)]
    return concat_normals([p[0] for p in parts]), PanelFit.concat([p[1] for p in parts])


def panel_normals(sub, dd, shape, u_shape, spin, higher, convention, stated: bool) -> SpinJudged:
    """Holes measured with their local surface known, the spin known, not refuted or bounded (module docstring).

    Parameters
    ----------
    sub : SensorLayout, the sensors that read these holes; dd : (m, n) float, mm, their readings
    shape : (m, 3, 3) float, 1/mm, TCS; u_shape : (m,) 1/mm; spin : (m,) rad; higher : Beyond or None
    convention : (m,) bool, holes whose shape was put into the TCS by the cell's convention (no pose)
    stated : bool, the convention was stated (``--spin-deg``): without redundancy it is taken
    """
    m = len(dd)
    redundant = sub.n == 4
    free0 = convention & (not redundant) & (not stated)
    nan = np.full(m, np.nan)
    if not free0.any() and not (redundant and convention.any()):  # the usual: the pose, or a stated 3-sensor convention
        h, extra = _fit(sub, dd, shape, u_shape, spin, higher)
        c = np.flatnonzero(convention & (spin > 0))
        if c.size:  # the stated convention: the spin's term from its ends
            hc, ec = _read_spin(sub, dd[c], shape[c], u_shape[c], spin[c], None if higher is None else higher.rows(c),
                                _rows(h, c), extra.rows(c), read=False)
            h, extra = _put(h, c, hc, everything=True), _with(extra, c, ec)
        return SpinJudged(h, extra, np.zeros(m, bool), convention.copy(), nan,
                          convention & (_spin_share(h, convention) > SPIN_BOUND_SHARE), nan, nan, stated)
    a = np.flatnonzero(~free0)
    parts = []
    z, alias, alias_reach = nan.copy(), nan.copy(), nan.copy()
    free = free0.copy()
    held = None
    if a.size:
        h, extra = _fit(sub, dd[a], shape[a], u_shape[a], spin[a], None if higher is None else higher.rows(a))
        test = np.abs(extra.panel_misfit_z)
        off = convention[a] & (test > SPIN_SIGMAS) if redundant else np.zeros(a.size, bool)
        near = off & (spin[a] <= SPIN_ENDS_MAX)
        if near.any():  # the first-order test; the convention holds where a spin within +-spin reaches the misfit
            off[near] = ~_within_reach(sub, dd[a[near]], shape[a[near]], u_shape[a[near]], spin[a[near]],
                                       None if higher is None else higher.rows(a[near]), h.residual[near])
        free[a[off]] = True
        z[a[off]] = extra.panel_misfit_z[off]
        c = np.flatnonzero(convention[a] & ~off) if redundant and not stated else np.zeros(0, int)
        if c.size:  # the convention not refuted but not stated either: where its alias tilts otherwise, every spin
            psi, reach = _alias(sub, dd[a[c]], shape[a[c]], u_shape[a[c]], spin[a[c]],
                                None if higher is None else higher.rows(a[c]), _rows(h, c))
            wide = reach > SPIN_ALIAS_SHARE * h.U95[c]
            w = a[c[wide]]
            free[w], alias[w], alias_reach[w] = True, psi[wide], reach[wide]
            off[c[wide]] = True
            held = (w, _rows(h, c[wide]), extra.rows(c[wide]))
        keep = ~off
        read = keep & convention[a] & (spin[a] > 0) if redundant else np.zeros(a.size, bool)
        if read.any():  # the convention holds: the spin read from the redundant reading
            r = a[read]
            h, extra = _read_spin(sub, dd[r], shape[r], u_shape[r], spin[r], None if higher is None else higher.rows(r),
                                  _rows(h, read), extra.rows(read))
            parts.append((r, h, extra))
        keep &= ~read
        if keep.any():
            parts.append((a[keep], _rows(h, keep), extra.rows(keep)))
    b = np.flatnonzero(free)
    if b.size:
        h, extra = _fit(sub, dd[b], shape[b], u_shape[b], spin[b], None, free=True)
        if higher is not None:  # a tight radius: the CAD beyond second order over every spin (spin_free)
            h, extra = _free_beyond(sub, dd[b], shape[b], u_shape[b], higher.rows(b), h, extra)
        if held is not None and held[0].size:  # the alias's holes: the misfit the convention passed kept for rules 2-3
            k = np.searchsorted(b, held[0])
            h = _put(h, k, _put(held[1], np.arange(k.size), _rows(h, k)), everything=True)
            extra.panel_misfit[k], extra.panel_misfit_z[k] = held[2].panel_misfit, held[2].panel_misfit_z
        parts.append((b, h, extra))
    share = np.zeros(m)
    for idx, hp, _ in parts:
        share[idx] = _spin_share(hp, convention[idx] & ~free[idx])
    h, extra = _merge(m, parts) if len(parts) > 1 or parts[0][0].size != m else (parts[0][1], parts[0][2])
    return SpinJudged(h, extra, free, convention & ~free, z, convention & ~free & (share > SPIN_BOUND_SHARE), alias,
                      alias_reach, stated)


def _free_beyond(sub, dd, shape, u_shape, higher, h, extra):
    """``(h, extra)`` of holes judged over every spin with the CAD beyond second order where it can matter
    (:func:`metrology.measure.spin_free.needs_beyond`)."""
    from metrology.measure.spin_free import free_beyond, needs_beyond

    k = np.flatnonzero(needs_beyond(sub, dd, shape, h))
    if not k.size:
        return h, extra
    hk, z = free_beyond(_fit, _spun, sub, dd[k], shape[k], u_shape[k], higher.rows(k), _rows(h, k))
    if z is not None:
        extra.panel_misfit_z[k] = z
    return _put(h, k, hk, everything=True), extra


def _alias(sub, dd, shape, u_shape, spin, higher, h0):
    """``(psi, reach)`` (h,) rad of :func:`metrology.measure.spin_alias.alias_reach` for holes fitted at the
    convention's spin (``h0``): two more fits, the head turned by 45 and 90 deg."""
    from metrology.measure.spin_alias import alias_reach

    k = len(dd)
    zero = np.zeros(k)
    fits = [_fit(sub, dd, K, u_shape, zero, hi)[0] for K, hi in (_spun(shape, higher, np.full(k, p))
                                                                  for p in (0.25 * np.pi, 0.5 * np.pi))]
    sd = np.fmax(fits[0].residual_sd, fits[1].residual_sd)
    return alias_reach((h0.residual, fits[0].residual, fits[1].residual),
                       (h0.budget.tilt, fits[0].budget.tilt, fits[1].budget.tilt), sd, SPIN_SIGMAS, spin)


def _within_reach(sub, dd, shape, u_shape, spin, higher, r0):
    """(h,) bool: the misfit ``r0`` (mm) at the convention's spin lies within what a spin within ``+-spin`` moves it
    (fits at its ends) plus :data:`SPIN_SIGMAS` of its sd: the first-order test's spin term leaves out the CAD beyond
    second order and the misfit's curvature in the spin, as large as the term itself at a tight radius (Table 2 on
    R 50: 1-2 % of holes refused the convention, then judged over every spin with a model that cannot hold there)."""
    zero = np.zeros(len(dd))
    ends = [_fit(sub, dd, K, u_shape, zero, hi)[0] for K, hi in (_spun(shape, higher, sign * spin) for sign in (1.0, -1.0))]
    reach = np.fmax(np.abs(ends[0].residual - r0), np.abs(ends[1].residual - r0))
    with np.errstate(invalid="ignore"):
        return np.abs(r0) <= reach + SPIN_SIGMAS * ends[0].residual_sd


def _spun(shape, higher, psi):
    """``(shape, higher)`` of a head turned by ``psi (h,)`` rad about its tool axis beyond the given
    (``tcs2panel Rz(psi)``, as metrology/sim/forward/log.py step 3 turns it): ``Rz^T K Rz``, the axes ``Rz^T e``."""
    c, s = np.cos(psi), np.sin(psi)
    Rz = np.zeros((len(psi), 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -s, s, c, 1.0
    K = np.einsum("hji,hjk,hkl->hil", Rz, shape, Rz)
    if higher is None:
        return K, None
    return K, replace(higher, axes=higher.axes @ Rz, tcs2panel=None if higher.tcs2panel is None else higher.tcs2panel @ Rz)


def _read_spin(sub, dd, shape, u_shape, spin, higher, h0, e0, read=True):
    """HoleNormals and PanelFit of holes on the cell's convention judged at the spin their redundant reading
    gives (module docstring); ``h0, e0`` their fit at the convention's spin (its misfit kept for rule 2). Holes
    where the spin's share of U95 is under :data:`SPIN_READ_SHARE` stay ``h0, e0``; where the spin's estimate is
    no better than ``+-spin``, or lies beyond it by more than its doubt, they are judged at the convention with
    ``+-spin``; either way the spin's term is taken from the fits at its ends (:func:`_spin_ends`). ``read``
    False (no redundant reading): the convention with ``+-spin``, its term from the ends.

    A hole judged at the convention is ``h0``'s (the same fit: the shape unturned, ``+-spin``), and its end at
    ``+spin`` the fit the read already made (:func:`_fits`)."""
    a0 = h0.budget.source(SPIN).half_width if h0.budget is not None else np.full(len(dd), np.inf)
    r = np.flatnonzero((a0 > SPIN_READ_SHARE * np.nan_to_num(h0.U95)) & (spin <= SPIN_ENDS_MAX))
    if not r.size:
        return h0, e0
    dd, shape, u_shape, spin, higher = dd[r], shape[r], u_shape[r], spin[r], None if higher is None else higher.rows(r)
    zero = np.zeros(r.size)

    def fit(k, psi, width):  # the holes k (an index into r) turned by psi (rad), the spin's doubt width
        K, hi = _spun(shape[k], None if higher is None else higher.rows(k), psi)
        return _fit(sub, dd[k], K, u_shape[k], width, hi)

    r0 = h0.residual[r]
    if not read:  # no redundant reading: the convention, its term from the spin's ends
        psi, width, reach, h1 = zero, spin, zero, None
    else:
        psi, width, reach, h1 = _estimate(fit, r0, spin)
    u = np.flatnonzero(width < spin)  # the spin read: judged at it
    c = np.flatnonzero(width >= spin)  # the convention with +-spin
    (h, e), hp, hm = _fits(fit, u, c, psi, width, spin, h1, _rows(h0, r), e0.rows(r))
    h = _spin_ends(h, hp, hm, width < spin)
    e.panel_misfit[:], e.panel_misfit_z[:] = e0.panel_misfit[r], e0.panel_misfit_z[r]
    if h0.misfit_bound is not None:  # rule 2: the most the spin within +-spin moves the misfit, beyond its first order
        at_ends = np.fmax(np.abs(hp.residual - r0), np.abs(hm.residual - r0))
        reach = np.nan_to_num(np.where(width < spin, reach, at_ends))
        bound = h0.misfit_bound.copy()
        bound[r] = np.fmax(bound[r], reach)
        h0 = replace(h0, misfit_bound=bound)
    return _put(h0, r, h), _with(e0, r, e)


def _fits(fit, u, c, psi, width, spin, h1, hc, ec):
    """``((h, e), hp, hm)`` of the holes ``u`` (the spin read: at ``psi`` with ``width``, and at ``psi +- width``) and
    ``c`` (the convention: ``hc, ec``, at ``+-spin``; ``h1`` the fit at ``+spin`` where the read made it), in order
    ``0..len(psi)``: only the fits not yet made (one call each: a call's rows stay near the cache's size)."""
    from metrology.measure.surface import PanelFit

    zero = np.zeros(len(psi))
    order = np.argsort(np.concatenate([u, c]), kind="stable")

    def joined(hu, hc):  # (u then c) in hole order
        return _rows(concat_normals([hu, hc]), order)

    if u.size:
        hu, eu = fit(u, psi[u], width[u])
        hpu, hmu = fit(u, psi[u] + width[u], zero[u])[0], fit(u, psi[u] - width[u], zero[u])[0]
    else:
        hu, eu = _rows(hc, u), ec.rows(u)
        hpu = hmu = hu
    if not c.size:
        return (hu, eu), hpu, hmu
    hmc = fit(c, -spin[c], zero[c])[0]
    hpc = fit(c, spin[c], zero[c])[0] if h1 is None else _rows(h1, c)
    e = PanelFit.concat([eu, ec.rows(c)]).rows(order)  # hc, ec: every hole's; the convention's are the rows c
    return (joined(hu, _rows(hc, c)), e), joined(hpu, hpc), joined(hmu, hmc)


def _estimate(fit, r0, spin):
    """``(psi, width, reach, h1)``: the spin the misfit ``r0`` at the convention's gives (secant steps on ``fit``) and
    its doubt, (h,) rad, where :data:`SPIN_READ_MAX` admits it, else ``0, spin``; how far the misfit moves to the
    spin's ends (h,) mm; and the fit at ``+spin`` (HoleNormals). The secant steps only where the doubt admits a read
    (it comes from the first slope)."""
    every = np.arange(len(r0))
    zero = np.zeros(len(r0))
    h1, _ = fit(every, spin, zero)  # the misfit at +spin, and its sd without the spin's doubt
    with np.errstate(invalid="ignore", divide="ignore"):
        slope = (h1.residual - r0) / spin
        u_psi = h1.residual_sd / np.abs(slope)
        psi = -r0 / slope
        width = SPIN_READ_WIDTH * u_psi
        may = np.flatnonzero(np.isfinite(psi) & np.isfinite(width) & (width < SPIN_READ_MAX * spin))
        for _ in range(SPIN_READ_STEPS - 1 if may.size else 0):
            p = np.clip(np.nan_to_num(psi[may]), -spin[may], spin[may])
            hp, _ = fit(may, p, zero[may])
            slope[may] = np.where(np.abs(p) > 1e-3 * spin[may], (hp.residual - r0[may]) / np.where(p == 0, 1.0, p),
                                  slope[may])
            psi[may] = p - hp.residual / slope[may]
    use = np.isfinite(psi) & np.isfinite(width) & (width < SPIN_READ_MAX * spin) & (np.abs(psi) <= spin + width)
    reach = np.fmax(np.abs(h1.residual - r0), np.abs(slope) * spin)  # mm: the misfit's move to the spin's ends
    return np.clip(np.where(use, psi, 0.0), -spin, spin), np.where(use, width, spin), reach, h1


def _spin_ends(h, hp, hm, read):
    """``h`` with its spin's term from the fits at the spin's ends ``hp, hm`` (HoleNormals of the same holes): the
    angle's larger change to either end, spread along it as the bound's kind (:data:`SPIN_BOUND_MODEL`; uniform where
    the spin was read, ``read (h,) bool``: its term then the source :data:`~metrology.measure.budget.SPIN_READ`), the
    tilt's larger change its 2-D spread. The first-order term (:func:`metrology.measure.panel_terms.panel_sources`)
    turns the shape alone: where the footprint is large against the radius the CAD's terms beyond second order turn
    too, and the change is not linear in the spin. The larger of the two is kept."""
    from metrology.measure.budget import Budget

    b = h.budget
    g = b.tilt
    dp, dm = hp.budget.tilt - g, hm.budget.tilt - g
    d = np.where(((dp * dp).sum(1) >= (dm * dm).sum(1))[:, None], dp, dm)
    a = np.fmax(np.abs(hp.angle - h.angle), np.abs(hm.angle - h.angle))  # rad, the angle's change to the farther end
    a = np.where(np.isfinite(a), a, 0.0)
    src, rsrc = b.source(SPIN), b.source(SPIN_READ)
    v = SPREAD_VARIANCE[src.kind.value]  # the fits' spin source is the bound's kind
    more = a > src.half_width
    cov = np.where(more[:, None], np.stack([d[:, 0] ** 2, d[:, 0] * d[:, 1], d[:, 1] ** 2], 1) * v, src.cov)
    hw = np.where(more, a, src.half_width)
    r = read[:, None]
    spin_src = replace(src, cov=np.where(r, 0.0, cov), half_width=np.where(read, 0.0, hw))
    read_src = replace(rsrc, cov=np.where(r, cov / (3.0 * v), rsrc.cov), half_width=np.where(read, hw, rsrc.half_width))
    b = Budget(g, tuple(spin_src if s.name == SPIN else read_src if s.name == SPIN_READ else s for s in b.sources))
    un = combine(b)
    bad = ~np.isfinite(h.angle)
    panel = np.sqrt(un.of(PANEL_SHAPE) ** 2 + un.of(SPIN) ** 2 + un.of(SPIN_READ) ** 2 + un.of(SURFACE_MODEL) ** 2) \
        if h.curvature_bound is not None else None
    return replace(h, u_angle=np.where(bad, np.nan, un.u), U95=np.where(bad, np.nan, un.U95), budget=b,
                   curvature_bound=panel)
