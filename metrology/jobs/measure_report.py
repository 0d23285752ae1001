"""What ``metro measure`` found: :class:`MeasureReport`, the typed result the report, the JSON and the
exit code are made from (``metrology.jobs.measure`` builds it)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from metrology.core.verdict import Check, Verdict

if TYPE_CHECKING:
    from metrology.measure.run import MeasureResult

__all__ = ["MeasureReport", "SCHEMA"]

SCHEMA = "metro.measure/1"


@dataclass(frozen=True)
class MeasureReport:
    """What ``metro measure`` found (its JSON is :meth:`to_dict`).

    Attributes
    ----------
    result : MeasureResult, the holes measured: summary, drift watch, counts
    sources : dict, role -> display name (log, layout, out, qif)
    tolerance_deg : float, deg; min_radius_mm : float, mm
    layout_names : tuple of str
    has_covariance : bool, the layout carried the calibration's covariance (propagated)
    engine : str, "one process" or the Dask cluster used
    warnings : tuple of str
    fail_on_drift : bool, whether a drift alarm fails the verdict
    chart : dict, the drift chart's settings (:func:`metrology.measure.chart.chart_settings`, by_panel)
    curvature : dict, where each hole's curvature came from ({} : the assumed bound)
    effects : tuple of str, the layout's head terms applied to every hole (their covariance in U95)
    panel_map : PanelMap or None, the hole table's holes as judged (:mod:`metrology.report.panel_map`),
        with ``--points`` and ``--report``
    """

    result: "MeasureResult"
    sources: dict
    tolerance_deg: float
    min_radius_mm: float
    layout_names: tuple
    has_covariance: bool
    engine: str
    warnings: tuple = ()
    fail_on_drift: bool = False
    chart: dict = field(default_factory=dict)
    curvature: dict = field(default_factory=dict)
    effects: tuple = ()
    panel_map: object = None

    @property
    def counts(self) -> dict:
        return self.result.summary.counts()

    @property
    def verdict(self) -> Verdict:
        c = self.counts
        # an alarm whose change persisted asks for a recalibration (gated by --fail-on-drift); one whose
        # run did not persist (chart.PERSIST_Z: a false alarm or a transient knock) is shown, never gated
        alarms = sum(1 for a in self.result.alarms if a.persisted)
        transient = len(self.result.alarms) - alarms
        checks = [Check("drilling tolerance: holes that fail", c["fails"], 0, "holes", c["fails"] == 0),
                  Check("drilling tolerance: holes undecided (U95 straddles the tolerance)", c["undecided"], 0,
                        "holes", c["undecided"] == 0),
                  Check("drilling tolerance: holes whose drilled angle is not known (not measured after the adjustment, "
                        "the readings before it not sound: re-inspect)", self.result.summary.unknown_after, 0, "holes",
                        self.result.summary.unknown_after == 0),
                  Check("measurement: holes not measured", c["not_measured"], None, "holes", True, gate=False),
                  Check("drift watch: alarms whose change persisted (recalibrate)", alarms, 0, "alarms", alarms == 0,
                        gate=self.fail_on_drift),
                  Check("drift watch: alarms whose run did not persist (check the head)", transient, None, "alarms",
                        True, gate=False)]
        cv = self.curvature or {"assumed": True}
        if cv.get("assumed"):  # no panel known: the bound is an assumption, named
            checks.append(Check(f"curvature ASSUMED (no --panel/--points): every panel's radius >= "
                                f"{self.min_radius_mm:g} mm", self.min_radius_mm, None, "mm", True, gate=False))
        elif cv:
            checks.append(Check(f"curvature from {cv['source']}", cv.get("holes", 0), None, "holes", True, gate=False))
            if cv.get("spin_on_convention_holes") or cv.get("spin_free_holes"):
                checks.append(Check(f"head's spin (no pose in the log): holes judged with it in the cell's convention "
                                    f"(+-{cv['spin_deg']:g} deg{'' if cv['spin_stated'] else ', confirmed by the redundant reading'}; "
                                    f"log the commanded pose to know it)", cv["spin_on_convention_holes"], None, "holes",
                                    True, gate=False))
                checks.append(Check("head's spin not known: holes judged with a U95 over every spin",
                                    cv["spin_free_holes"], None, "holes", True, gate=False))
            if cv.get("off_cad_holes"):
                checks.append(Check(f"panel off its CAD: holes whose redundant reading sees the surface's shape off the "
                                    f"CAD's (|z| > {cv['off_cad_sigmas']:g}; mean size "
                                    f"{cv['off_cad_mean_per_mm']:.2g} 1/mm)", cv["off_cad_holes"], None, "holes", True,
                                    gate=False))
            if cv.get("cad_checked"):
                checks.append(Check(f"panel against its CAD (the log's commanded pose): holes off it (|offset| > "
                                    f"{cv['cad_offset_limit_mm']:g} mm; mean |offset| {cv['cad_offset_mean_abs_mm']:.3f} mm, "
                                    f"largest {cv['cad_offset_max_mm']:+.3f} mm at {cv['cad_offset_max_hole']}; the "
                                    f"measured normal against the CAD's, with the robot's own orientation error: mean "
                                    f"{cv['normal_vs_cad_mean_deg']:.3f} deg, largest {cv['normal_vs_cad_max_deg']:.3f} "
                                    f"deg at {cv['normal_vs_cad_max_hole']})",
                                    cv["cad_off_holes"], None, "holes", True, gate=False))
        return Verdict(tuple(checks))

    def to_dict(self) -> dict:
        s = self.result.summary
        groups = [{"cell": cell, "panel": panel, "day": day, "counts": s.counts(grp), **s.figures(grp)}
                  for (cell, panel, day), grp in sorted(s.groups.items())]
        series = [{"cell": cell, "counts": s.counts(grp), **s.figures(grp)} for cell, grp in sorted(s.series.items())]
        return {
            "schema": SCHEMA,
            "sources": dict(self.sources),
            "sensors": list(self.layout_names),
            "tolerance_deg": self.tolerance_deg,
            "decision_rule": "ISO 14253-1: conforms if angle + U95 <= tolerance, fails if angle - U95 > tolerance",
            "judged": {"after_adjustment": s.judged_after, "before_adjustment": s.judged_before},
            "uncertainty": {"reading_noise": True, "calibration_covariance": self.has_covariance, "coverage": 0.95,
                            "effect_terms": list(self.effects)},
            "min_radius_mm": self.min_radius_mm,
            "curvature": dict(self.curvature) if self.curvature else {"assumed": True, "source": (
                f"bound: every panel's radius >= {self.min_radius_mm:g} mm (an assumption: no --panel or --points)")},
            "engine": self.engine,
            "holes": self.result.rows,
            "partitions": self.result.partitions,
            "partitions_written": self.result.written,
            "counts": self.counts,
            "counts_detail": {"unknown_after": s.unknown_after},
            "fleet": s.figures(s.total()),
            "cells": series,
            "groups": groups,
            "drift": {"chart": dict(self.chart), "cells_charted": sorted(self.result.watch.charts),
                      "alarms": [a.to_dict() for a in self.result.alarms]},
            "worst": list(s.worst),
            "warnings": list(self.warnings),
            "verdict": self.verdict.to_dict(),
        }
