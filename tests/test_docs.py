"""The README and docs/ stay in sync with the code: every quoted command, option, library
name and link exists. (The pages are written by hand; this is what keeps them honest.)"""

from __future__ import annotations

import importlib
import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def _commands():
    from typer.main import get_command

    from cli.main import app

    group = get_command(app)
    return {name: {o for p in cmd.params for o in (*p.opts, *p.secondary_opts)} | {"--help", "-h"}
            for name, cmd in group.commands.items()}


def _metro_lines(text: str):
    """Each ``metro <command> ...`` invocation in code blocks and inline code (line, words)."""
    blocks = re.findall(r"```[a-z]*\n(.*?)```", text, flags=re.S)
    inline = re.findall(r"`(metro [^`]+)`", text)
    for chunk in [*blocks, *inline]:
        for line in chunk.splitlines():
            line = line.split("#")[0].strip().lstrip("$ ").strip()
            for part in re.split(r"&&|\|", line):
                part = part.strip()
                if part.startswith("metro "):
                    try:
                        yield part, shlex.split(part)
                    except ValueError:
                        yield part, part.split()


def _root_options():
    from typer.main import get_command

    from cli.main import app

    group = get_command(app)
    return {o for p in group.get_params(group.make_context("metro", [], resilient_parsing=True))
            for o in (*p.opts, *p.secondary_opts)}


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_quoted_command_and_option_exists(page):
    commands, root = _commands(), _root_options()
    bad = []
    for line, words in _metro_lines(page.read_text()):
        while len(words) > 1 and words[1].startswith("-"):  # metro's own options: metro -q calibrate ...
            if words[1] not in root:
                bad.append(f"{line!r}: metro has no option {words[1]}")
            words = words[:1] + words[2:]
        if len(words) < 2:
            continue
        name = words[1]
        if name not in commands:
            bad.append(f"{line!r}: no command {name!r}")
            continue
        for w in words[2:]:
            opt = w.split("=")[0]
            if opt.startswith("-") and opt != "-" and not re.fullmatch(r"-\d.*", opt) and opt not in commands[name]:
                bad.append(f"{line!r}: {name} has no option {opt}")
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_quoted_library_name_imports(page):
    bad = []
    for dotted in sorted(set(re.findall(r"`(metrology(?:\.\w+)+)", page.read_text()))):
        parts = dotted.split(".")
        for cut in range(len(parts), 0, -1):
            try:
                obj = importlib.import_module(".".join(parts[:cut]))
            except ImportError:
                continue
            try:
                for attr in parts[cut:]:
                    obj = getattr(obj, attr)
            except AttributeError:
                bad.append(dotted)
            break
        else:
            bad.append(dotted)
    assert not bad, f"{page.name} quotes names that do not import: {bad}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_relative_link_resolves(page):
    links = re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", page.read_text())
    missing = [link for link in links if not (page.parent / link).exists()]
    assert not missing, f"{page.name}: broken links {missing}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_quoted_repository_path_exists(page):
    """Paths in backticks that start at a top-level folder of the repository exist."""
    tops = ("metrology/", "cli/", "tests/", "benchmarks/", "fixtures/", "docs/")
    paths = {p for p in re.findall(r"`([A-Za-z0-9_./-]+)`", page.read_text()) if p.startswith(tops)}
    missing = sorted(p for p in paths if not (ROOT / p).exists())
    assert not missing, f"{page.name} quotes paths that do not exist: {missing}"


def test_the_check_sees_a_wrong_option():
    """The command check can fail: a made-up option is reported."""
    commands = _commands()
    [(line, words)] = list(_metro_lines("```bash\nmetro calibrate x.csv --no-such-option\n```"))
    assert words[1] in commands and "--no-such-option" not in commands[words[1]]


def test_readme_front_page_is_short_and_has_the_two_commands():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 200
    assert 'pip install . && metro demo' in text
    assert 'pip install ".[test]" && pytest' in text


def test_every_json_schema_and_every_stdin_command_is_listed_in_cli_md():
    """The schema table of docs/cli.md names every ``metro.<kind>/1`` the CLI prints, and its
    ``-`` section every command whose inputs go through ``stdin_files``."""
    import re

    text = (ROOT / "docs" / "cli.md").read_text()
    schemas, stdin_section = text.split("## `-` for stdin")[0], text.split("## `-` for stdin")[1]
    for source in sorted((ROOT / "cli").glob("cmd_*.py")):
        code = source.read_text()
        for kind in re.findall(r"echo_json\([^\n]*?,\s*\"([a-z_]+)\"\)", code):
            assert f"`metro.{kind}/1`" in schemas, (source.name, kind)
        if "stdin_files(" in code:
            for command in re.findall(r"@app\.command\(\"([a-z-]+)\"", code) or [source.stem[4:].replace("_", "-")]:
                assert re.search(f"`{command}[` ]", stdin_section), (source.name, command)


def _report_commands():
    from typer.main import get_command

    from cli.main import app

    return sorted(name for name, cmd in get_command(app).commands.items()
                  if any("--report" in p.opts for p in cmd.params))


@pytest.mark.parametrize("page, pattern", [("README.md", r"`--report FILE\.html` \(([^)]*)\)"),
                                           ("docs/reports.md", r"\A# Reports\n\n(.*?)take\n")])
def test_the_lists_of_commands_with_report_name_every_one(page, pattern):
    """The README's and docs/reports.md's lists of the commands that take ``--report`` are the
    commands that take it."""
    m = re.search(pattern, (ROOT / page).read_text(), re.S)
    assert m, page
    listed = set(re.findall(r"[a-z][a-z-]+", m.group(1).replace("and", " ")))
    assert listed == set(_report_commands()), (page, sorted(listed))


def test_metro_help_describes_the_demo_by_its_steps():
    """``metro --help``'s line for demo names each of the demo's steps' commands, in order."""
    from typer.testing import CliRunner

    from cli.main import app
    from metrology.jobs.demo import DEMO_STEPS

    r = CliRunner().invoke(app, ["demo", "--help"], env={"COLUMNS": "400"})
    steps = [line.split()[0] for _, line in DEMO_STEPS]
    assert " -> ".join(steps) in " ".join(r.output.replace("│", " ").split()), steps


def test_the_docs_count_the_demos_steps():
    """Issue 51, item 14: docs/cli.md says how many steps the demo has, as many as it runs."""
    from metrology.jobs.demo import DEMO_STEPS

    words = {5: "five", 6: "six", 7: "seven", 8: "eight", 9: "nine"}
    assert f"its {words[len(DEMO_STEPS)]} steps" in (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
