"""The fleet summary's typed records (:mod:`metrology.measure.summary`): a group's key, its counts by status and
figures, the worst holes, and the sums of the panel's checks against its CAD. Each is written once, at the edge,
by its ``to_dict`` (the JSON's keys)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import NamedTuple

import numpy as np

__all__ = ["GroupKey", "Counts", "Quantiles", "Figures", "WorstHole", "OffCadSums", "CadSums", "OFF_CAD_SIGMAS",
           "CAD_OFFSET_MM"]

#: with the panel known: a hole whose redundant reading misses the CAD's surface by more than this
#: many sigmas (noise, calibration, the panel's stated uncertainty; two-sided p ~ 6e-5) counts as
#: a panel off its CAD there
OFF_CAD_SIGMAS = 4.0
#: with the robot's commanded pose in the log: a hole whose readings put the surface this far off the
#: CAD's along its normal (mm) counts as off its CAD there (on its CAD the bundled panels read within
#: 0.01 mm: tests/measure/test_panel_bundled.py)
CAD_OFFSET_MM = 0.05


class GroupKey(NamedTuple):
    """What a group of holes shares: its cell, panel and day (UTC date, ISO 8601)."""

    cell: str
    panel: str
    day: str


@dataclass(frozen=True)
class Counts:
    """Holes by status."""

    conforms: int = 0
    fails: int = 0
    undecided: int = 0
    not_measured: int = 0

    @property
    def total(self) -> int:
        return self.conforms + self.fails + self.undecided + self.not_measured

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Quantiles:
    """Quantiles of an angle, deg (NaN: no hole)."""

    p50: float
    p95: float
    p99: float
    p99_9: float

    def to_dict(self) -> dict:
        return {"p50": self.p50, "p95": self.p95, "p99": self.p99, "p99.9": self.p99_9}


@dataclass(frozen=True)
class Figures:
    """A group's figures: holes judged and the judged angle's mean and s (deg); for a cell and the fleet (groups
    with a histogram) its Ppk with the 95 % interval and the angle's quantiles before and after (None: not kept)."""

    measured: int
    mean_deg: float
    sd_deg: float
    ppk: float | None = None
    ppk_ci95: tuple | None = None
    capability: str | None = None
    quantiles_before_deg: Quantiles | None = None
    quantiles_after_deg: Quantiles | None = None

    def to_dict(self) -> dict:
        out = {"measured": self.measured, "mean_deg": self.mean_deg, "sd_deg": self.sd_deg}
        if self.ppk is not None:
            out.update({"ppk": self.ppk, "ppk_ci95": list(self.ppk_ci95), "capability": self.capability})
        if self.quantiles_before_deg is not None:
            out["quantiles_before_deg"] = self.quantiles_before_deg.to_dict()
            out["quantiles_after_deg"] = self.quantiles_after_deg.to_dict()
        return out


@dataclass(frozen=True)
class WorstHole:
    """One of the :data:`WORST` holes with the largest judged angle (deg; ``time_s``: s since 1970, UTC)."""

    hole_id: str
    cell: str
    panel: str
    time_s: float
    angle_deg: float
    U95_deg: float
    status: str

    def order(self) -> tuple:
        """The worst first; ties by cell, time and hole."""
        return -self.angle_deg, self.cell, self.time_s, self.hole_id

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class OffCadSums:
    """With the panel known: holes checked (4 sensors), those off the CAD (``|z|`` over :data:`OFF_CAD_SIGMAS`),
    the sum of their sizes and the largest (1/mm) with its hole."""

    checked: int = 0
    holes: int = 0
    sum_per_mm: float = 0.0
    max_per_mm: float = 0.0
    max_hole: str | None = None

    @classmethod
    def of(cls, t) -> "OffCadSums":
        """The sums of a batch's results ``t`` (pyarrow.Table; none without ``panel_misfit_z``)."""
        if "panel_misfit_z" not in t.column_names:
            return cls()
        z = t.column("panel_misfit_z").to_numpy(zero_copy_only=False).astype(float)
        size = t.column("panel_misfit_per_mm").to_numpy(zero_copy_only=False).astype(float)
        f = np.isfinite(z)
        off = f & (np.abs(np.nan_to_num(z)) > OFF_CAD_SIGMAS)
        if not off.any():
            return cls(int(f.sum()))
        i = int(np.flatnonzero(off)[np.argmax(size[off])])
        return cls(int(f.sum()), int(off.sum()), float(size[off].sum()), float(size[i]),
                   t.column("hole_id")[i].as_py())

    def merged(self, o: "OffCadSums") -> "OffCadSums":
        big = o if o.max_per_mm > self.max_per_mm else self
        return OffCadSums(self.checked + o.checked, self.holes + o.holes, self.sum_per_mm + o.sum_per_mm,
                          big.max_per_mm, big.max_hole)


@dataclass(frozen=True)
class CadSums:
    """With the log's commanded pose: holes checked against the CAD, those off it (``|offset|`` over
    :data:`CAD_OFFSET_MM`), the sums of ``|offset|`` (mm) and of the normal's angle to the CAD's (deg), and the
    largest of each with its hole. The angle counts no hole off its CAD: it holds the robot's own orientation
    error as well, which on the forward simulator's default logs (true angles 0.5-5 deg before the adjustment)
    is every hole's 0.5-5 deg."""

    checked: int = 0
    holes: int = 0
    sum_abs_mm: float = 0.0
    max_mm: float = 0.0
    max_mm_hole: str | None = None
    sum_deg: float = 0.0
    max_deg: float = 0.0
    max_deg_hole: str | None = None

    @classmethod
    def of(cls, t) -> "CadSums":
        """The sums of a batch's results ``t`` (pyarrow.Table; none without ``cad_offset_mm``)."""
        if "cad_offset_mm" not in t.column_names:
            return cls()
        off = t.column("cad_offset_mm").to_numpy(zero_copy_only=False).astype(float)
        ang = t.column("normal_vs_cad_deg").to_numpy(zero_copy_only=False).astype(float)
        f = np.isfinite(off) & np.isfinite(ang)
        if not f.any():
            return cls()
        i = int(np.flatnonzero(f)[np.argmax(np.abs(off[f]))])
        j = int(np.flatnonzero(f)[np.argmax(ang[f])])
        hole = t.column("hole_id")
        return cls(int(f.sum()), int((f & (np.abs(np.nan_to_num(off)) > CAD_OFFSET_MM)).sum()),
                   float(np.abs(off[f]).sum()), float(off[i]), hole[i].as_py(), float(ang[f].sum()), float(ang[j]),
                   hole[j].as_py())

    def merged(self, o: "CadSums") -> "CadSums":
        mm = o if abs(o.max_mm) > abs(self.max_mm) else self
        deg = o if o.max_deg > self.max_deg else self
        return CadSums(self.checked + o.checked, self.holes + o.holes, self.sum_abs_mm + o.sum_abs_mm, mm.max_mm,
                       mm.max_mm_hole, self.sum_deg + o.sum_deg, deg.max_deg, deg.max_deg_hole)
