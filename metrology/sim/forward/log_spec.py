"""What a simulated hole log is made of: the cell's set-up (:class:`LogSpec`), the faults a sensor
can carry (:class:`SensorDrift`, :class:`SensorShift`) and one chunk of holes (:class:`HoleChunk`).

The generation itself is :mod:`.log`; the files, :mod:`.log_write`.

Conventions (mm, rad inside; degrees only in the files' ``_deg`` columns):

- TCS: the sensors' zero points ``zero (n, 3)`` mm and unit beams ``direction (n, 3)``. The tool
  axis is ``k = s e_z`` with ``s`` the sign of the beams' mean ``z`` component
  (:func:`tool_axis_sign`): ``k`` points from the head toward the surface, along the beams. The
  paper's Table 6 head and :mod:`.head` have ``s = +1``; its Table 2 layout has beams along ``-z``,
  ``s = -1``.
- A reading is the distance along the true beam from the true zero point to the panel, plus the
  sensor's offset (drift, shift; mm), Gaussian noise, and rarely a gross error; it is rounded to
  ``resolution_mm`` and blank (NaN) outside ``range_mm`` or where the beam misses the panel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from metrology.core.layout import SensorLayout
from metrology.sim.forward.panels import Panel

__all__ = ["SensorDrift", "SensorShift", "LogSpec", "HoleChunk", "tool_axis_sign", "START_TIME_S"]

#: default time of a log's first hole: 2026-11-25T06:00:00Z, s since the Unix epoch
START_TIME_S = 1795586400.0
SECONDS_PER = {"hour": 3600.0}


def tool_axis_sign(layout: SensorLayout) -> float:
    """``+1`` when the beams point along TCS ``+z`` on average, ``-1`` along ``-z``; ValueError when
    their mean ``z`` is 0 or a beam points against the others (the sensors must face the panel)."""
    uz = layout.direction[:, 2]
    s = float(np.sign(uz.mean()))
    if s == 0 or np.any(s * uz <= 0):
        raise ValueError(f"layout beams' z components {np.round(uz, 4).tolist()}: every beam must point to the same "
                         "side (the tool axis is the sign of their mean z)")
    return s


@dataclass(frozen=True)
class SensorDrift:
    """A slow linear zero drift of one sensor: its readings grow by ``rate_mm`` per hour of log time
    (``per="hour"``) or per hole (``per="hole"``) from the cell's hole ``start_hole`` (0-based) on.

    ``cell`` None: every cell's head drifts alike; else only the cell of that name (e.g. ``"C1"``).
    """

    sensor: str
    rate_mm: float
    per: str = "hour"
    start_hole: int = 0
    cell: str | None = None

    def __post_init__(self):
        if self.per not in ("hour", "hole"):
            raise ValueError(f"drift of {self.sensor}: per must be 'hour' or 'hole', got {self.per!r}")
        if not math.isfinite(self.rate_mm):
            raise ValueError(f"drift of {self.sensor}: rate {self.rate_mm} is not a finite number of mm")
        if self.start_hole < 0:
            raise ValueError(f"drift of {self.sensor}: start hole {self.start_hole} is negative")

    def offset(self, hole, time_s, start_time_s):
        """Offset ``(h,)`` mm at the cell's holes ``hole (h,)`` (0-based) taken at ``time_s (h,)`` s;
        ``start_time_s`` (s) is the nominal time of ``start_hole``."""
        on = hole >= self.start_hole
        if self.per == "hole":
            return np.where(on, self.rate_mm * (hole - self.start_hole), 0.0)
        return np.where(on, self.rate_mm * np.maximum(time_s - start_time_s, 0.0) / SECONDS_PER["hour"], 0.0)


@dataclass(frozen=True)
class SensorShift:
    """A knocked sensor: its zero jumps by ``size_mm`` at the cell's hole ``hole`` (0-based) and stays."""

    sensor: str
    size_mm: float
    hole: int
    cell: str | None = None

    def __post_init__(self):
        if not math.isfinite(self.size_mm):
            raise ValueError(f"shift of {self.sensor}: size {self.size_mm} is not a finite number of mm")
        if self.hole < 0:
            raise ValueError(f"shift of {self.sensor}: hole {self.hole} is negative")

    def offset(self, hole):
        """Offset ``(h,)`` mm at the cell's holes ``hole (h,)``."""
        return np.where(hole >= self.hole, self.size_mm, 0.0)


