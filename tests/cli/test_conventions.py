"""The command-line conventions (docs/cli.md): --json with a schema tag on every command,
'-' for stdin, help without value placeholders on flags, -q/-v, warnings on stderr,
progress bars on a terminal only.

Runs under the newest typer and typer 0.16 (click 8.2): ``result.stderr`` is separate in both.
"""

import json
import re

import pytest
from typer.main import get_command
from typer.testing import CliRunner

import cli._common as common
from cli.main import app
from metrology.core.schema import SCHEMA_PATTERN, schema_tag, tagged
from metrology.io.data import DATA_DIR

runner = CliRunner()
M = DATA_DIR / "measured"
H = DATA_DIR / "hidden"
COMMANDS = sorted(get_command(app).commands)
TINY_XYZ = "0 0 0\n100 0 0.01\n0 100 -0.01\n100 100 0\n50 50 0.02\n20 70 -0.02\n"


def _read(path):
    return path.read_bytes()


@pytest.fixture(scope="module")
def small_export(tmp_path_factory):
    """A 20-pose export from the forward simulator (``metro simulate``), for a quick diagnose."""
    out = tmp_path_factory.mktemp("sim") / "export.csv"
    r = runner.invoke(app, ["simulate", "--layout", str(H / "layout.toml"), "--plane", str(H / "plane.json"),
                            "--out", str(out), "--poses", "20"])
    assert r.exit_code == 0, r.output
    return out


def _tiny_log(tmp):
    """30 holes cast at planes for the bundled Table 6 layout, as CSV bytes."""
    from tests.measure.helpers import calibrated_layout, hole_log, write_log_csv

    cols, _, _ = hole_log(calibrated_layout(), n=30, angle_deg=(0.01, 0.1))
    return write_log_csv(cols, tmp / "tiny.csv").read_bytes()


def _cases(tmp, small_export):
    """One cheap --json run of each command: (args, stdin). Several read an input from '-'."""
    return {
        "fit-plane": (["fit-plane", "-", "--format", "xyz"], TINY_XYZ),
        "calibrate": (["calibrate", "-", "--plane", str(M / "plane.json"), "--layout", str(M / "nominal.toml")],
                      _read(M / "calibration.csv")),
        "validate": (["validate", str(M / "validation.csv"), "--plane", str(M / "plane.json"), "--layout", "-"],
                     _read(M / "nominal.toml")),
        "diagnose": (["diagnose", str(small_export), "--plane", "-", "--layout", str(H / "layout.toml"), "--folds", "2"],
                     _read(H / "plane.json")),
        "simulate": (["simulate", "--layout", "-", "--plane", str(H / "plane.json"), "--out", str(tmp / "s.csv"),
                      "--poses", "12"], _read(H / "layout.toml")),
        "normals": (["normals", str(DATA_DIR / "panel_cyl800.stl"), "--layout", "-", "--grid", "60", "--no-loop"],
                    _read(DATA_DIR / "layout_table6.toml")),
        "reproduce": (["reproduce", "--poses", "20", "--figures", "-"], None),
        "demo": (["demo", "--out", str(tmp / "demo")], None),
        "version": (["version"], None),
        "simulate-log": (["simulate-log", "--out", str(tmp / "log.csv"), "--holes", "50"], None),
        "measure": (["measure", "-", "--layout", str(M / "nominal.toml"), "--out", str(tmp / "holes.csv")],
                    _tiny_log(tmp)),
        "plan": (["plan", "--layout", str(M / "nominal.toml"), "--plane", "-", "--poses", "6", "--candidates", "300"],
                 _read(M / "datum.ply")),
    }


def _one_step_demo(monkeypatch):
    """The demo cut to one quick step (the walk-through itself is tested in test_core.py)."""
    import metrology.jobs.demo as demo

    monkeypatch.setattr(demo, "DEMO_STEPS", (("1. Print the version", "version"),))


