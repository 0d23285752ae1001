"""A command's verdict as data: named checks against limits, and the exit code they give.

Every command that judges something returns a :class:`Verdict`; ``--json`` carries its
``to_dict()`` under ``"verdict"`` and the CLI exits with :func:`exit_code`:

    0  ran and passed        1  ran and the verdict failed        2  bad input or usage

A :class:`Check` with ``gate=False`` is information (a target the user did not set, a
statistic shown beside the tolerance): it is reported, never failed on.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Check", "Verdict", "EXIT_PASSED", "EXIT_FAILED", "EXIT_BAD_INPUT", "exit_code"]

EXIT_PASSED = 0
EXIT_FAILED = 1
EXIT_BAD_INPUT = 2


@dataclass(frozen=True)
class Check:
    """One judged quantity.

    Attributes
    ----------
    name : str, what is judged (``"holes conforming"``, ``"max normal deviation"``)
    value : float or int, the measured value, in ``unit``
    limit : float or int or None, the limit it is judged against (None: nothing to judge)
    unit : str, the unit of ``value`` and ``limit`` (``"deg"``, ``"mm"``, ``"holes"``, ``""``)
    passed : bool
    gate : bool, whether ``passed`` counts toward the verdict (False: information only)
    at_least : bool, the value must be at least ``limit`` (default: at most), for the words
    """

    name: str
    value: float
    limit: float | None
    unit: str
    passed: bool
    gate: bool = True
    at_least: bool = False

    def to_dict(self) -> dict:
        return {"name": self.name, "value": self.value, "limit": self.limit, "unit": self.unit,
                "passed": bool(self.passed), "gate": bool(self.gate)}


@dataclass(frozen=True)
class Verdict:
    """The checks of one run; it passed when every gating check passed."""

    checks: tuple = ()

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.checks if c.gate)

    def to_dict(self) -> dict:
        return {"passed": self.passed, "checks": [c.to_dict() for c in self.checks]}


def exit_code(verdict: Verdict) -> int:
    """0 when ``verdict`` passed, 1 when it failed (2 is for bad input, raised before a verdict)."""
    return EXIT_PASSED if verdict.passed else EXIT_FAILED
