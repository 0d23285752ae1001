"""A head's sensor properties that hold from its calibration to production, and a calibration run drawn with them.

A property acts on every reading the sensor ever gives, in the calibration export and in the
production log alike (issue 50): what ``metro diagnose`` learns on the first must go to work on
the second. Each is written from the physics (nothing here imports the measurement model or its
effect terms; :mod:`.characteristic`, :mod:`.incidence` give the shapes):

- a characteristic ``e(d)`` mm of the true distance (a gain ``g d``, a calibration table, an S-curve;
  :class:`~.characteristic.Characteristic`);
- an incidence bias ``b(a)`` mm, even in the true incidence angle ``a`` of the beam on the surface
  (:class:`~.incidence.IncidenceBias`);
- a temperature coefficient of the zero, ``tempco_mm_per_k (T - ref_temp_c)`` mm (the head's
  temperature ``T``, deg C; the sensor's housing and mount grow with it).

:func:`draw_calibration` draws a calibration run of a head with such properties over a flat datum,
its temperature swept over a stated span (production then runs partly outside it).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["SensorProperty", "HeadProperties", "CalibrationRun", "draw_calibration"]


@dataclass(frozen=True)
class SensorProperty:
    """The properties of sensor ``sensor`` (index): any of a characteristic, an incidence bias and a
    temperature coefficient (mm per deg C about ``ref_temp_c``)."""

    sensor: int
    characteristic: object = None
    incidence: object = None
    tempco_mm_per_k: float = 0.0
    ref_temp_c: float = 20.0

    def offset(self, d_true, angle, temp_c):
        """Reading offset ``(h,)`` mm at true distances ``d_true (h,)`` mm, incidence angles ``angle
        (h,)`` rad (None where no incidence bias), head temperatures ``temp_c (h,)`` deg C."""
        out = np.zeros(np.shape(d_true))
        if self.characteristic is not None:
            out = out + self.characteristic(d_true)
        if self.incidence is not None:
            out = out + self.incidence(angle)
        if self.tempco_mm_per_k:
            out = out + self.tempco_mm_per_k * (np.asarray(temp_c, float) - self.ref_temp_c)
        return out

    def to_dict(self) -> dict:
        return {"sensor": self.sensor,
                "characteristic": None if self.characteristic is None else self.characteristic.to_dict(),
                "incidence": None if self.incidence is None else self.incidence.to_dict(),
                "tempco_mm_per_k": self.tempco_mm_per_k, "ref_temp_c": self.ref_temp_c}


@dataclass(frozen=True)
class HeadProperties:
    """The properties of a head's sensors (:class:`SensorProperty`, one per sensor that has any)."""

    sensors: tuple = ()

    @property
    def needs_incidence(self) -> bool:
        return any(p.incidence is not None for p in self.sensors)

    def offsets(self, d_true, angle, temp_c):
        """``(h, n)`` mm: each reading's offset at true distances ``d_true (h, n)`` mm, incidence angles
        ``angle (h, n)`` rad or None, temperatures ``temp_c (h,)`` deg C."""
        out = np.zeros(np.shape(d_true))
        for p in self.sensors:
            a = None if angle is None else angle[:, p.sensor]
            out[:, p.sensor] = p.offset(d_true[:, p.sensor], a, temp_c)
        return np.where(np.isfinite(out), out, 0.0)

    def to_dict(self) -> dict:
        return {"sensors": [p.to_dict() for p in self.sensors]}


@dataclass(frozen=True)
class CalibrationRun:
    """A calibration run drawn with a head's properties.

    export : TrackerExport (reported poses = true poses, readings); plane : (normal (3,), offset mm),
    the flat datum in the tracker frame; d_true : (p, n) mm, true distances; incidence : (p, n) rad;
    temperature : (p,) deg C
    """

    export: object
    plane: tuple
    d_true: np.ndarray
    incidence: np.ndarray
    temperature: np.ndarray
    extra: dict = field(default_factory=dict)


def draw_calibration(rng: np.random.Generator, true_layout, properties: HeadProperties, n_poses: int, *,
                     noise_mm: float, temp_span_c=(19.0, 21.0), tilt_max_deg: float = 14.0,
                     range_mm=(30.0, 70.0), z0_mm: float = 30.0) -> CalibrationRun:
    """A calibration export of the head ``true_layout`` (TCS, mm) with ``properties`` over a flat
    datum: ``n_poses`` poses tilted up to ``tilt_max_deg``, 15-60 s apart, the head's temperature
    swept twice over ``temp_span_c`` (a warm-up and a cool-down: interleaved, not one sweep),
    Gaussian reading noise ``noise_mm``."""
    from metrology.core.frames import quaternion_from_matrix
    from metrology.io.export import TrackerExport
    from metrology.sim.forward.drift import draw_times
    from metrology.sim.forward.errors import add_noise
    from metrology.sim.forward.poses import draw_poses
    from metrology.sim.forward.surface import draw_surface

    surface, _ = draw_surface(rng)
    rot, trans, hits = draw_poses(rng, surface, true_layout.zero, true_layout.direction, n_poses,
                                  tilt_max_rad=np.radians(tilt_max_deg), range_mm=range_mm, z0_mm=z0_mm)
    t = draw_times(rng, n_poses)
    lo, hi = temp_span_c
    phase = rng.uniform(0, 2 * np.pi)
    temp = 0.5 * (lo + hi) + 0.5 * (hi - lo) * np.sin(2 * np.pi * 2 * t / max(t[-1], 1.0) + phase)
    d = hits.d + properties.offsets(hits.d, hits.incidence, temp)
    d = add_noise(rng, d, noise_mm)
    export = TrackerExport(tuple(f"P{i + 1:03d}" for i in range(n_poses)), t, np.round(temp, 3),
                           quaternion_from_matrix(rot), trans, true_layout.names, d)
    return CalibrationRun(export, (surface.normal, -float(surface.origin @ surface.normal)), hits.d, hits.incidence, temp)
