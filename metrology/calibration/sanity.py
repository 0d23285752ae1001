"""Gross mismatches between a tracker export and the model, and the user mistake that explains them.

A plausible mistake in a user's own export (quaternions written scalar-last under the scalar-first
header, positions in metres or inches, two sensor columns swapped, readings in metres or microns)
does not make the fit fail: it makes it fit nonsense. :func:`screen` fits the data (per-sensor
least squares, a few ms) and calls the data *gross* when any of these holds:

* **geometry**: for some sensor, fewer than ``MIN_READINGS`` of its readings come from a pose in
  which its nominal beam meets the datum in front of the sensor;
* **noise**: the residual RMS of some sensor is more than :data:`GROSS_NOISE_FACTOR` (100: two
  orders of magnitude) times its stated ``noise_mm`` *and* the chi-square of its residuals,
  ``sum(r^2) / noise^2`` on ``m - 5`` degrees of freedom, has p < :data:`GROSS_P` (1e-12);
  skipped for a sensor without a stated noise;
* **correction**: the fit moves a zero point more than :data:`GROSS_ZERO_MM` or tilts a beam more
  than :data:`GROSS_TILT_DEG` from the layout it starts from (a column that belongs to another
  sensor fits as well as its own, 70 mm and 50 deg away). A few gross readings (a spot on a
  scratch; ``diagnose`` flags them) can drag a least-squares fit that far along a direction
  the poses leave weak (a blind case with 2-mm gross readings: 11.9 mm and 11.9 deg), so where
  the least-squares fit fails this test the correction is judged on a robust refit (soft-L1
  loss, discounting residuals beyond :data:`ROBUST_SCALE` times the stated noise). A mistake in
  the export misplaces every reading, and the robust fit goes as far astray as the plain one.

Where the noise test fails, the same robust refit tells a few gross readings from a mistake:
the sensor has a few gross readings when its residuals' robust scale (1.4826 times their median
absolute value) is within :data:`GROSS_READINGS_SCALE` (3) stated noises and at most
max(:data:`GROSS_READINGS_MIN`, :data:`GROSS_READINGS_FRACTION` of its readings) (3, 15 %) are
further than :data:`GROSS_READING_SIGMAS` (10) noises from that fit. Three 2-mm gross readings
of one sensor in 59 poses at 3 um noise (a blind case) put its residual RMS at 0.33 mm, 109
times the noise; its robust scale is 3.7 um and 3 readings are far. A mistake misplaces many
readings: all (a swapped column, a unit) or a block of them (two columns swapped in a fifth of
the rows, a shift from some pose on). A reading further than :data:`GROSS_ZERO_MM` from the
robust fit is no gross reading of the surface but a code or a mistake (9999 for "no reading").
:func:`check_dataset` refuses such data for a calibration (a least-squares calibration would
follow them), saying they are a few gross readings and how to find them, and lets them
through for ``diagnose`` (``allow_gross_readings``), whose ``outliers`` family flags them.

:func:`explain` then re-reads the data under each likely mistake and refits; the mistake whose
reading is not gross, with the smallest residual, is named in a :class:`Mismatch`.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np

from metrology.calibration.dataset import MIN_READINGS, Dataset, load_dataset
from metrology.io.export import POSITION_UNITS
from metrology.core.stats import robust_sigma

__all__ = ["GROSS_NOISE_FACTOR", "GROSS_P", "GROSS_ZERO_MM", "GROSS_TILT_DEG", "ROBUST_SCALE", "GROSS_READINGS_SCALE",
           "GROSS_READING_SIGMAS", "GROSS_READINGS_FRACTION", "GROSS_READINGS_MIN", "Screening", "Mismatch",
           "screen", "explain", "check_dataset", "load_checked"]

#: residual RMS over stated noise above which (with :data:`GROSS_P`) the data are a gross mismatch
GROSS_NOISE_FACTOR = 100.0
#: chi-square p-value below which (with :data:`GROSS_NOISE_FACTOR`) the data are a gross mismatch
GROSS_P = 1e-12
#: a fitted zero point further than this from the starting layout is not a calibration, mm
GROSS_ZERO_MM = 10.0
#: a fitted beam tilted further than this from the starting layout is not a calibration, deg
GROSS_TILT_DEG = 10.0
#: the robust refit of the correction test discounts residuals beyond this many stated noises
ROBUST_SCALE = 3.0
#: a sensor fails the noise test through a few gross readings only (not a mistake) when the robust
#: refit's scale is within this many stated noises ...
GROSS_READINGS_SCALE = 3.0
#: ... and its readings further than this many stated noises from that fit are few: at most
#: :data:`GROSS_READINGS_MIN` or this fraction of the sensor's readings, whichever is more
GROSS_READING_SIGMAS = 10.0
GROSS_READINGS_FRACTION = 0.15
GROSS_READINGS_MIN = 3


def _noise_fails(rms, noise_mm, p_value) -> np.ndarray:
    """(n,) bool: the noise test (RMS over :data:`GROSS_NOISE_FACTOR` stated noises and chi-square
    p under :data:`GROSS_P`; False where no noise is stated)."""
    with np.errstate(invalid="ignore"):
        return (rms > GROSS_NOISE_FACTOR * noise_mm) & (p_value < GROSS_P)


def _mm(x) -> str:
    """A length for a message: 2 significant digits, no exponent."""
    if not np.isfinite(x):
        return "not computable"
    return f"{x:.0f} mm" if abs(x) >= 10 else f"{float(f'{x:.2g}'):g} mm"


@dataclass(frozen=True)
class Screening:
    """How one reading of the data fits the model.

    Attributes
    ----------
    names : tuple of str, length n
    n_geometric : (n,) int, readings whose nominal beam meets the datum in front of the sensor
    n_readings : (n,) int, readings in the export
    residual_rms : (n,) float, mm; NaN where not fitted
    noise_mm : (n,) float, mm; NaN where not stated
    p_value : (n,) float, chi-square p of the residuals against the stated noise; NaN where not stated
    zero_shift_mm : (n,) float, mm, |fitted - starting zero point|
    tilt_deg : (n,) float, deg, angle between the fitted and the starting beam
    worst : (str, float) or (), the reading furthest from the fit, in words, and its value (mm)
    robust_scale_mm : (n,) float, mm, or None: 1.4826 x the median absolute residual of the
        robust refit, where the noise test was failed (NaN elsewhere; inf where a reading is
        further than :data:`GROSS_ZERO_MM` from that fit); None when not refitted
    n_far : (n,) int or None: readings further than :data:`GROSS_READING_SIGMAS` stated noises
        from the robust refit, where the noise test was failed (0 elsewhere)
    """

    names: tuple
    n_geometric: np.ndarray
    n_readings: np.ndarray
    residual_rms: np.ndarray
    noise_mm: np.ndarray
    p_value: np.ndarray
    zero_shift_mm: np.ndarray
    tilt_deg: np.ndarray
    worst: tuple = ()
    robust_scale_mm: np.ndarray | None = None
    n_far: np.ndarray | None = None

    @property
    def geometry_fails(self) -> bool:
        return bool(np.any(self.n_geometric < np.minimum(MIN_READINGS, self.n_readings)))

    @property
    def noise_fails(self) -> np.ndarray:
        return _noise_fails(self.residual_rms, self.noise_mm, self.p_value)

    @property
    def gross_readings(self) -> np.ndarray:
        """(n,) bool: sensors that fail the noise test only through a few gross readings (see
        the module: the robust refit's scale near the noise, few readings far from it)."""
        if self.robust_scale_mm is None or self.n_far is None:
            return np.zeros(len(self.names), bool)
        few = self.n_far <= np.maximum(GROSS_READINGS_MIN, GROSS_READINGS_FRACTION * self.n_readings)
        with np.errstate(invalid="ignore"):
            return self.noise_fails & few & (self.robust_scale_mm <= GROSS_READINGS_SCALE * self.noise_mm)

    @property
    def mistaken(self) -> bool:
        """Gross for a reason other than a few gross readings: a mistake of the export or layout."""
        return self.geometry_fails or bool(np.any(self.noise_fails & ~self.gross_readings)
                                           or np.any(self.correction_fails))

    @property
    def correction_fails(self) -> np.ndarray:
        return (self.zero_shift_mm > GROSS_ZERO_MM) | (self.tilt_deg > GROSS_TILT_DEG)

    @property
    def gross(self) -> bool:
        return self.geometry_fails or bool(np.any(self.noise_fails) or np.any(self.correction_fails))

    @property
    def score(self) -> float:
        """Residual RMS over all sensors, mm (lower fits better; inf when not fitted)."""
        r = self.residual_rms
        return float(np.sqrt(np.mean(r**2))) if np.all(np.isfinite(r)) else np.inf

    def rms_text(self) -> str:
        return _mm(self.score)

    def describe(self) -> str:
        """Why this reading is gross, in words."""
        if self.geometry_fails:
            i = int(np.argmin(self.n_geometric - self.n_readings))
            return (f"the poses cannot put the spots on the datum: the nominal beam of {self.names[i]} meets "
                    f"the datum in front of the sensor in {self.n_geometric[i]} of {self.n_readings[i]} poses")
        if np.any(self.noise_fails):
            i = int(np.argmax(np.where(self.noise_fails, self.residual_rms / self.noise_mm, -1)))
            return (f"the residual RMS of {self.names[i]} is {_mm(self.residual_rms[i])} against a stated noise "
                    f"of {self.noise_mm[i]:g} mm (chi-square p < {GROSS_P:g})")
        i = int(np.argmax(np.where(self.correction_fails, self.zero_shift_mm + self.tilt_deg, -1)))
        return (f"the fit moves the zero point of {self.names[i]} {self.zero_shift_mm[i]:.3g} mm and tilts its "
                f"beam {self.tilt_deg[i]:.3g} deg from the layout, not a calibration")


def _correction(start, fitted):
    """(|zero shift| (n,) mm, beam tilt (n,) deg) of the layout ``fitted`` from ``start``."""
    shift = np.linalg.norm(fitted.zero - start.zero, axis=1)
    u0 = start.direction / np.linalg.norm(start.direction, axis=1, keepdims=True)
    u1 = fitted.direction / np.linalg.norm(fitted.direction, axis=1, keepdims=True)
    return shift, np.degrees(np.arctan2(np.linalg.norm(np.cross(u0, u1), axis=1), np.sum(u0 * u1, axis=1)))


def screen(dataset: Dataset) -> Screening:
    """Fit ``dataset`` (least squares, its layout as the start; a robust refit where that one
    fails the correction test, see the module) and measure how it fits."""
    from scipy.stats import chi2

    from metrology.calibration.estimators import lsq
    from metrology.core.model import readings

    layout, obs = dataset.layout, dataset.obs
    has = np.isfinite(obs.d)
    _, valid = readings(layout.zero, layout.direction, obs.normal, obs.offset)
    n_geo, n_read = (valid & has).sum(axis=0), has.sum(axis=0)
    n = layout.n
    nan = np.full(n, np.nan)
    if np.any(n_geo < np.minimum(MIN_READINGS, n_read)):
        return Screening(layout.names, n_geo, n_read, nan, layout.noise_mm, nan, nan, nan)
    with np.errstate(all="ignore"):
        cal = lsq(layout, obs)
    rms = np.where(cal.n_used >= MIN_READINGS, cal.residual_rms, np.nan)
    dof = np.maximum(cal.n_used - 5, 1)
    with np.errstate(all="ignore"):
        p = chi2.sf(cal.n_used * rms**2 / layout.noise_mm**2, dof)
    shift, tilt = _correction(layout, cal.layout)
    stated = np.isfinite(layout.noise_mm) & (layout.noise_mm > 0)
    noisy = _noise_fails(rms, layout.noise_mm, p)
    dragged = ((shift > GROSS_ZERO_MM) | (tilt > GROSS_TILT_DEG)) & stated
    robust = far = None
    if np.any(dragged | noisy):
        # a few gross readings can drag the least-squares fit and inflate its RMS: a robust refit
        with np.errstate(all="ignore"):
            rob = lsq(layout, obs, loss="soft_l1", f_scale=np.where(stated, ROBUST_SCALE * layout.noise_mm, 1.0))
        shift_r, tilt_r = _correction(layout, rob.layout)
        better = dragged & (shift_r <= GROSS_ZERO_MM) & (tilt_r <= GROSS_TILT_DEG)
        shift, tilt = np.where(better, shift_r, shift), np.where(better, tilt_r, tilt)
        pred_r, _ = readings(rob.layout.zero, rob.layout.direction, obs.normal, obs.offset)
        robust, far = np.full(n, np.nan), np.zeros(n, int)
        for i in np.flatnonzero(noisy):
            a = np.abs(obs.d[:, i] - pred_r[:, i])
            a = a[np.isfinite(a)]
            # a reading further off than a calibration can move is a code or a mistake, not a
            # gross reading of the surface (a spot on a scratch or an edge is off by a few mm)
            robust[i] = np.inf if len(a) == 0 or np.max(a) > GROSS_ZERO_MM else robust_sigma(a, about=0.0)
            far[i] = int(np.sum(a > GROSS_READING_SIGMAS * layout.noise_mm[i]))
    pred, _ = readings(cal.layout.zero, cal.layout.direction, obs.normal, obs.offset)
    res = np.abs(obs.d - pred)
    worst = ()
    if np.any(np.isfinite(res)):
        k, i = np.unravel_index(np.nanargmax(res), res.shape)
        worst = (f"the reading furthest from the fit is pose {dataset.export.pose_id[k]} d_{layout.names[i]} = "
                 f"{obs.d[k, i]:g} mm, {_mm(res[k, i])} off", float(obs.d[k, i]))
    return Screening(layout.names, n_geo, n_read, rms, layout.noise_mm, p, shift, tilt, worst, robust, far)


@dataclass(frozen=True)
class Mismatch:
    """A gross mismatch and, when one fits, the mistake that explains it.

    Attributes
    ----------
    as_read : Screening
    mistake : str or None, the mistake in words ("quaternions look scalar-last ...")
    fix : str or None, what to do about it
    fitted : Screening or None, the data read under that mistake
    tried : tuple of str, the mistakes tested
    """

    as_read: Screening
    mistake: str | None
    fix: str | None
    fitted: Screening | None
    tried: tuple

    def message(self, source: str) -> str:
        """The one-line error."""
        first = self.as_read
        if self.mistake is not None and not (first.geometry_fails or np.any(first.noise_fails)):
            f = self.fitted
            return (f"{source}: {self.mistake}: read that way the fit stays within {np.max(f.zero_shift_mm):.2g} mm "
                    f"and {np.max(f.tilt_deg):.2g} deg of the layout, while as read {first.describe()} "
                    f"(residual RMS {f.rms_text()} both ways); {self.fix}")
        if self.mistake is not None:
            against = (f"against {first.rms_text()} as read ({first.describe()})" if np.isfinite(first.score)
                       else f"while as read {first.describe()}")
            return f"{source}: {self.mistake}: read that way the residual RMS is {self.fitted.rms_text()} {against}; {self.fix}"
        worst, code = "", "VALUE"
        if first.worst:
            worst, code = f"; {first.worst[0]}", f"{first.worst[1]:g}"
        if not first.mistaken:  # a few gross readings
            i = int(np.argmax(np.where(first.gross_readings, first.residual_rms / first.noise_mm, -1)))
            return (f"{source}: a few gross readings: the residual RMS of {first.names[i]} is "
                    f"{_mm(first.residual_rms[i])} against a stated noise of {first.noise_mm[i]:g} mm, but a robust "
                    f"fit leaves {_mm(first.robust_scale_mm[i])} with {first.n_far[i]} of its {first.n_readings[i]} "
                    f"readings far from it{worst}; a calibration would follow them: 'metro diagnose' names them "
                    f"(outliers), then leave them out of the export")
        return (f"{source}: the readings do not fit the poses and the datum: {first.describe()}{worst}; "
                f"none of the usual export mistakes explains it ({len(self.tried)} tried: quaternion order, position "
                f"and reading units, swapped sensor columns); if {code} is "
                f"the PLC's 'no reading' code, pass --no-reading {code}")


def _hypotheses(dataset: Dataset, quaternion_order: str, position_units: str):
    """(words, fix, tried label, dataset) for each likely mistake, relative to how the data were read."""
    ex = dataset.export
    other = "xyzw" if quaternion_order == "wxyz" else "wxyz"
    perm = [3, 0, 1, 2] if other == "xyzw" else [1, 2, 3, 0]
    quats = [(None, ex.quaternion)]
    if other == "xyzw":
        quats.append(("quaternions look scalar-last (x, y, z, w) under the scalar-first header qw,qx,qy,qz",
                      ex.quaternion[:, perm]))
    else:
        quats.append(("quaternions look scalar-first (w, x, y, z), not --quaternion-order xyzw",
                      ex.quaternion[:, perm]))
    units = {"mm": "mm", "m": "metres", "in": "inches"}
    for (qword, q), unit in itertools.product(quats, POSITION_UNITS):
        if qword is None and unit == position_units:
            continue
        words, fixes = [], []
        if qword is not None:
            words.append(qword)
            fixes.append(f"--quaternion-order {other}")
        if unit != position_units:
            words.append(f"positions look like {units[unit]}")
            fixes.append(f"--position-units {unit}")
        scale = POSITION_UNITS[unit] / POSITION_UNITS[position_units]
        ds = replace(dataset, export=replace(ex, quaternion=q, tcs2tracker_trans=ex.tcs2tracker_trans * scale))
        fix = "reorder the columns or pass " if qword is not None else "convert them to mm or pass "
        yield " and ".join(words), fix + " ".join(fixes), "+".join(fixes), ds
    for factor, what in ((1000.0, "metres"), (1e-3, "microns")):
        ds = replace(dataset, export=replace(ex, d=ex.d * factor))
        yield f"readings look like {what}", "write the readings in mm", f"readings in {what}", ds
    names = ex.names
    for a, b in itertools.combinations(range(len(names)), 2):
        idx = list(range(len(names)))
        idx[a], idx[b] = b, a
        ds = replace(dataset, export=replace(ex, d=ex.d[:, idx]))
        yield (f"columns d_{names[a]} and d_{names[b]} look swapped", "swap the two column headers",
               f"d_{names[a]}<->d_{names[b]}", ds)


#: a mistake is refitted only when the layout it starts from predicts its readings within this
#: factor of the best-predicted reading of the data (the others are orders of magnitude off)
PREFILTER = 100.0


def _nominal_rms(dataset: Dataset) -> float:
    """RMS of readings minus the layout's predictions, mm, with no fit (inf when none predicted)."""
    from metrology.core.model import readings

    obs = dataset.obs
    pred, _ = readings(dataset.layout.zero, dataset.layout.direction, obs.normal, obs.offset)
    r = obs.d - pred
    ok = np.isfinite(r)
    if ok.sum(axis=0).min() < MIN_READINGS:
        return np.inf
    return float(np.sqrt(np.mean(r[ok] ** 2)))


def explain(dataset: Dataset, quaternion_order: str = "wxyz", position_units: str = "mm",
            screening: Screening | None = None, allow_gross_readings: bool = False) -> Mismatch | None:
    """None when ``dataset`` is not a gross mismatch; else the :class:`Mismatch`, naming the
    mistake (of those in the module docstring) whose reading is not gross and fits best.

    ``quaternion_order`` and ``position_units`` say how the export was read (the mistakes
    are tested relative to it). ``allow_gross_readings``: data gross only through a few gross
    readings (:attr:`Screening.gross_readings`) are not a mismatch.
    """
    first = screen(dataset) if screening is None else screening
    if not first.gross or (allow_gross_readings and not first.mistaken):
        return None
    cands = [(h, _nominal_rms(h[3])) for h in _hypotheses(dataset, quaternion_order, position_units)]
    floor = min([c[1] for c in cands] + [_nominal_rms(dataset)])
    best, tried = None, [h[2] for h, _ in cands]
    for (words, fix, label, ds), nominal_rms in cands:
        if not nominal_rms <= PREFILTER * floor:
            continue
        s = screen(ds)
        if not s.gross and (best is None or s.score < best[2].score):
            best = (words, fix, s)
    if best is None:
        return Mismatch(first, None, None, None, tuple(tried))
    return Mismatch(first, best[0], best[1], best[2], tuple(tried))


def check_dataset(dataset: Dataset, source: str, quaternion_order: str = "wxyz", position_units: str = "mm",
                  allow_gross_readings: bool = False) -> None:
    """Raise a one-line ``ValueError`` naming the mistake when ``dataset`` is a gross mismatch
    (with ``allow_gross_readings``, not when it is gross only through a few gross readings)."""
    mismatch = explain(dataset, quaternion_order, position_units, allow_gross_readings=allow_gross_readings)
    if mismatch is not None:
        raise ValueError(mismatch.message(source))


def load_checked(export_path, plane_path, layout_path, quaternion_order="wxyz", position_units="mm", no_reading=None,
                 warn=None, allow_gross_readings=False):
    """:func:`~metrology.calibration.dataset.load_dataset`, then refuse a gross mismatch naming the
    likely mistake (:func:`check_dataset`; ``allow_gross_readings``:
    not data gross only through a few gross readings, which ``diagnose`` flags). ``warn(line)``
    is called with the count of dropped "no reading" codes, if any."""
    dataset = load_dataset(export_path, plane_path, layout_path, quaternion_order, position_units, no_reading, warn)
    check_dataset(dataset, str(export_path), quaternion_order, position_units, allow_gross_readings)
    if warn is not None and dataset.dropped:
        warn(f"{export_path}: {dataset.no_reading_summary()}")
    return dataset
