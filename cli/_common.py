"""Shared CLI plumbing: one-line errors with exit code 2, warnings and ``-v`` notes on
stderr, ``-q``, progress bars, JSON output with its schema tag."""

from __future__ import annotations

import contextlib
import functools
import json
import sys
import time


import typer

EXIT_BAD_INPUT = 2


class _State:
    """What the root options (``metro -q``/``-v``) set for the run, and the names shown
    for temporary files (stdin spooled to a file is shown as ``<stdin>``)."""

    quiet = False
    verbose = False
    t0 = time.perf_counter()
    aliases: dict = {}
    depth = 0  # runs in progress: the demo runs its steps inside its own run


STATE = _State()


def set_verbosity(quiet: bool, verbose: bool) -> None:
    """Start a run: ``-q``/``-v`` as given, the clock of the ``-v`` notes at zero."""
    STATE.quiet, STATE.verbose = bool(quiet), bool(verbose) and not quiet
    STATE.t0 = time.perf_counter()
    STATE.aliases = {}


def begin_run(quiet: bool, verbose: bool):
    """Called by the root callback; returns the function that ends the run. A run inside
    another (a demo step) keeps the outer run's ``-q``/``-v``, clock and names."""
    if STATE.depth == 0:
        set_verbosity(quiet, verbose)
    STATE.depth += 1

    def end():
        STATE.depth -= 1

    return end


def shown(text: str) -> str:
    """``text`` with every temporary path that stands for stdin replaced by ``<stdin>``."""
    for real, name in STATE.aliases.items():
        text = text.replace(real, name)
    return text


def fail(message: str) -> None:
    """Print ``error: message`` on one line to stderr and exit with code 2 (even under ``-q``)."""
    typer.echo(f"error: {' '.join(shown(str(message)).split())}", err=True)
    raise typer.Exit(EXIT_BAD_INPUT)


RANGE_HELP = "MIN,MAX"


def parse_range(text, option: str, unit: str = "mm", positive: bool = False):
    """``"a,b"`` -> (a, b) floats with a < b (and 0 < a when ``positive``), or None for None; a
    one-line error otherwise. The one range syntax of every command (``--standoff-mm 40,60``)."""
    if text is None:
        return None
    try:
        a, b = (float(v) for v in str(text).split(","))
    except ValueError:
        fail(f"{option} {text}: expected two numbers MIN,MAX in {unit} (e.g. {option} 40,60)")
    if not a < b or (positive and not a > 0):
        fail(f"{option} {text}: expected {'0 < ' if positive else ''}MIN < MAX")
    return a, b


def output_path(value, option: str):
    """The path of an output file option, or None; fails (one line, exit 2) on a value that names a
    folder or lies in one that does not exist (:func:`metrology.io.atomic.check_output_file`)."""
    if value is None:
        return None
    from metrology.io.atomic import check_output_file

    try:
        return check_output_file(value, option)
    except ValueError as exc:
        fail(str(exc))


#: exit code when the reader of stdout went away (``| head``): a shell's for a process killed by SIGPIPE
EXIT_CLOSED_PIPE = 128 + 13


def closed_pipe() -> None:
    """stdout's reader has gone (``metro ... | head -1``): not bad input. Quiet, as other tools:
    no message, exit :data:`EXIT_CLOSED_PIPE`; stdout is pointed at /dev/null so the interpreter's
    final flush does not complain."""
    import os
    import sys

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass
    raise typer.Exit(EXIT_CLOSED_PIPE)


def guarded(fn):
    """Turn ``ValueError``/``OSError`` from the library into a one-line error, exit 2; a closed
    stdout pipe into a quiet exit (:func:`closed_pipe`)."""
    import errno

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except (ValueError, OSError) as exc:
            if isinstance(exc, BrokenPipeError) or getattr(exc, "errno", None) == errno.EPIPE \
                    or "[Errno 32] Broken pipe" in str(exc):  # pyarrow's writer re-raises it as an OSError
                closed_pipe()
            fail(str(exc))

    return wrapper


QUATERNION_HELP = ("What the columns qw,qx,qy,qz hold: wxyz (scalar first, the format) or xyzw (a scalar-last "
                   "export under the same header).")
POSITION_HELP = "Unit of the export's x,y,z columns: mm, m or in (converted to mm)."
REPORT_HELP = ("One self-contained HTML report (.html): the verdict, the figures, the numbers with their "
               "uncertainties, what to do next; inputs with SHA-256, versions, the command line.")
NO_READING_HELP = ("The PLC's 'no reading' code in the d_ columns (default 0 where the sensor's range excludes it): "
                   "dropped and counted, never used as a distance.")
