"""Typer's coercion of a plain command-line value, without building a pydantic adapter for it.

Typer >= 0.2x coerces every parameter of the invoked command through a pydantic ``TypeAdapter``
(``typer._coercion.build_runtime_param``), built even where the value is ``None``: the first one
imports pydantic and builds its schema machinery (0.07-0.09 s CPU; later ones 0.2-0.4 ms each),
which ``metro measure`` paid on every run (issue 49 item 4 (b): 0.1 s of a 1.5-2 s run;
benchmarks/results/measure_speed_issue49_r8.md). Bool flags skip it (typer's own rule); a value
that is ``None``, a ``str`` for a ``str``, a decimal number for an ``int`` or ``float`` without
bounds, or a path for a ``Path`` gets here what typer's adapter returns for it (the same value and
type; a path through typer's own checks, ``typer._param_types.coerce_cli_path``). Anything else
(a bound, a choice, ``inf``, an error) goes to typer's own runtime parameter, built then as typer
builds it: every message stays typer's. On a typer without these internals (the floor
pyproject.toml allows has no pydantic) nothing changes. ``tests/cli/test_coerce.py`` compares both.
"""

from __future__ import annotations

import re

#: what Python's ``float()`` and pydantic's lax ``float`` read the same: a plain decimal (no ``_``, no
#: spaces, no ``inf``/``nan``: those go to pydantic)
_FLOAT = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d{1,3})?", re.ASCII)
#: an ``int`` as both read it: no sign but ``-``, no leading zero, short of any digit limit
_INT = re.compile(r"-?(?:0|[1-9]\d{0,17})", re.ASCII)
#: "not handled here": typer's own coercion decides
_TYPER = object()


def _internals():
    """typer's runtime-parameter builder and path check, or ``None`` on a typer without them."""
    try:
        from typer._coercion import build_runtime_param
        from typer._param_types import coerce_cli_path
    except ImportError:
        return None
    return build_runtime_param, coerce_cli_path


class _Plain:
    """One parameter's runtime coercion (typer's ``RuntimeParam.coerce``): a plain value here,
    anything else by typer's own (built on first need)."""

    def __init__(self, descriptor, kind: str | None, build, coerce_path):
        self.descriptor, self.kind, self._build, self._coerce_path = descriptor, kind, build, coerce_path
        self._typer = None

    def coerce(self, value, param, ctx):
        if value is None:
            return None  # typer's RuntimeParam.coerce: a single value that is None stays None
        got = self._plain(value, param, ctx)
        if got is not _TYPER:
            return got
        if self._typer is None:
            self._typer = self._build(self.descriptor)
        return self._typer.coerce(value, param=param, ctx=ctx)

    def _plain(self, value, param, ctx):
        kind, t = self.kind, type(value)
        if kind is None:
            return _TYPER
        if kind == "str":
            return value if t is str else _TYPER
        if kind == "float":
            if t is float:
                return value
            return float(value) if t is str and _FLOAT.fullmatch(value) else _TYPER
        if kind == "int":
            if t is int:
                return value
            return int(value) if t is str and _INT.fullmatch(value) else _TYPER
        # a Path: typer's own check on the path pydantic would make of the string (``Path(value)``)
        if t is not str or not value or "\x00" in value:
            return _TYPER
        info = self.descriptor.parameter_info
        try:
            return self._coerce_path(self.descriptor.annotation(value), info, path_type=self.descriptor.annotation,
                                     param=param, ctx=ctx)
        except Exception:  # noqa: BLE001  (typer's own coercion raises its own message for it)
            return _TYPER


def _kind(descriptor) -> str | None:
    """Which plain kind the parameter is, or ``None`` (typer's own coercion throughout)."""
    from pathlib import Path

    info, a = descriptor.parameter_info, descriptor.annotation
    if info.parser is not None or getattr(info, "click_type", None) is not None or descriptor.file_annotation \
            is not None or descriptor.is_choice:
        return None
    if a is str:
        return "str"
    if a in (float, int):
        return None if info.min is not None or info.max is not None or info.clamp else a.__name__
    if a is Path and info.path_type in (None, Path) and descriptor.is_path:
        return "path"
    return None


def quicken(params) -> None:
    """Give each typer parameter of ``params`` whose coercion is not built yet a :class:`_Plain` one."""
    parts = None
    for p in params:
        if getattr(p, "_runtime_param", False) is not None or not hasattr(p, "type_descriptor"):
            continue  # built already, or not a typer parameter (or a typer without runtime parameters)
        if parts is None:
            parts = _internals()
            if parts is None:
                return
        if p.nargs == 1 and not p.multiple:
            p._runtime_param = _Plain(p.type_descriptor, _kind(p.type_descriptor), *parts)