def test_every_command_takes_json_and_tags_its_output(tmp_path, small_export, monkeypatch):
    _one_step_demo(monkeypatch)
    cases = _cases(tmp_path, small_export)
    assert sorted(cases) == COMMANDS, "a command without a --json case here"
    for name in COMMANDS:
        cmd = get_command(app).commands[name]
        assert any("--json" in p.opts and p.is_flag for p in cmd.params), f"{name}: no --json flag"
        args, stdin = cases[name]
        r = runner.invoke(app, [*args, "--json"], input=stdin)
        assert r.exit_code in (0, 1), f"{name}: {r.output}"
        out = json.loads(r.stdout)
        # every JSON carries its verdict, and the exit code is the verdict's (docs/cli.md)
        v = out["verdict"]
        assert set(v) == {"passed", "checks"} and r.exit_code == (0 if v["passed"] else 1), name
        assert all(set(c) >= {"name", "value", "limit", "unit", "passed", "gate"} for c in v["checks"]), name
        assert v["passed"] == all(c["passed"] for c in v["checks"] if c["gate"]), name
        assert SCHEMA_PATTERN.match(out["schema"]), f"{name}: schema {out['schema']!r}"
        assert list(out)[0] == "schema"
        if name == "demo":  # each step's own output is tagged too
            assert [s["result"]["schema"] for s in out["steps"]] == ["metro.version/1"]
        if stdin is not None:  # the stdin input is named <stdin>, never its temporary file
            assert "metro-stdin-" not in r.stdout


def test_schema_helper():
    assert schema_tag("plane") == "metro.plane/1" and schema_tag("demo", 3) == "metro.demo/3"
    assert list(tagged("x", {"a": 1, "schema": "old"})) == ["schema", "a"]
    with pytest.raises(ValueError, match="schema kind 'Bad Kind'"):
        schema_tag("Bad Kind")


@pytest.mark.parametrize("name", ["", *COMMANDS])
def test_help_shows_flags_as_flags_and_arguments_in_capitals(name):
    r = runner.invoke(app, [name, "--help"] if name else ["--help"], env={"COLUMNS": "160"})
    assert r.exit_code == 0, r.output
    assert "<bool>" not in r.output and "[default: None]" not in r.output
    usage = next(line for line in r.output.splitlines() if "Usage:" in line)
    assert "{" not in usage
    for p in get_command(app).commands[name].params if name else []:
        if p.param_type_name == "argument":
            assert f" {p.name.upper()}" in usage


def test_h_and_version_and_bare_metro(monkeypatch):
    import shellingham

    assert runner.invoke(app, ["-h"]).exit_code == 0
    r = runner.invoke(app, ["--version"])
    assert r.exit_code == 0 and r.stdout.startswith("metro ")
    r = runner.invoke(app, [])
    assert r.exit_code == 0 and "Usage:" in r.stdout
    # typer finds the shell from the process tree (shellingham), not from $SHELL: pytest started
    # from `sh` would get "Shell sh not supported", so the user's shell is set to bash here
    monkeypatch.setattr(shellingham, "detect_shell", lambda *a, **k: ("bash", "/bin/bash"))
    r = runner.invoke(app, ["--show-completion"], prog_name="metro")
    assert r.exit_code == 0 and "_METRO_COMPLETE" in r.stdout  # the bash completion script


def test_stdin_errors_name_stdin_and_the_line():
    text = _read(M / "calibration.csv").decode().splitlines()
    text[2] = re.sub(r",[^,]*$", ",abc", text[2])
    r = runner.invoke(app, ["calibrate", "-", "--plane", str(M / "plane.json"), "--layout", str(M / "nominal.toml")],
                      input="\n".join(text) + "\n")
    assert r.exit_code == 2 and r.stdout == ""
    assert r.stderr.startswith("error: <stdin>: line 3:") and "'abc'" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_two_stdin_inputs_is_an_error_naming_both():
    r = runner.invoke(app, ["calibrate", "-", "--plane", "-", "--layout", str(M / "nominal.toml")], input="x")
    assert r.exit_code == 2
    assert "EXPORT" in r.stderr and "--plane" in r.stderr and "only one input" in r.stderr


def test_stdin_cloud_needs_a_format_unless_its_header_names_it():
    r = runner.invoke(app, ["fit-plane", "-"], input=TINY_XYZ)
    assert r.exit_code == 2 and "--format" in r.stderr
    r = runner.invoke(app, ["fit-plane", "-", "--json"], input=_read(M / "datum.ply"))  # PLY: its header
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["source"] == "<stdin>"
    r = runner.invoke(app, ["fit-plane", str(M / "datum.ply"), "--format", "ply"])
    assert r.exit_code == 2 and "only for a cloud on stdin" in r.stderr
    r = runner.invoke(app, ["fit-plane", "-"], input="")
    assert r.exit_code == 2 and "nothing on stdin" in r.stderr