@dataclass(frozen=True)
class LogSpec:
    """One production set-up: the head as it is, the head as the cell believes it is, the panel,
    and how holes, readings and faults are drawn.

    Attributes
    ----------
    true_layout : SensorLayout, mm, TCS; the head as it is (casts the beams; its ``range_mm``
        blanks readings, its ``noise_mm`` is the noise unless ``noise_mm`` is given)
    cell_layout : SensorLayout, mm, TCS; the calibrated layout the cell computes its normal with
    panel : Panel
    angle_rad : (2,) float, rad, the true angle between tool axis and surface normal before the
        adjustment is uniform on [min, max]
    noise_mm : float or None, mm, 1 sigma reading noise of every sensor; None: ``true_layout.noise_mm``
    standoff_mm : float or None, mm, the mean reading on a flat surface square to the tool axis, which
        fixes where the TCS sits on the axis; None: the mean of the middles of ``range_mm``
    spin_rad : float, rad, the head's turn about the tool axis is uniform on [-spin, spin]
    spin_path : callable or None, ``spin_path(hole (h,) int) -> (h,) rad``: the head's turn at the cell's hole
        ``hole`` (a spin constant over the run, or drifting along it); None: uniform on [-spin, spin], hole by hole
    patch_half_mm : float, mm, drilling points are uniform over ``|x|, |y| <= patch_half_mm`` of the panel
    holes_per_hour : float, the cell's rate; hole ``j`` is at ``start_time_s + (j + 0.4 U) 3600 / rate`` s
    start_time_s : float, s since the Unix epoch (UTC)
    holes_per_panel : int, holes drilled in one panel before the next one
    drifts : tuple of SensorDrift
    shifts : tuple of SensorShift
    gross_rate : float, probability that a reading is gross (a multipath spot): ``+-U(gross_mm)`` mm more
    gross_mm : (2,) float, mm
    resolution_mm : float, mm, readings are rounded to this (the sensor's output step)
    temperature_c : (3,) float, deg C: mean, daily half-swing, 1 sigma noise of ``temperature_c``
        (logged; it acts on the readings only through a temperature coefficient of ``properties``)
    table : HoleTable or None; given, the holes are drilled at its points, cycled (:mod:`.log`), and
        ``angle_rad`` is the robot's attitude error from the table's feed; None: points uniform over the patch
    cad_panel : Panel or None, the panel the cell knows (its CAD: hole table checks, the shape operator it
        hands the controller); None: ``panel`` (the panel sits on its CAD)
    controller : callable or None, ``controller(layout, d, shape) -> (normal, ok)`` (:mod:`.log`, step 5),
        with an attribute ``wants_shape``; None: the micro-plane (:func:`.log.plane_normal`)
    properties : HeadProperties or None, the true head's sensor properties (:mod:`.properties`: a
        characteristic, an incidence bias, a temperature coefficient acting with ``temperature_c``)
    """

    true_layout: SensorLayout
    cell_layout: SensorLayout
    panel: Panel
    angle_rad: tuple = (math.radians(0.5), math.radians(5.0))
    noise_mm: float | None = None
    standoff_mm: float | None = None
    spin_rad: float = 0.0
    spin_path: object = None
    patch_half_mm: float = 200.0
    holes_per_hour: float = 600.0
    start_time_s: float = START_TIME_S
    holes_per_panel: int = 2000
    drifts: tuple = ()
    shifts: tuple = ()
    gross_rate: float = 0.0
    gross_mm: tuple = (0.2, 2.0)
    resolution_mm: float = 1e-4
    temperature_c: tuple = (20.0, 2.0, 0.1)
    table: object = None
    cad_panel: Panel | None = None
    controller: object = None
    properties: object = None

    @property
    def cad(self) -> Panel:
        """The panel the cell knows: ``cad_panel``, else ``panel``."""
        return self.panel if self.cad_panel is None else self.cad_panel

    def __post_init__(self):
        t, c = self.true_layout, self.cell_layout
        if tuple(t.names) != tuple(c.names):
            raise ValueError(f"true layout sensors {list(t.names)} differ from the cell layout's {list(c.names)}")
        if tool_axis_sign(t) != tool_axis_sign(c):
            raise ValueError("true and cell layouts point their beams to opposite sides of the head")
        lo, hi = self.angle_rad
        if not (0 <= lo <= hi < math.radians(45)):
            raise ValueError(f"angle range {math.degrees(lo):g},{math.degrees(hi):g} deg: expected "
                             "0 <= min <= max < 45")
        sigma = self.sigma_mm
        if not np.all(np.isfinite(sigma) & (sigma >= 0)):
            raise ValueError(f"reading noise {sigma.tolist()} mm: the layout states no noise_mm for every "
                             "sensor; give a noise (mm)")
        if not math.isfinite(self.target_reading_mm) or self.target_reading_mm <= 0:
            raise ValueError("the layout states no range_mm for every sensor; give a stand-off (mm)")
        if self.table is None:
            self.panel.check_patch(self.patch_half_mm)
        else:
            from metrology.sim.forward.holes import check_table

            check_table(self.table, self.cad, "the CAD panel")
        if not (self.holes_per_hour > 0 and math.isfinite(self.holes_per_hour)):
            raise ValueError(f"holes per hour must be positive, got {self.holes_per_hour}")
        if self.holes_per_panel < 1:
            raise ValueError(f"holes per panel must be at least 1, got {self.holes_per_panel}")
        if not (0 <= self.gross_rate <= 1):
            raise ValueError(f"gross rate {self.gross_rate}: expected a probability in [0, 1]")
        if not (self.resolution_mm >= 0 and self.spin_rad >= 0):
            raise ValueError("resolution and spin must be >= 0")
        for fault in (*self.drifts, *self.shifts):
            if fault.sensor not in t.names:
                raise ValueError(f"sensor {fault.sensor!r}: not in the layout ({', '.join(t.names)})")

    # ------------------------------------------------------------------ derived
    @property
    def sensors(self) -> tuple:
        return tuple(self.true_layout.names)

    @property
    def axis_sign(self) -> float:
        """``s``: the tool axis (head toward surface) is ``s e_z`` in the TCS."""
        return tool_axis_sign(self.true_layout)

    @property
    def sigma_mm(self) -> np.ndarray:
        """Reading noise ``(n,)`` mm, 1 sigma."""
        if self.noise_mm is not None:
            return np.full(self.true_layout.n, float(self.noise_mm))
        return np.asarray(self.true_layout.noise_mm, float)

    @property
    def target_reading_mm(self) -> float:
        """The mean reading on a flat surface square to the tool axis (mm)."""
        if self.standoff_mm is not None:
            return float(self.standoff_mm)
        r = self.true_layout.range_mm
        return float(np.mean(r.mean(axis=1))) if np.all(np.isfinite(r)) else math.nan

    @property
    def standoff_distance_mm(self) -> float:
        """``D``: the drill point is at ``D k`` in the TCS (mm). On a flat surface square to ``k`` at
        distance ``D``, sensor ``i`` reads ``(D - k.E_i) / (k.u_i)``; ``D`` makes their mean the target."""
        s = self.axis_sign
        ku = s * self.true_layout.direction[:, 2]
        kE = s * self.true_layout.zero[:, 2]
        n = self.true_layout.n
        return float((n * self.target_reading_mm + np.sum(kE / ku)) / np.sum(1.0 / ku))

    def offsets_for(self, cell: str):
        """The drifts and shifts acting on ``cell``'s head, per sensor index: list of (index, fault)."""
        names = self.sensors
        return [(names.index(f.sensor), f) for f in (*self.drifts, *self.shifts) if f.cell in (None, cell)]

    def to_dict(self) -> dict:
        return {"sensors": list(self.sensors), "panel": self.panel.to_dict(),
                "angle_deg": [math.degrees(a) for a in self.angle_rad], "noise_mm": self.sigma_mm.tolist(),
                "standoff_mm": self.target_reading_mm, "standoff_distance_mm": self.standoff_distance_mm,
                "tool_axis_sign": self.axis_sign, "spin_deg": math.degrees(self.spin_rad),
                "patch_half_mm": self.patch_half_mm, "holes_per_hour": self.holes_per_hour,
                "start_time_s": self.start_time_s, "holes_per_panel": self.holes_per_panel,
                "drifts": [vars(d) for d in self.drifts], "shifts": [vars(s) for s in self.shifts],
                "gross_rate": self.gross_rate, "resolution_mm": self.resolution_mm,
                "table": None if self.table is None else {"source": self.table.source, "holes": self.table.m},
                "cad_panel": self.cad.to_dict(),
                "controller": getattr(self.controller, "name", "microplane"),
                "properties": None if self.properties is None else self.properties.to_dict(),
                "true_zero_mm": self.true_layout.zero.tolist(),
                "true_direction": self.true_layout.direction.tolist()}


