"""The typed results of a diagnosis: outcome and confidence, each cause named, its size, its rivals.

Text is made from these once, at the edge (:func:`metrology.diagnosis.decide.verdict_summary`, the report), and
JSON by ``to_dict`` (the ``--json`` schema: every key as before; ``rivals`` and ``at`` appear only
where there is one).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

# The annotations name types of modules that import this one, so they are not imported here (an
# import cycle; annotations stay strings, ``from __future__ import annotations``): ``Fit``
# (diagnosis/fit), ``Covariates`` (core/effects), ``CandidateResult`` (diagnosis/candidates),
# ``NoiseTests`` and ``Trend`` (diagnosis/stats), ``DatumFormCheck`` and ``DatumPlaneCheck``
# (diagnosis/datum), ``Detectable`` (diagnosis/detectable), ``Empirical`` (diagnosis/search).

__all__ = ["Outcome", "Confidence", "Decision", "Reason", "Param", "Size", "Rival", "Cause", "Confounding", "Discrepancy",
           "HeldOutFigures", "StepFigures", "Diagnosis", "PlotData"]


class Outcome(StrEnum):
    """What a diagnosis concludes: a cause named (``cause`` then says which), nothing above the
    detectable sizes, or residuals no catalogued cause explains."""

    NAMED = "named"
    NONE = "none"
    UNEXPLAINED = "unexplained"


class Confidence(StrEnum):
    """How firmly the verdict stands (see docs/diagnose.md, "reading a verdict")."""

    HIGH = "high"
    MODERATE = "moderate"
    AMBIGUOUS = "ambiguous"
    PARTIAL = "partial"
    LOW = "low"


class Decision(StrEnum):
    """What a rule of :mod:`metrology.diagnosis.rules` decided when it fired (a :class:`Reason`)."""

    CHOSEN = "chosen"  # 2-3: a step took the significant candidate with the largest held-out gain
    MEMBER = "member"  # 3, 5: another member of the family was taken (better held out, or explains its sensors)
    IMITATION = "imitation"  # 4: a per-pose cause set aside for a fixed one that predicts as well
    NOTHING_SIGNIFICANT = "nothing significant"  # 2: no candidate passes both tests: the selection stops
    LEAD = "lead"  # 2: a candidate fits in sample only
    MAX_CAUSES = "max causes"  # 7: the selection stops at MAX_CAUSES
    FIXED_SELECTION = "fixed selection"  # 8: the selection without per-pose causes is taken
    PER_POSE_SELECTION = "per-pose selection"  # 8: the per-pose selection predicts significantly better: kept
    NEEDED = "needed"  # 10: held-out gain given the others significant (or exempt)
    NOT_NEEDED = "not needed"  # 10: not significant: not named
    DROPPED = "dropped"  # 10: the sole cause chosen is not needed against the base model: nothing named
    EXPLAINS = "explains its sensors"  # 11: the joint model leaves its sensors' residuals noise
    NOT_EXPLAINED = "does not explain its sensors"  # 11: not named
    CROSSTALK_BETTER = "crosstalk better"  # 12: another sensor's distance predicts better: not named
    CROSSTALK_TIE = "crosstalk tie"  # 12: crosstalk predicts as well: named, its rival said
    RANDOM_POSE = "random pose error"  # 13: a random pose error explains the structure left
    WEAK = "weak evidence"  # 14: named, held-out p not below ALPHA_HIGH
    CONFOUNDED = "confounded"  # 15: a runner-up or a base parameter the data cannot separate
    CONFIDENCE = "confidence"  # 16: the verdict's confidence
    DATUM_DISAGREES = "datum disagrees"  # 17: the datum cloud's form disagrees with the readings'
    DATUM_PLANE_OFF = "datum plane off"  # 18: the plane the readings place is off its scan's beyond its covariance
    EMPIRICAL = "empirical term"  # 20-21: a term of the open search predicts held-out poses better: taken
    EMPIRICAL_NOT_HELD = "not held out"  # 20-21: passes in sample, does not predict held-out poses better
    EMPIRICAL_BETTER = "empirical better"  # 22: a term of the vocabulary predicts a named cause's residual better
    EMPIRICAL_TIE = "empirical tie"  # 22: a term predicts it better, not significantly: named, ambiguous


@dataclass(frozen=True)
class Reason:
    """One rule that fired, recorded where the engine decided (the verdict's trail, in order).

    rule : int, its number in :mod:`metrology.diagnosis.rules`; name : str, the rule's function
    there; decided : Decision; concerns : tuple of str, the candidates' labels it concerned (the
    first the one decided on); statistic : str, what was held against the threshold; value :
    float or None, its value; threshold : float or None, the level (the rule's constant, split
    where the rule splits it); gain : float or None, the held-out chi-square gain weighed;
    step : int or None, the selection step (from 1); outcome : str or None, what it gave (a
    confidence, a rival's label).
    """

    rule: int
    name: str
    decided: Decision
    concerns: tuple = ()
    statistic: str = ""
    value: float | None = None
    threshold: float | None = None
    gain: float | None = None
    step: int | None = None
    outcome: str | None = None

    def to_dict(self) -> dict:
        return {"rule": self.rule, "name": self.name, "decided": str(self.decided), "concerns": list(self.concerns),
                "statistic": self.statistic, "value": _num(self.value), "threshold": _num(self.threshold),
                "gain": _num(self.gain), "step": self.step,
                "outcome": None if self.outcome is None else str(self.outcome)}


def _num(x):
    return None if x is None else float(x)


@dataclass(frozen=True)
class Param:
    """One parameter of a component as fitted (a component's ``describe()["params"]`` entry).

    value : float, in ``unit``; unit : str; stderr : float or None (None: the component was not
    fitted with a covariance)."""

    value: float
    unit: str
    stderr: float | None = None

    @classmethod
    def from_dict(cls, d: dict) -> "Param":
        """From a ``describe()["params"]`` entry (``value``, ``unit``, and ``stderr`` where it has one)."""
        return cls(d["value"], d["unit"], d.get("stderr"))

    def to_dict(self) -> dict:
        return {"value": self.value, "unit": self.unit, "stderr": self.stderr}


@dataclass(frozen=True)
class Size:
    """A cause's size in its family's unit.

    value : float; stderr : float or None (the fit's, plus the family members' spread where
    there is one); unit : str; meaning : str; stderr_fit, model_spread : float or None (the two
    parts of ``stderr``, where the spread was added)."""

    value: float
    stderr: float | None
    unit: str
    meaning: str
    stderr_fit: float | None = None
    model_spread: float | None = None

    def to_dict(self) -> dict:
        out = {"value": self.value, "stderr": self.stderr, "unit": self.unit, "meaning": self.meaning}
        if self.stderr_fit is not None or self.model_spread is not None:
            out.update(stderr_fit=self.stderr_fit, model_spread=self.model_spread)
        return out


@dataclass(frozen=True)
class Rival:
    """An explanation outside the catalogue that predicts held-out poses as well as a cause, or
    better (crosstalk: a shift in proportion to another sensor's distance).

    label : str, the rival term (``crosstalk.L2<-L1``); family : str; of : str, the label of the
    catalogued cause it rivals; better : bool, it predicts significantly better (the cause is then
    not named) rather than as well (the cause is named, confidence ``ambiguous``); p : float or
    None, the p-value of "better" (None for a tie); separate : str, the command that designs poses
    telling them apart.
    """

    label: str
    family: str
    of: str
    better: bool
    p: float | None
    separate: str

    def to_dict(self) -> dict:
        return {"label": self.label, "family": self.family, "of": self.of, "better": self.better, "p": self.p,
                "separate": self.separate}


#: the keys of a cause's description that :class:`Cause` holds as typed attributes
_TYPED = ("label", "cause", "sensors", "size", "heldout_gain_chi2", "p_heldout_given_others", "p_insample", "step",
          "test", "params", "rivals")


@dataclass(frozen=True)
class Cause:
    """One cause named.

    label : str, the member (``drift.L2@temp``); cause : str, its family (a catalogue name);
    sensors : list of str (empty for a cause of the set-up); size : Size or None;
    heldout_gain_chi2 : float, its held-out chi-square gain given the other causes;
    p_heldout_given_others : float or None (None: a cause with no held-out test, the random pose
    error); p_insample : float; step : int, the selection step that chose it; test : str or None,
    the test that named it where that is not the held-out one; params : dict of str to Param, its
    parameters by name; rivals : tuple of Rival it cannot be told from;
    detail : dict, the rest of its description (component, reference, located pose, pose-error
    figures...), JSON-ready, in the order ``to_dict`` writes it (the typed keys there as None,
    holding their place: their values are the attributes).
    """

    label: str
    cause: str
    sensors: list
    size: Size | None
    heldout_gain_chi2: float
    p_heldout_given_others: float | None
    p_insample: float
    step: int
    test: str | None = None
    params: dict[str, Param] = field(default_factory=dict)
    rivals: tuple = ()
    detail: dict = field(default_factory=dict)

    @classmethod
    def from_description(cls, d: dict, rivals=()) -> "Cause":
        """A cause from its description (a component's ``describe()`` with the verdict's figures; its
        ``size`` a :class:`Size` or None)."""
        return cls(d["label"], d["cause"], list(d["sensors"]), d.get("size"), d["heldout_gain_chi2"],
                   d.get("p_heldout_given_others"), d["p_insample"], d["step"], d.get("test"),
                   {k: v if isinstance(v, Param) else Param.from_dict(v) for k, v in d.get("params", {}).items()},
                   tuple(rivals), {k: None if k in _TYPED else v for k, v in d.items()})

    def to_dict(self) -> dict:
        out = dict(self.detail)
        out.update(label=self.label, cause=self.cause, sensors=list(self.sensors),
                   size=None if self.size is None else self.size.to_dict(), heldout_gain_chi2=self.heldout_gain_chi2,
                   p_heldout_given_others=self.p_heldout_given_others, p_insample=self.p_insample, step=self.step,
                   params={k: v.to_dict() for k, v in self.params.items()})
        if self.test is not None:
            out["test"] = self.test
        if self.rivals:
            out["rivals"] = [r.to_dict() for r in self.rivals]
        return out


@dataclass(frozen=True)
class Confounding:
    """Two things the data cannot separate (rule 15, or a crosstalk tie of rule 12).

    between : tuple of str, the two (candidates' labels; or a parameter ``label.name`` and the
    base parameter it is correlated with); message : str, what to do about it;
    p_separation : float or None, the p-value of one predicting held-out poses better than the
    other (None for a crosstalk tie, tested the other way); correlation : float or None, the
    parameter's largest absolute correlation with the base geometry (unitless; set for a
    poorly separated parameter, then ``p_separation`` is not reported)."""

    between: tuple
    message: str
    p_separation: float | None = None
    correlation: float | None = None

    def to_dict(self) -> dict:
        figure = {"p_separation": self.p_separation} if self.correlation is None else {"correlation": self.correlation}
        return {"between": list(self.between), **figure, "message": self.message}


@dataclass(frozen=True)
class Discrepancy:
    """The measurement beside its simulation under the base model, and under the extended one
    where a cause is named (:func:`metrology.diagnosis.decide.side_by_side`).

    sensors : list of str; stated_noise_mm : list of float, mm, per sensor;
    measured_residual_rms_mm, simulated_base_residual_rms_mm : list of float, mm, per sensor, in sample;
    measured_heldout_normal_rad : float, rad, the base model's mean held-out normal deviation;
    simulated_base_heldout_normal_rad, simulated_base_heldout_normal_sd_rad : float, rad, its mean
    and standard deviation over the simulated copies; sim_reps : int, copies per figure;
    extended_model : str or None, the label of the extended model simulated (None: none named,
    and the three figures below None too); simulated_extended_residual_rms_mm : list of float, mm;
    simulated_extended_heldout_normal_rad, simulated_extended_heldout_normal_sd_rad : float, rad.
    ``to_dict`` gives the angles in degrees (``_deg``), as ``--json`` has them.
    """

    sensors: list
    stated_noise_mm: list
    measured_residual_rms_mm: list
    simulated_base_residual_rms_mm: list
    measured_heldout_normal_rad: float
    simulated_base_heldout_normal_rad: float
    simulated_base_heldout_normal_sd_rad: float
    sim_reps: int
    extended_model: str | None = None
    simulated_extended_residual_rms_mm: list | None = None
    simulated_extended_heldout_normal_rad: float | None = None
    simulated_extended_heldout_normal_sd_rad: float | None = None

    def to_dict(self) -> dict:
        out = {"sensors": self.sensors, "stated_noise_mm": self.stated_noise_mm,
               "measured_residual_rms_mm": self.measured_residual_rms_mm,
               "simulated_base_residual_rms_mm": self.simulated_base_residual_rms_mm,
               "measured_heldout_normal_deg": _deg(self.measured_heldout_normal_rad),
               "simulated_base_heldout_normal_deg": _deg(self.simulated_base_heldout_normal_rad),
               "simulated_base_heldout_normal_sd_deg": _deg(self.simulated_base_heldout_normal_sd_rad),
               "sim_reps": self.sim_reps}
        if self.extended_model is not None:
            out.update(simulated_extended_residual_rms_mm=self.simulated_extended_residual_rms_mm,
                       simulated_extended_heldout_normal_deg=_deg(self.simulated_extended_heldout_normal_rad),
                       simulated_extended_heldout_normal_sd_deg=_deg(self.simulated_extended_heldout_normal_sd_rad),
                       extended_model=self.extended_model)
        return out


@dataclass(frozen=True)
class HeldOutFigures:
    """The k-fold-by-pose held-out figures of the base model, and of the model the verdict judges
    where a cause is named (:func:`metrology.diagnosis.decide.side_by_side`).

    folds : int, k; base_rms_mm : float, mm, the base model's held-out residual RMS (where a model
    is named, without the readings a named outliers cause flags gross); base_normal_rad : float,
    rad, its mean held-out normal deviation; model : str or None, the label of the model judged
    (None: nothing named, and the figures below None too); extended_rms_mm : float, mm;
    rms_ratio : float, base over extended; base_rms_concerned_mm, extended_rms_concerned_mm,
    rms_ratio_concerned : the same on the named causes' sensors; extended_normal_rad : float, rad;
    normal_ratio : float, base over extended mean normal deviation; p_heldout : float, the
    model's held-out test (its selection step's). ``to_dict`` gives the angles in degrees (``_deg``).
    """

    folds: int
    base_rms_mm: float
    base_normal_rad: float
    model: str | None = None
    extended_rms_mm: float | None = None
    rms_ratio: float | None = None
    base_rms_concerned_mm: float | None = None
    extended_rms_concerned_mm: float | None = None
    rms_ratio_concerned: float | None = None
    extended_normal_rad: float | None = None
    normal_ratio: float | None = None
    p_heldout: float | None = None

    def to_dict(self) -> dict:
        out = {"folds": self.folds, "base_rms_mm": self.base_rms_mm, "base_normal_deg": _deg(self.base_normal_rad)}
        if self.model is not None:
            out.update(model=self.model, extended_rms_mm=self.extended_rms_mm, rms_ratio=self.rms_ratio,
                       base_rms_concerned_mm=self.base_rms_concerned_mm,
                       extended_rms_concerned_mm=self.extended_rms_concerned_mm,
                       rms_ratio_concerned=self.rms_ratio_concerned, extended_normal_deg=_deg(self.extended_normal_rad),
                       normal_ratio=self.normal_ratio, p_heldout=self.p_heldout)
        return out


def _deg(rad: float) -> float:
    """Degrees at the JSON edge."""
    return float(np.rad2deg(rad))


@dataclass(frozen=True)
class StepFigures:
    """The residuals after one step of the selection (:func:`metrology.diagnosis.decide.diagnose`'s ``steps``).

    added : str or None, the label of the cause the step added (None: the base model, the first
    row); model : str, ``base + ...``; residual_rms_mm : list of float, mm, per sensor, in sample;
    heldout_rms_mm : float, mm, held out; p_heldout : float or None, the cause's held-out test at
    its step; heldout_gain_chi2 : float or None, its held-out chi-square gain there; named : bool
    or None, whether the verdict names it (a step's cause can be turned down after the selection).
    """

    added: str | None
    model: str
    residual_rms_mm: list
    heldout_rms_mm: float
    p_heldout: float | None = None
    heldout_gain_chi2: float | None = None
    named: bool | None = None

    def to_dict(self) -> dict:
        out = {"added": self.added, "model": self.model, "residual_rms_mm": self.residual_rms_mm,
               "heldout_rms_mm": self.heldout_rms_mm}
        if self.added is not None:
            out.update(p_heldout=self.p_heldout, heldout_gain_chi2=self.heldout_gain_chi2, named=self.named)
        return out


@dataclass(frozen=True)
class PlotData:
    """What the residual plots of :func:`metrology.report.diagnose.plot_report` draw.

    base : Fit; cov : Covariates; d0 : (p, n) float, mm, the base readings; best : the named
    (or partial) CandidateResult or None; names : tuple of str; sigma : (n,) float, mm;
    flags : (p, n) bool, flagged readings; structure : dict, the base structure table (covariate
    -> sensor name -> :class:`~metrology.diagnosis.stats.Trend`);
    heldout_base : (p, n) float, mm, or None, the base model's k-fold held-out residuals;
    heldout_after : (p, n) float, mm, or None, those of the model the ``heldout`` figures of
    :class:`Diagnosis` judge (base + the causes named; None when nothing is named). In both, a
    reading flagged gross by a named outliers cause is NaN, as it is left out of those figures.
    """

    base: Fit
    cov: Covariates
    d0: np.ndarray
    best: CandidateResult | None
    names: tuple
    sigma: np.ndarray
    flags: np.ndarray
    structure: dict[str, dict[str, Trend]]
    heldout_base: np.ndarray | None = None
    heldout_after: np.ndarray | None = None


@dataclass(frozen=True)
class Diagnosis:
    """Result of :func:`diagnose`; :meth:`to_dict` is the ``--json`` output.

    ``cause`` the first cause's family, or ``none``/``unexplained`` (:attr:`outcome`);
    ``confidence`` a :class:`~metrology.diagnosis.results.Confidence`; ``named`` the first
    :class:`~metrology.diagnosis.results.Cause` (or None);
    ``causes`` every cause named (forward selection, :mod:`metrology.diagnosis.select`), each
    a :class:`~metrology.diagnosis.results.Cause` with its parameters and standard errors, its
    size in the family's unit where one is defined, its held-out gain given the others and any
    rival outside the catalogue it cannot be told from, largest gain first (``cause`` is the first);
    ``steps`` the residuals after each step of the selection (:class:`StepFigures`); ``discrepancy``
    the measurement beside its simulation (:class:`Discrepancy`); ``heldout`` the held-out figures
    (:class:`HeldOutFigures`); ``confounding`` what the data cannot separate (:class:`Confounding`);
    ``candidates`` are the candidates scored at the first step, largest held-out gain first; ``tests_base`` and
    ``tests_extended`` the noise-model battery before and after the extension;
    ``datum_form`` the datum check (None without a datum cloud); ``plot_data`` what the plots draw;
    ``detectable`` the size of each family these poses detect at 95 % power (family ->
    :class:`~metrology.diagnosis.detectable.Detectable`); ``reasons`` the rules that made the verdict, in the
    order they fired (:class:`Reason`; the summary is made from them).
    """

    cause: str
    sensors: list
    confidence: Confidence
    summary: str
    named: Cause | None
    candidates: tuple
    tests_base: NoiseTests
    tests_extended: NoiseTests | None
    structure_base: dict[str, dict[str, Trend]]
    discrepancy: Discrepancy
    heldout: HeldOutFigures
    confounding: list[Confounding]
    base_theta: np.ndarray
    base_stderr: np.ndarray
    thresholds: dict
    datum_form: DatumFormCheck | None = None
    plot_data: PlotData | None = None
    causes: tuple = ()
    steps: tuple = ()
    detectable: dict[str, Detectable] = field(default_factory=dict)
    reasons: tuple = ()
    #: the datum plane estimated with the sensors under its scan's covariance
    #: (:class:`metrology.diagnosis.datum.DatumPlaneCheck`), None when not run
    datum_plane: DatumPlaneCheck | None = None
    #: the open search's terms where the catalogue does not explain
    #: (:class:`metrology.diagnosis.search.Empirical`), None where not searched
    empirical: Empirical | None = None

    def __post_init__(self):
        object.__setattr__(self, "confidence", Confidence(self.confidence))

    @property
    def outcome(self) -> Outcome:
        """A cause named, or none, or unexplained."""
        return Outcome(self.cause) if self.cause in (Outcome.NONE, Outcome.UNEXPLAINED) else Outcome.NAMED

    def to_dict(self):
        return {
            "cause": self.cause, "sensors": self.sensors, "confidence": self.confidence, "summary": self.summary,
            "causes": [c.to_dict() for c in self.causes], "steps": [st.to_dict() for st in self.steps],
            "extended": None if self.named is None else self.named.to_dict(), "heldout": self.heldout.to_dict(),
            "discrepancy": self.discrepancy.to_dict(),
            "candidates": [c.to_dict() for c in self.candidates], "confounding": [c.to_dict() for c in self.confounding],
            "tests": {"base": self.tests_base.to_dict(),
                      "extended": None if self.tests_extended is None else self.tests_extended.to_dict()},
            "structure": {key: {name: t.to_dict() for name, t in row.items()} for key, row in self.structure_base.items()},
            "base": {"theta": self.base_theta.tolist(), "stderr": self.base_stderr.tolist(),
                     "columns": ["dx_mm", "dy_mm", "dz_mm", "a_rad", "b_rad"]},
            "thresholds": self.thresholds,
            "datum_form": None if self.datum_form is None else self.datum_form.to_dict(),
            "detectable": {family: d.to_dict() for family, d in self.detectable.items()},
            "reasons": [r.to_dict() for r in self.reasons],
            "datum_plane": None if self.datum_plane is None else self.datum_plane.to_dict(),
            "empirical": None if self.empirical is None else self.empirical.to_dict(),
        }