def _zero_reading_export():
    """The measured export with one reading set to the no-reading code 0: a warning, not an error."""
    lines = _read(M / "calibration.csv").decode().splitlines()
    lines[1] = lines[1] + "0" if lines[1].endswith(",") else re.sub(r",[^,]*$", ",0", lines[1])
    return "\n".join(lines) + "\n"


def test_warnings_on_stderr_silenced_by_q_and_v_notes_the_steps():
    args = ["validate", "-", "--plane", str(M / "plane.json"), "--layout", str(M / "nominal.toml"), "--tolerance-deg", "1"]
    r = runner.invoke(app, args, input=_zero_reading_export())
    assert r.exit_code == 0, r.output
    assert "warning: <stdin>: 1 reading(s) equal to the no-reading code 0" in r.stderr
    assert "warning" not in r.stdout
    quiet = runner.invoke(app, ["-q", *args], input=_zero_reading_export())
    assert quiet.exit_code == 0 and quiet.stderr == "" and quiet.stdout == r.stdout
    loud = runner.invoke(app, ["-v", *args], input=_zero_reading_export())
    assert loud.exit_code == 0 and loud.stdout == r.stdout
    assert re.search(r"^\[ *[0-9.]+ s\] metro validate$", loud.stderr, re.M)
    assert "--layout" not in loud.stderr and "EXPORT: read" in loud.stderr and "metro validate: done" in loud.stderr
    err = runner.invoke(app, ["-q", "validate", "-", "--plane", "-", "--layout", "x"], input="x")
    assert err.exit_code == 2 and err.stderr.startswith("error:")  # errors print under -q


def test_library_warnings_become_one_warning_line(capsys):
    common.set_verbosity(False, False)
    common.show_warning(UserWarning("a cloud in metres?"), UserWarning, "f.py", 1)
    assert capsys.readouterr().err == "warning: a cloud in metres?\n"
    common.set_verbosity(True, False)
    common.show_warning(UserWarning("x"), UserWarning, "f.py", 1)
    assert capsys.readouterr().err == ""
    common.set_verbosity(False, False)


def test_progress_bar_on_a_terminal_only(tmp_path, monkeypatch):
    """The demo's bar (with a nested line for its step) is drawn on stderr when it is a
    terminal, never on stdout, and not under -q or when stderr is a file or pipe."""
    _one_step_demo(monkeypatch)
    r = runner.invoke(app, ["demo", "--out", str(tmp_path / "a"), "--json"])
    assert r.exit_code == 0 and r.stderr == ""  # not a terminal: silent
    monkeypatch.setattr(common, "_stderr_is_tty", lambda: True)
    r = runner.invoke(app, ["demo", "--out", str(tmp_path / "b"), "--json"])
    assert r.exit_code == 0, r.output
    assert "demo" in r.stderr and "0/1" in r.stderr and "step 1. metro version" in r.stderr and "━" in r.stderr
    assert json.loads(r.stdout)["schema"] == "metro.demo/1"  # stdout holds the JSON only
    r = runner.invoke(app, ["-q", "demo", "--out", str(tmp_path / "c"), "--json"])
    assert r.exit_code == 0 and r.stderr == ""


def test_files_written_from_stdin_name_it_stdin_never_its_temporary_copy(tmp_path):
    """The temporary copy of stdin is gone when the command ends: no written file may name it.
    (The export is the bundled one's first 16 poses: its report costs half the CPU of the full 100
    poses' and names its input the same way.)"""
    from tests.calibration.helpers import export_rows, write_rows

    r = runner.invoke(app, ["fit-plane", "-", "--out", str(tmp_path / "plane.json"), "--report", str(tmp_path / "f.html")],
                      input=_read(M / "datum.ply"))
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "plane.json").read_text())["source"] == "<stdin>"
    export = _read(write_rows(tmp_path / "short.csv", export_rows(M / "calibration.csv")[:17]))
    r = runner.invoke(app, ["calibrate", "-", "--plane", str(M / "plane.json"), "--layout", str(M / "nominal.toml"),
                            "--out", str(tmp_path / "c.toml"), "--report", str(tmp_path / "c.html")], input=export)
    assert r.exit_code == 0, r.output
    assert "# export <stdin>, datum " in (tmp_path / "c.toml").read_text()
    html = (tmp_path / "c.html").read_text()
    assert "&lt;stdin&gt;" in html  # the inputs table (escaped), with the stream's checksum
    import hashlib

    assert hashlib.sha256(export).hexdigest() in html
    for f in ("plane.json", "f.html", "c.toml", "c.html"):
        assert "metro-stdin-" not in (tmp_path / f).read_text(), f