@dataclass(frozen=True)
class HoleChunk:
    """Consecutive holes of one cell: what the cell logs and the truth behind it.

    Attributes
    ----------
    cell : str, e.g. ``"C1"``
    sensors : tuple of str, length n
    hole : (h,) int64, 0-based index of the hole in its cell
    time_s : (h,) float, s since the Unix epoch (UTC)
    temperature_c : (h,) float, deg C
    panel : (h,) int64, 0-based index of the panel in its cell
    d, d_after : (h, n) float, mm, readings before and after the attitude adjustment; NaN = blank
    drill_point : (h, 3) float, mm, panel frame
    true_angle, true_after : (h,) float, rad, angle between tool axis and true surface normal
        before and after the adjustment
    normal_tcs, normal_after_tcs : (h, 3) float, unit, TCS before / after; the true outward
        normal (it points toward the head: ``n . k < 0``)
    offset : (h, n) float, mm, the drifts' and shifts' offset in each reading
    gross, gross_after : (h, n) bool, the readings made gross
    adjusted : (h,) bool, False where the cell had fewer than 3 readings and kept its attitude
        (or its controller answered not ok)
    pose_rotvec : (h, 3) float, rad, panel frame: the commanded ``tcs2panel`` rotation (before the
        adjustment) as a rotation vector (axis times angle)
    pose_origin : (h, 3) float, mm, panel frame: the commanded TCS origin
    ids : (h,) str or None, the log's hole ids (a hole table's); None: :meth:`hole_ids`
    point_ids : (h,) str or None, the hole table's own id of each hole (``ids`` without the pass suffix)
    nominal : (h, 3) float, mm, panel frame, the table's nominal drill point (NaN without a table)
    cad_angle : (h,) float, rad, angle between the true normal at the drilled point and the CAD's normal
        at the nominal point (off-CAD shows here); NaN without a table
    cad_offset : (h,) float, mm, the true surface's height over the CAD's at the nominal point, along the
        CAD's outward normal; NaN without a table
    """

    cell: str
    sensors: tuple
    hole: np.ndarray
    time_s: np.ndarray
    temperature_c: np.ndarray
    panel: np.ndarray
    d: np.ndarray
    d_after: np.ndarray
    drill_point: np.ndarray
    true_angle: np.ndarray
    true_after: np.ndarray
    normal_tcs: np.ndarray
    normal_after_tcs: np.ndarray
    offset: np.ndarray
    gross: np.ndarray
    gross_after: np.ndarray
    adjusted: np.ndarray
    pose_rotvec: np.ndarray = None
    pose_origin: np.ndarray = None
    ids: np.ndarray = None
    point_ids: np.ndarray = None
    nominal: np.ndarray = None
    cad_angle: np.ndarray = None
    cad_offset: np.ndarray = None

    @property
    def n(self) -> int:
        return len(self.hole)

    def hole_ids(self) -> np.ndarray:
        """``(h,)`` str, ``"<cell>-<hole+1, 8 digits>"``, e.g. ``"C1-00000001"``; a hole table's ids when given."""
        if self.ids is not None:
            return self.ids
        return np.char.add(f"{self.cell}-", np.char.zfill((self.hole + 1).astype(str), 8))

    def slice(self, start: int, stop: int) -> "HoleChunk":
        """The holes ``[start, stop)`` of this chunk."""
        kw = {k: (v[start:stop] if isinstance(v, np.ndarray) else v) for k, v in vars(self).items()}
        return HoleChunk(**kw)

    @staticmethod
    def concat(chunks) -> "HoleChunk":
        """One chunk of consecutive chunks of the same cell."""
        chunks = list(chunks)
        first = chunks[0]
        if any(c.cell != first.cell for c in chunks):
            raise ValueError("chunks of different cells cannot be joined")
        kw = {k: (np.concatenate([vars(c)[k] for c in chunks]) if isinstance(v, np.ndarray) else v)
              for k, v in vars(first).items()}
        return HoleChunk(**kw)