JSON_HELP = "Print the result as JSON on stdout (with its \"schema\" tag)."


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
        if v is None or v is False or v == p.default or not p.opts or (isinstance(v, (tuple, list)) and not v):
            continue
        opt = max(p.opts, key=len)
        if v is True:
            parts.append(opt)
        elif isinstance(v, (tuple, list)) and getattr(p, "multiple", False):  # a repeatable option: --meta a=1 --meta b=2
            for item in v:
                parts += [opt, str(item)]
        elif isinstance(v, (tuple, list)):
            parts += [opt, *map(str, v)]
        else:
            parts += [opt, str(v)]
    return shlex.join(parts)


def with_verdict(obj: dict, verdict) -> dict:
    """``obj`` (a command's JSON) with its ``verdict`` (:class:`metrology.core.verdict.Verdict`) added."""
    return {**obj, "verdict": verdict.to_dict()}


def finish(verdict) -> None:
    """End the command with the exit code of its verdict: 0 passed, 1 failed (docs/cli.md)."""
    from metrology.core.verdict import exit_code

    code = exit_code(verdict)
    if code:
        raise typer.Exit(code)


def reported(*paths) -> None:
    """One ``report: FILE`` line on stderr per report written (not under ``-q``)."""
    if not STATE.quiet:
        for p in paths:
            if p is not None:
                typer.echo(f"report: {shown(str(p))}", err=True)


def warn(line: str) -> None:
    """Print ``warning: line`` to stderr, unless ``-q``."""
    if not STATE.quiet:
        typer.echo(f"warning: {shown(str(line))}", err=True)


def note(line: str) -> None:
    """Under ``-v``: print ``[  1.23 s] line`` to stderr (seconds since the command started)."""
    if STATE.verbose:
        typer.echo(f"[{time.perf_counter() - STATE.t0:7.2f} s] {shown(str(line))}", err=True)


def show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """:func:`warnings.showwarning` for the run: a library's warning as one ``warning:`` line."""
    warn(str(message))


def echo(text: str) -> None:
    """Print ``text`` on stdout (stdin's temporary file named ``<stdin>``)."""
    typer.echo(shown(str(text)))


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


def dumps(obj, kind: str) -> str:
    """JSON text of ``obj`` tagged ``"schema": "metro.<kind>/1"`` (:func:`metrology.core.schema.tagged`)."""
    from metrology.core.schema import tagged

    return shown(json.dumps(to_jsonable(tagged(kind, obj)), indent=2, sort_keys=False))


def echo_json(obj, kind: str) -> None:
    """Print ``obj`` as JSON with its schema tag on stdout."""
    sys.stdout.write(dumps(obj, kind) + "\n")


def _stderr_is_tty() -> bool:
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


_LIVE = []  # the one rich Progress on screen (nested bars add a line to it)


@contextlib.contextmanager
def progress_bar(label: str):
    """Yield a :data:`metrology.core.progress.ProgressFn` drawn as a rich bar on stderr: done/total,
    or the count alone (a pulsing bar) while the total is None (not known).

    Silent when stderr is not a terminal and under ``-q``; under ``-v`` each step is also
    noted with its duration. A bar opened inside another (the demo's steps) is a second
    line of the same display.
    """
    last = {"what": None, "t": time.perf_counter()}

    def log(what):  # one note per stage: "selection step 1: candidate 3/36" is stage "selection step 1"
        stage = None if what is None else what.split(":")[0]
        if stage != last["what"]:
            now = time.perf_counter()
            if last["what"] not in (None, "done"):
                note(f"{label}: {last['what']} ({now - last['t']:.2f} s)")
            last.update(what=stage, t=now)

    if STATE.quiet or not _stderr_is_tty():
        yield lambda done, total, what: log(what)
        log(None)
        return
    from rich.console import Console
    from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    with contextlib.ExitStack() as stack:
        if _LIVE:
            bar = _LIVE[-1]
        else:
            bar = Progress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[count]}"),
                           TimeElapsedColumn(), TextColumn("{task.fields[what]}"),
                           console=Console(file=sys.stderr, force_terminal=True), transient=True,
                           redirect_stdout=sys.stdout.isatty(), redirect_stderr=True)
            stack.enter_context(bar)
            _LIVE.append(bar)
            stack.callback(_LIVE.pop)
        task = bar.add_task(label, total=None, what="", count="")  # no total yet: a pulsing bar
        stack.callback(bar.remove_task, task)

        def update(done, total, what):
            log(what)
            # total None: not known (a log's holes before it is read): the count alone, the bar pulsing
            count = f"{done:,}" if total is None else f"{done}/{total}"
            bar.update(task, completed=done, what=shown(what), count=count, refresh=True,
                       **({} if total is None else {"total": total}))

        yield update
        log(None)
