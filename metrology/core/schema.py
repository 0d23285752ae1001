"""The ``schema`` tag every JSON output of metro carries: ``"metro.<kind>/<version>"``.

A reader checks the kind and the version before it trusts the keys; a change that breaks
readers bumps the version.
"""

from __future__ import annotations

import re

__all__ = ["SCHEMA_PATTERN", "schema_tag", "tagged"]

#: what every tag matches: ``metro.`` a lower-case kind, ``/`` and an integer version
SCHEMA_PATTERN = re.compile(r"^metro\.[a-z][a-z0-9_-]*/[0-9]+$")


def schema_tag(kind: str, version: int = 1) -> str:
    """``"metro.<kind>/<version>"``, e.g. ``schema_tag("plane") == "metro.plane/1"``."""
    tag = f"metro.{kind}/{int(version)}"
    if not SCHEMA_PATTERN.match(tag):
        raise ValueError(f"schema kind {kind!r}: expected lower-case letters, digits, '_' or '-'")
    return tag


def tagged(kind: str, data: dict, version: int = 1) -> dict:
    """A copy of ``data`` with ``"schema"`` first; a ``schema`` already in ``data`` is replaced."""
    return {"schema": schema_tag(kind, version), **{k: v for k, v in data.items() if k != "schema"}}
