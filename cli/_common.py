"""Shared CLI plumbing: one-line errors with exit code 2, JSON output."""

from __future__ import annotations

import functools
import json
import sys

import typer

EXIT_BAD_INPUT = 2


def fail(message: str) -> None:
    """Print ``error: message`` on one line to stderr and exit with code 2."""
    typer.echo(f"error: {' '.join(str(message).split())}", err=True)
    raise typer.Exit(EXIT_BAD_INPUT)


def guarded(fn):
    """Turn ``ValueError``/``OSError`` from the library into a one-line error, exit 2."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except (ValueError, OSError) as exc:
            fail(str(exc))

    return wrapper


QUATERNION_HELP = ("What the columns qw,qx,qy,qz hold: wxyz (scalar first, the format) or xyzw (a scalar-last "
                   "export under the same header).")
POSITION_HELP = "Unit of the export's x,y,z columns: mm, m or in (converted to mm)."
REPORT_HELP = ("One self-contained HTML report (.html): the verdict, the figures, the numbers with their "
               "uncertainties, what to do next; inputs with SHA-256, versions, the command line.")
NO_READING_HELP = ("The PLC's 'no reading' code in the d_ columns (default 0 where the sensor's range excludes it): "
                   "dropped and counted, never used as a distance.")


def invocation(ctx) -> str:
    """The command line a report names, rebuilt from what was parsed (``ctx``, a
    ``typer.Context``): the command, its arguments, and each option not left at its default.
    Independent of ``sys.argv``, so the same under ``metro demo`` and in tests."""
    import shlex

    parts = ctx.command_path.split()
    for p in ctx.command.params:
        v = ctx.params.get(p.name)
        if p.param_type_name == "argument":
            parts.append(str(v))
            continue
        if v is None or v is False or v == p.default or not p.opts:
            continue
        opt = max(p.opts, key=len)
        if v is True:
            parts.append(opt)
        elif isinstance(v, (tuple, list)):
            parts += [opt, *map(str, v)]
        else:
            parts += [opt, str(v)]
    return shlex.join(parts)


def warn(line: str) -> None:
    """Print ``warning: line`` to stderr."""
    typer.echo(f"warning: {line}", err=True)


def to_jsonable(obj):
    """Convert numpy scalars/arrays (and NaN) to plain JSON values."""
    import numpy as np

    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if np.isfinite(v) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    return obj


def dumps(obj) -> str:
    return json.dumps(to_jsonable(obj), indent=2, sort_keys=False)


def echo_json(obj) -> None:
    sys.stdout.write(dumps(obj) + "\n")