def test_q_and_v_anywhere_and_usage_errors_are_one_line_and_a_hint():
    args = ["validate", "-", "--plane", str(M / "plane.json"), "--layout", str(M / "nominal.toml"), "--tolerance-deg", "1"]
    first = runner.invoke(app, ["-q", *args], input=_zero_reading_export())
    last = runner.invoke(app, [*args, "-q"], input=_zero_reading_export())
    assert first.exit_code == last.exit_code == 0 and last.stderr == "" and last.stdout == first.stdout
    loud = runner.invoke(app, [*args[:2], "-v", *args[2:]], input=_zero_reading_export())
    assert re.search(r"^\[ *[0-9.]+ s\] metro validate$", loud.stderr, re.M)
    # an export that exists: the missing option is the only usage error (click checks options and
    # typer's file callbacks in an order that changed between versions)
    for bad, words in ((["calibrate", str(M / "calibration.csv")], "error: Missing option '--plane'"),
                       (["version", "--bogus"], "error: No such option: --bogus"),
                       (["reproduce", "--poses", "x"], "error: Invalid value for '--poses'")):
        r = runner.invoke(app, bad)
        lines = r.stderr.strip().splitlines()
        assert r.exit_code == 2 and len(lines) == 2 and lines[0].startswith(words), r.stderr
        assert lines[1] == f"hint: 'metro {bad[0]} -h' lists the arguments and options"


@pytest.mark.parametrize("name", COMMANDS)
def test_help_reads_at_80_columns(name):
    """Every option's long name whole (no rich ellipsis), no line over 80 characters."""
    r = runner.invoke(app, [name, "-h"], env={"COLUMNS": "80"})
    assert r.exit_code == 0 and "…" not in r.stdout
    assert max(len(line) for line in r.stdout.splitlines()) <= 80
    for p in get_command(app).commands[name].params:
        if p.param_type_name == "option" and not p.hidden:
            assert max(p.opts, key=len) in r.stdout, (name, p.opts)


def test_one_wording_for_a_missing_file_and_the_suffixes_in_every_format_error(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "panel.txt").write_text("x")
    (tmp_path / "p.yaml").write_text("x")
    plane, nominal = str(M / "plane.json"), str(M / "nominal.toml")
    cases = [
        (["validate", str(M / "validation.csv"), "--plane", "nope.json", "--layout", nominal], "nope.json: no such file (--plane)"),
        (["calibrate", "nope.csv", "--plane", plane, "--layout", nominal], "nope.csv: no such file (EXPORT)"),
        (["validate", str(M / "validation.csv"), "--plane", plane, "--layout", "nope.toml"], "nope.toml: no such file (--layout)"),
        (["fit-plane", "nope.ply"], "nope.ply: no such file (CLOUD)"),
        (["normals", "nope.stl", "--layout", nominal, "--grid", "40"], "nope.stl: no such file (PANEL)"),
        (["plan", "--layout", nominal, "--plane", "nope.ply", "--poses", "6"], "nope.ply: no such file (--plane)"),
        (["normals", "panel.txt", "--layout", nominal, "--grid", "40"],
         "panel.txt: unknown extension '.txt' for PANEL; expected one of .stl, .obj, .ply"),
        (["validate", str(M / "validation.csv"), "--plane", "p.yaml", "--layout", nominal],
         "p.yaml: unknown extension '.yaml' for --plane; expected one of .json, .csv"),
        (["fit-plane", "p.yaml"], "p.yaml: unknown extension '.yaml' for CLOUD; expected one of .csv, .e57"),
        (["measure", "nope.csv", "--layout", nominal], "nope.csv: no such file (LOG)"),
        (["measure", "p.yaml", "--layout", "nope.toml"], "nope.toml: no such file (--layout)"),
        (["measure", "p.yaml", "--layout", nominal, "--panel", "nope.stl", "--points", "p.yaml"],
         "nope.stl: no such file (--panel)"),
        (["measure", "p.yaml", "--layout", nominal, "--points", "nope.csv"], "nope.csv: no such file (--points)"),
        (["simulate-log", "--panel", "nope.stl", "--out", "x.csv"], "nope.stl: no such file (--panel)"),
        (["simulate-log", "--points", "nope.csv", "--out", "x.csv"], "nope.csv: no such file (--points)"),
    ]
    for args, words in cases:
        r = runner.invoke(app, args)
        assert r.exit_code == 2 and r.stderr.startswith(f"error: {words}") and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert r.stdout == ""


