"""How ``metro <command> --help`` shows parameters, the same under every typer we support.

Typer 0.2x prints a flag as ``--json <bool>`` and a required argument as ``{cloud}`` in the
usage line; typer 0.16 prints ``[default: None]`` under every optional value. The command
class below shows a flag as a bare flag, an argument as ``CLOUD`` (``[CLOUD]`` when
optional) and no default where there is none.
"""

from __future__ import annotations

import re

import typer.core

#: what rich's markup takes for a style tag (rich.markup's own pattern): ``[certificate]``,
#: ``[tolerance]``; a help text's bracketed words are escaped so rich shows them as written
_TAG = re.compile(r"(\\*)(\[[a-z#/@][^[]*?])")


def escape_markup(text: str) -> str:
    """``text`` with each bracketed word escaped for rich markup (as ``rich.markup.escape``,
    without importing rich on every command line)."""
    return _TAG.sub(lambda m: f"{m.group(1)}{m.group(1)}\\{m.group(2)}", text)


def _escape_help(obj) -> None:
    """Escape ``obj.help`` once (a command or a parameter)."""
    if getattr(obj, "help", None) and not getattr(obj, "_metro_escaped", False):
        obj.help = escape_markup(obj.help)
        obj._metro_escaped = True


def _fix(params) -> None:
    for p in params:
        if isinstance(p, typer.core.TyperArgument):
            p.metavar = p.metavar or p.name.upper()
        elif getattr(p, "is_flag", False):
            p.metavar = ""  # a flag takes no value: show none
        if p.default is None:
            p.show_default = False


def _rich_help() -> bool:
    """typer draws help with rich, parsing its markup: ``typer.core.HAS_RICH`` in newer typer (it
    reads TYPER_USE_RICH); older typer (the floor pyproject.toml allows) uses rich where it imports."""
    core = typer.core
    return bool(getattr(core, "HAS_RICH", getattr(core, "rich", None) is not None))


class _Fixed:
    """The metavar fix, shared by the command and the group (the root) classes."""

    def get_params(self, ctx):
        params = super().get_params(ctx)  # with --help and the completion options added by typer
        _fix(params)
        if _rich_help() and getattr(self, "rich_markup_mode", None) == "rich":
            for obj in (self, *params):
                _escape_help(obj)
        return params


#: the exit code of a run interrupted by Ctrl-C (128 + SIGINT)
INTERRUPTED = 130
#: the root options that may be given anywhere on the line (``metro validate -q ...``)
ANYWHERE = ("-q", "--quiet", "-v", "--verbose")


def root_options_first(args: list) -> list:
    """``args`` with the root options of :data:`ANYWHERE` moved before the command (tokens after
    ``--`` are left alone): ``validate x.csv -q`` -> ``-q validate x.csv``."""
    end = args.index("--") if "--" in args else len(args)
    moved = [a for a in args[:end] if a in ANYWHERE]
    return moved + [a for a in args[:end] if a not in ANYWHERE] + args[end:]


class MetroGroup(_Fixed, typer.core.TyperGroup):
    """The root ``metro`` group, its options shown as in :class:`MetroCommand`; ``-q``/``-v``
    anywhere on the line; a usage error as one ``error:`` line and a ``hint:`` line, exit 2."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        import sys

        click = getattr(typer.core, "_click", None) or __import__("click")  # typer >= 0.2x vendors click
        abort = getattr(typer.core, "Abort", None) or click.exceptions.Abort

        args = root_options_first(list(sys.argv[1:] if args is None else args))
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        try:
            rv = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except KeyboardInterrupt:  # click, typer < 0.16: typer's newer own returns 130 quietly
            rv = INTERRUPTED
        except click.exceptions.UsageError as e:
            path = e.ctx.command_path if e.ctx is not None else "metro"
            click.echo(f"error: {' '.join(e.format_message().split())}", err=True)
            click.echo(f"hint: '{path} -h' lists the arguments and options", err=True)
            sys.exit(e.exit_code)
        except click.ClickException as e:
            click.echo(f"error: {' '.join(e.format_message().split())}", err=True)
            sys.exit(e.exit_code)
        except abort as e:
            if not isinstance(e.__cause__, KeyboardInterrupt):
                click.echo("error: aborted", err=True)
                sys.exit(1)
            rv = INTERRUPTED
        if rv == INTERRUPTED:  # Ctrl-C: one line, exit 128 + SIGINT as a shell shows it
            click.echo("error: interrupted (Ctrl-C): every file is written whole or not at all; a folder output "
                       "resumes", err=True)
        sys.exit(rv if isinstance(rv, int) else 0)


class MetroCommand(_Fixed, typer.core.TyperCommand):
    """A typer command with the metavars fixed (see the module)."""

    def collect_usage_pieces(self, ctx):
        pieces = [self.options_metavar] if self.options_metavar else []
        for p in self.get_params(ctx):
            if isinstance(p, typer.core.TyperArgument):
                name = p.metavar + ("..." if p.nargs != 1 else "")
                pieces.append(name if p.required else f"[{name}]")
            else:
                pieces.extend(p.get_usage_pieces(ctx))
        return pieces


def use_metro_command(app: typer.Typer) -> None:
    """Give every command registered on ``app`` (without a class of its own) :class:`MetroCommand`."""
    for info in app.registered_commands:
        if info.cls in (None, typer.core.TyperCommand):
            info.cls = MetroCommand
