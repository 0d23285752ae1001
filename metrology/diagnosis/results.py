"""The typed results of a diagnosis: outcome and confidence, each cause named, its size, its rivals.

Text is made from these once, at the edge (:mod:`metrology.diagnosis.summary`, the report), and
JSON by ``to_dict`` (the ``--json`` schema: every key as before; ``rivals`` and ``at`` appear only
where there is one).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

__all__ = ["Outcome", "Confidence", "Size", "Rival", "Cause"]


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

    @classmethod
    def from_dict(cls, d: dict | None) -> "Size | None":
        if d is None:
            return None
        return cls(d["value"], d.get("stderr"), d["unit"], d["meaning"], d.get("stderr_fit"), d.get("model_spread"))

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
    the test that named it where that is not the held-out one; params : dict, its parameters
    (value, unit, stderr); rivals : tuple of Rival it cannot be told from;
    detail : dict, the rest of its description (component, reference, located pose, pose-error
    figures...), JSON-ready, in the order ``to_dict`` writes it.
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
    params: dict = field(default_factory=dict)
    rivals: tuple = ()
    detail: dict = field(default_factory=dict)

    @classmethod
    def from_description(cls, d: dict, rivals=()) -> "Cause":
        """A cause from its description (a component's ``describe()`` with the verdict's figures)."""
        return cls(d["label"], d["cause"], list(d["sensors"]), Size.from_dict(d.get("size")), d["heldout_gain_chi2"],
                   d.get("p_heldout_given_others"), d["p_insample"], d["step"], d.get("test"), d.get("params", {}),
                   tuple(rivals), dict(d))

    def to_dict(self) -> dict:
        out = dict(self.detail)
        out.update(label=self.label, cause=self.cause, sensors=list(self.sensors),
                   size=None if self.size is None else self.size.to_dict(), heldout_gain_chi2=self.heldout_gain_chi2,
                   p_heldout_given_others=self.p_heldout_given_others, p_insample=self.p_insample, step=self.step,
                   params=self.params)
        if self.test is not None:
            out["test"] = self.test
        if self.rivals:
            out["rivals"] = [r.to_dict() for r in self.rivals]
        return out