def test_follow_on_a_planned_file_says_waiting_for_readings(tmp_path):
    planned = tmp_path / "planned.csv"
    r = runner.invoke(app, ["plan", "--layout", str(M / "nominal.toml"), "--plane", str(M / "datum.ply"), "--poses", "6",
                            "--candidates", "300", "--out", str(planned)])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["calibrate", str(planned), "--plane", str(M / "plane.json"), "--layout",
                            str(M / "nominal.toml"), "--follow", "--idle-s", "0"])
    assert r.exit_code == 2 and "inf" not in r.output
    lines = r.stdout.splitlines()
    assert len(lines) == 6 and all(": waiting for readings" in line for line in lines)
    assert r.stderr.startswith("error: ") and "none with a reading yet" in r.stderr


@pytest.mark.parametrize("name", ["", *COMMANDS])
def test_help_keeps_every_word_in_square_brackets(name):
    """rich reads ``[certificate]`` as a style tag and drops it: every bracketed word of a help
    text (an option's, the command's) shows in ``--help`` as written."""
    r = runner.invoke(app, [name, "--help"] if name else ["--help"], env={"COLUMNS": "2000"})
    assert r.exit_code == 0, r.output
    shown = " ".join(r.output.replace("│", " ").split())
    cmd = get_command(app).commands[name] if name else get_command(app)
    texts = [p.help for p in cmd.params if getattr(p, "help", None)] + ([cmd.help] if name and cmd.help else [])
    for text in texts:
        for word in re.findall(r"\[[a-z#/@][^\[\]]*\]", text.replace("\\[", "[")):
            assert word in shown, (name, word)


def test_a_progress_bar_of_unknown_total_counts_without_a_total(monkeypatch):
    """``metro measure`` does not know a log's length before reading it: its bar shows the holes
    counted so far, never "983040/1" (a total of 1 it was never given), and a known total shows
    as done/total."""
    import io

    monkeypatch.setattr(common, "_stderr_is_tty", lambda: True)
    monkeypatch.setattr(common.STATE, "quiet", False)  # an earlier test's -q
    err = io.StringIO()
    monkeypatch.setattr(common.sys, "stderr", err)
    with common.progress_bar("measure") as progress:
        progress(983040, None, "983,040 holes measured")
    out = err.getvalue()
    assert "983040/1" not in out and "/1 " not in out
    assert "983,040" in out
    err.seek(0), err.truncate()
    with common.progress_bar("plan") as progress:
        progress(3, 7, "step")
    assert "3/7" in err.getvalue()


def test_measure_help_shows_brackets_without_backslashes_and_every_exit_cause(monkeypatch):
    """Issue 51, item 13: rich markup escapes are not shown; the exit codes name the drilled angle not known."""
    monkeypatch.setenv("COLUMNS", "200")
    r = runner.invoke(app, ["measure", "--help"])
    assert r.exit_code == 0
    text = " ".join(r.stdout.replace("│", " ").split())
    assert "\\[" not in text and "[calibration]" in text and "metro[fleet]" in text
    assert "drilled angle not known" in text


def test_ctrl_c_exits_130_with_one_line(tmp_path, monkeypatch):
    """Issue 51, item 14: an interrupted run says so on one line and exits 130."""
    import metrology.jobs.measure as job

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(job, "measure_files", interrupted)
    log = tmp_path / "log.csv"
    log.write_text("hole_id,time\n")
    r = runner.invoke(app, ["measure", str(log), "--layout", str(M / "nominal.toml")])
    assert r.exit_code == 130, r.output
    assert r.stderr.strip().splitlines() == [r.stderr.strip()] and r.stderr.startswith("error: interrupted (Ctrl-C)")
