"""What ``metro measure`` found: :class:`MeasureReport`, the typed result the report, the JSON and the
exit code are made from (``metrology.jobs.measure`` builds it)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

from metrology.core.verdict import Check, Verdict

#: a log in which more than this share of holes have readings that disagree does not fit the layout (the run is
#: refused: :func:`metrology.jobs.measure._check_fit`); without the panel, more than this share of holes judged by
#: rule 2b names the layout beside the curvature (a curved panel within the bound and a layout not this head's
#: calibration both give most holes such a misfit; only the panel tells them apart)
MISFIT_SHARE = 0.5

if TYPE_CHECKING:
    from metrology.measure.run import MeasureResult
    from metrology.measure.tally import Counts

__all__ = ["MeasureReport", "Sources", "ChartSettings", "RadiusBound", "KnownSurfaces", "OffCad", "CadCheck", "SCHEMA"]

SCHEMA = "metro.measure/1"


@dataclass(frozen=True)
class Sources:
    """The run's files as the report names them (display names).

    Attributes
    ----------
    log, layout : str; out : str or None, the results (``--out``); qif : str or None, the QIF document
    """

    log: str
    layout: str
    out: str | None = None
    qif: str | None = None

    def to_dict(self) -> dict:
        return {"log": self.log, "layout": self.layout, "out": self.out,
                **({} if self.qif is None else {"qif": self.qif})}


@dataclass(frozen=True)
class ChartSettings:
    """The drift chart's settings (:func:`metrology.measure.chart.chart_settings`): ``k`` and ``h`` (scales), the
    in-control ARL and the ARL at the detectable shift (holes), the baseline's holes, and whether each panel
    takes a new baseline (``by_panel``)."""

    k: float
    h: float
    arl0_holes: float
    baseline_holes: int
    detectable_scales: float
    arl_at_detectable_holes: float
    by_panel: bool = False

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class RadiusBound:
    """No panel known: each hole's curvature bounded by the panel's smallest radius.

    Attributes
    ----------
    radius_mm : float, mm
    stated_in : str or None, the layout whose ``[panel] radius_mm`` states it; None: assumed (the default
        or ``--min-radius-mm``)
    one_sensor_holes : int, holes judged with rule 2b's U95: a 4-sensor misfit beyond the noise within the bound,
        which one sensor's offset gives as well as the curvature (:data:`metrology.measure.rules.EDGE_SIGMAS`)
    """

    radius_mm: float
    stated_in: str | None = None
    one_sensor_holes: int = 0

    #: each hole's surface is not known, only bounded
    known = False

    @property
    def assumed(self) -> bool:
        return self.stated_in is None

    @property
    def source(self) -> str:
        return (f"bound: every panel's radius >= {self.radius_mm:g} mm (an assumption: no --panel or --points)"
                if self.assumed else
                f"bound: the cell's panel radius {self.radius_mm:g} mm stated in {self.stated_in} [panel] radius_mm")

    def to_dict(self) -> dict:
        bound = ({"assumed": True, "source": self.source} if self.assumed else
                 {"assumed": False, "source": self.source, "radius_mm": self.radius_mm})
        return {**bound, "one_sensor_offset_holes": self.one_sensor_holes}


@dataclass(frozen=True)
class OffCad:
    """The panel off its CAD (:meth:`metrology.measure.summary.FleetSummary.off_cad_figures`): holes checked (4
    sensors) and off (``|z|`` over ``off_cad_sigmas``), their mean and largest size (1/mm) and its hole."""

    off_cad_sigmas: float
    off_cad_checked: int
    off_cad_holes: int
    off_cad_mean_per_mm: float
    off_cad_max_per_mm: float
    off_cad_max_hole: str | None

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class CadCheck:
    """The panel against its CAD under the log's commanded pose
    (:meth:`metrology.measure.summary.FleetSummary.vs_cad_figures`): holes checked and off (``|offset|`` over
    ``cad_offset_limit_mm``), the offsets (mm) and the normal's angle to the CAD's (deg), with their holes."""

    cad_checked: int
    cad_off_holes: int
    cad_offset_limit_mm: float
    cad_offset_mean_abs_mm: float
    cad_offset_max_mm: float
    cad_offset_max_hole: str | None
    normal_vs_cad_mean_deg: float
    normal_vs_cad_max_deg: float
    normal_vs_cad_max_hole: str | None

    def to_dict(self) -> dict:
        return asdict(self)


#: how the head's spin is taken where the log has no pose (the cell's convention)
SPIN_CONVENTION = ("TCS x, y near the panel's x, y (tcs2panel = Q(-e_z -> -n) diag(1, -s, -s)); the spin beyond it "
                   "within +-spin_deg, uniform, in U95")


@dataclass(frozen=True)
class KnownSurfaces:
    """Each hole's local surface known (``--panel``/``--points``).

    Attributes
    ----------
    source : str, the CAD panel or hole table; holes : int, the table's holes
    position_error_mm : float, mm, the drill point's position error; form_tolerance_mm : float, mm
    spin_deg : float, deg, the head's spin within +-spin_deg where the log has no pose; spin_stated : bool
    spin_on_convention_holes, spin_free_holes : int, holes judged with the spin in the cell's convention, and
        with a U95 over every spin
    off_cad : OffCad; cad : CadCheck
    spin_bound_holes : int, holes whose readings (before or judged after) rest on the spin's bound, as their reason
        says: the spin not read, its bound over half their U95^2 (their U95 for
        any spin within the bound: ``spin_bound_model`` "edge", :data:`metrology.measure.spin.SPIN_BOUND_MODEL`)
    spin_alias_holes : int, holes whose readings, before the adjustment or the after-readings judged, the
        convention's alias spin sent to every spin, the convention not stated (their reason says so;
        :data:`metrology.measure.spin.SPIN_ALIAS_SHARE`)
    """

    source: str
    holes: int
    position_error_mm: float
    form_tolerance_mm: float
    spin_deg: float
    spin_stated: bool
    spin_on_convention_holes: int
    spin_free_holes: int
    off_cad: OffCad
    cad: CadCheck
    spin_bound_holes: int = 0
    spin_alias_holes: int = 0

    #: each hole's surface known; the bound is not assumed
    known, assumed = True, False

    def to_dict(self) -> dict:
        from metrology.measure.spin import SPIN_BOUND_MODEL

        return {"assumed": False, "source": self.source, "holes": self.holes,
                "position_error_mm": self.position_error_mm, "form_tolerance_mm": self.form_tolerance_mm,
                "spin_deg": self.spin_deg, "spin_stated": self.spin_stated, "spin_convention": SPIN_CONVENTION,
                "spin_on_convention_holes": self.spin_on_convention_holes, "spin_free_holes": self.spin_free_holes,
                "spin_alias_holes": self.spin_alias_holes,
                "spin_bound_holes": self.spin_bound_holes, "spin_bound_model": SPIN_BOUND_MODEL.value,
                **self.off_cad.to_dict(), **self.cad.to_dict()}


@dataclass(frozen=True)
class MeasureReport:
    """What ``metro measure`` found (its JSON is :meth:`to_dict`).

    Attributes
    ----------
    result : MeasureResult, the holes measured: summary, drift watch, counts
    sources : Sources, the files' display names
    tolerance_deg : float, deg; min_radius_mm : float, mm
    layout_names : tuple of str
    has_covariance : bool, the layout carried the calibration's covariance (propagated)
    engine : str, "one process" or the Dask cluster used
    warnings : tuple of str
    fail_on_drift : bool, whether a drift alarm fails the verdict
    chart : ChartSettings, the drift chart's settings
    curvature : RadiusBound or KnownSurfaces, where each hole's curvature came from
    effects : tuple of str, the layout's head terms applied to every hole (their covariance in U95)
    panel_map : PanelMap or None, the hole table's holes as judged (:mod:`metrology.report.panel_map`),
        with ``--points`` and ``--report``
    """

    result: "MeasureResult"
    sources: Sources
    tolerance_deg: float
    min_radius_mm: float
    layout_names: tuple
    has_covariance: bool
    engine: str
    warnings: tuple
    fail_on_drift: bool
    chart: ChartSettings
    curvature: "RadiusBound | KnownSurfaces"
    effects: tuple = ()
    panel_map: object = None

    @property
    def counts(self) -> "Counts":
        """Holes by status (:class:`~metrology.measure.tally.Counts`)."""
        return self.result.summary.counts()

    @property
    def verdict(self) -> Verdict:
        c = self.counts
        # an alarm whose change persisted asks for a recalibration (gated by --fail-on-drift); one whose
        # run did not persist (chart.PERSIST_Z: a false alarm or a transient knock) is shown, never gated
        alarms = sum(1 for a in self.result.alarms if a.persisted)
        transient = len(self.result.alarms) - alarms
        checks = [Check("drilling tolerance: holes that fail", c.fails, 0, "holes", c.fails == 0),
                  Check("drilling tolerance: holes undecided (U95 straddles the tolerance)", c.undecided, 0,
                        "holes", c.undecided == 0),
                  Check("drilling tolerance: holes whose drilled angle is not known (not measured after the adjustment, "
                        "the readings before it not sound: re-inspect)", self.result.summary.unknown_after, 0, "holes",
                        self.result.summary.unknown_after == 0),
                  Check("measurement: holes not measured", c.not_measured, None, "holes", True, gate=False),
                  Check("drift watch: alarms whose change persisted (recalibrate)", alarms, 0, "alarms", alarms == 0,
                        gate=self.fail_on_drift),
                  Check("drift watch: alarms whose run did not persist (check the head)", transient, None, "alarms",
                        True, gate=False)]
        cv = self.curvature
        if cv.assumed:  # no panel known: the bound is an assumption, named
            checks.append(Check(f"curvature ASSUMED (no --panel/--points): every panel's radius >= "
                                f"{self.min_radius_mm:g} mm", self.min_radius_mm, None, "mm", True, gate=False))
        elif isinstance(cv, RadiusBound):
            checks.append(Check(f"curvature from {cv.source}", 0, None, "holes", True, gate=False))
        else:
            checks.append(Check(f"curvature from {cv.source}", cv.holes, None, "holes", True, gate=False))
            if cv.spin_on_convention_holes or cv.spin_free_holes:
                unstated = (", not stated: kept only where the redundant reading does not refute it and its alias spin "
                            "tilts the normal alike")
                checks.append(Check(f"head's spin (no pose in the log): holes judged with it in the cell's convention "
                                    f"(+-{cv.spin_deg:g} deg{'' if cv.spin_stated else unstated}; "
                                    f"log the commanded pose to know it)", cv.spin_on_convention_holes, None, "holes",
                                    True, gate=False))
                checks.append(Check("head's spin not read (no redundant reading, or one blind to it): holes whose U95 "
                                    f"rests on the +-{cv.spin_deg:g} deg bound (over half of it; it holds for any spin "
                                    "within the bound, wherever it sits; log the commanded pose)",
                                    cv.spin_bound_holes, None, "holes", True, gate=False))
                why = "" if cv.spin_stated else " (the convention not stated: state --spin-deg or log the commanded pose)"
                checks.append(Check(f"head's spin not known: holes judged with a U95 over every spin{why}",
                                    cv.spin_free_holes, None, "holes", True, gate=False))
                if not cv.spin_stated and len(self.layout_names) == 4:  # the alias rule needs the redundant reading
                    from metrology.measure.spin import SPIN_ALIAS_SHARE

                    checks.append(Check("head's spin alias (the convention not stated): holes whose readings, before "
                                        "the adjustment or those judged, were judged over every spin, the redundant "
                                        "reading unable to tell the convention from a spin that tilts the normal over "
                                        f"{SPIN_ALIAS_SHARE:g} of U95 otherwise (their reason says so)",
                                        cv.spin_alias_holes, None, "holes", True, gate=False))
            o, c = cv.off_cad, cv.cad
            if o.off_cad_holes:
                checks.append(Check(f"panel off its CAD: holes whose redundant reading sees the surface's shape off the "
                                    f"CAD's (|z| > {o.off_cad_sigmas:g}; mean size "
                                    f"{o.off_cad_mean_per_mm:.2g} 1/mm)", o.off_cad_holes, None, "holes", True,
                                    gate=False))
            if c.cad_checked:
                checks.append(Check(f"panel against its CAD (the log's commanded pose): holes off it (|offset| > "
                                    f"{c.cad_offset_limit_mm:g} mm; mean |offset| {c.cad_offset_mean_abs_mm:.3f} mm, "
                                    f"largest {c.cad_offset_max_mm:+.3f} mm at {c.cad_offset_max_hole}; the "
                                    f"measured normal against the CAD's, with the robot's own orientation error: mean "
                                    f"{c.normal_vs_cad_mean_deg:.3f} deg, largest {c.normal_vs_cad_max_deg:.3f} "
                                    f"deg at {c.normal_vs_cad_max_hole})",
                                    c.cad_off_holes, None, "holes", True, gate=False))
        if isinstance(cv, RadiusBound) and len(self.layout_names) == 4 and cv.radius_mm < float("inf"):
            most = cv.one_sensor_holes > MISFIT_SHARE * self.result.rows
            checks.append(Check("one sensor's offset (rule 2b): holes judged with a U95 that covers it, the redundant "
                                "reading's misfit beyond the noise and within the radius bound (a burr under one spot "
                                "gives it as well as the panel's curvature" + (
                                    "; in most holes, a layout that is not this head's calibration (a nominal layout? "
                                    "another head's?) gives it too" if most else "") +
                                "; give --panel/--points to tell them apart)",
                                cv.one_sensor_holes, None, "holes", True, gate=False))
        return Verdict(tuple(checks))

    def to_dict(self) -> dict:
        s = self.result.summary
        groups = [{"cell": key.cell, "panel": key.panel, "day": key.day, "counts": s.counts(grp).to_dict(),
                   **s.figures(grp).to_dict()} for key, grp in sorted(s.groups.items())]
        series = [{"cell": cell, "counts": s.counts(grp).to_dict(), **s.figures(grp).to_dict()}
                  for cell, grp in sorted(s.series.items())]
        return {
            "schema": SCHEMA,
            "sources": self.sources.to_dict(),
            "sensors": list(self.layout_names),
            "tolerance_deg": self.tolerance_deg,
            "decision_rule": "ISO 14253-1: conforms if angle + U95 <= tolerance, fails if angle - U95 > tolerance",
            "judged": {"after_adjustment": s.judged_after, "before_adjustment": s.judged_before},
            "uncertainty": {"reading_noise": True, "calibration_covariance": self.has_covariance, "coverage": 0.95,
                            "effect_terms": list(self.effects)},
            "min_radius_mm": self.min_radius_mm,
            "curvature": self.curvature.to_dict(),
            "engine": self.engine,
            "holes": self.result.rows,
            "partitions": self.result.partitions,
            "partitions_written": self.result.written,
            "counts": self.counts.to_dict(),
            "counts_detail": {"unknown_after": s.unknown_after},
            "fleet": s.figures(s.total()).to_dict(),
            "cells": series,
            "groups": groups,
            "drift": {"chart": self.chart.to_dict(), "cells_charted": sorted(self.result.watch.charts),
                      "alarms": [a.to_dict() for a in self.result.alarms]},
            "worst": [w.to_dict() for w in s.worst],
            "warnings": list(self.warnings),
            "verdict": self.verdict.to_dict(),
        }
