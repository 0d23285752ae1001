"""The decision's thresholds (made in :mod:`metrology.diagnosis.rules`, beside the rules that use
them) and the advice that separates confounded causes."""

from __future__ import annotations

from metrology.core.effects import REGISTRY
from metrology.diagnosis.rules import THRESHOLDS

__all__ = ["THRESHOLDS", "ADVICE"]

#: the poses that separate each cause from the others (read from the effect registry)
ADVICE = {name: cls.advice for name, cls in REGISTRY.items()}
