"""cli/_coerce: a plain value coerced as typer's own adapter does, the rest left to typer; no pydantic on a plain line."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from cli._coerce import _internals, _Plain, quicken

pytestmark = pytest.mark.skipif(_internals() is None, reason="this typer has no runtime parameters (no pydantic)")


def _measure():
    import typer.main

    from cli.main import app

    return typer.main.get_command(app).commands["measure"]


def _outcome(coerce, value, param, ctx):
    try:
        got = coerce(value, param=param, ctx=ctx)
    except Exception as e:  # noqa: BLE001  (the outcome compared: type and message)
        return ("raised", type(e).__name__, str(e))
    return ("value", type(got).__name__, repr(got))  # repr: nan equals itself


@pytest.mark.parametrize("name, values", [
    ("tolerance_deg", ["0.1", "10", "-3", "+2.5", "1.", ".5", "1e-3", "2E+2", "1e400", "0.1000000000000000055511151231257827",
                       "inf", "-Infinity", "nan", "1_0", " 1", "1 ", "abc", "", "0x10", "1e", "\u0663", "1\n", 0.5, 0,
                       True]),
    ("opcua_queue", ["20000", "0", "-7", "007", "-0", "+5", "1_000", "1.0", "1e3", " 3", "x", "",
                     "123456789012345678", "1234567890123456789", "\u0663", 20000, 2.0, False]),
    ("scheduler", ["tcp://h:1", "", "-", " a ", b"bytes", 3]),
    ("layout", ["calibrated.toml", "dir", "missing.toml", "", ".", "-", "a/../calibrated.toml", b"calibrated.toml"]),
    ("units", ["mm", "in"]),
    ("follow", [True, False, "true", "no", None]),
])
def test_a_plain_value_is_what_typers_own_coercion_makes_of_it_and_the_rest_typers_message(name, values, tmp_path,
                                                                                          monkeypatch):
    from typer._coercion import build_runtime_param

    from cli._coerce import _kind

    monkeypatch.chdir(tmp_path)
    (tmp_path / "calibrated.toml").write_text("")
    (tmp_path / "dir").mkdir()
    cmd = _measure()
    param = next(p for p in cmd.params if p.name == name)
    ctx = cmd.context_class(cmd)
    typer_own = build_runtime_param(param.type_descriptor)
    ours = _Plain(param.type_descriptor, _kind(param.type_descriptor), *_internals())
    for v in values + [None]:
        want = _outcome(typer_own.coerce, v, param, ctx)
        got = _outcome(ours.coerce, v, param, ctx)
        assert got == want, (name, v)


def test_quicken_leaves_a_built_coercion_and_a_parameter_typer_does_not_own_alone():
    cmd = _measure()
    built = next(p for p in cmd.params if p.name == "tolerance_deg")
    sentinel = object()
    built._runtime_param, plain = sentinel, object()
    try:
        quicken([built, plain])
        assert built._runtime_param is sentinel
    finally:
        built._runtime_param = None


def test_a_measure_line_of_plain_values_imports_no_pydantic(tmp_path):
    code = ("import sys\nfrom cli.main import app\n"
            "try:\n    app(sys.argv[1:])\nexcept SystemExit:\n    pass\n"
            "print('pydantic' in sys.modules, 'typer._adapters' in sys.modules)\n")
    args = ["-q", "measure", str(tmp_path / "no.csv"), "--layout", str(tmp_path), "--out", str(tmp_path / "o.csv"),
            "--tolerance-deg", "0.1", "--opcua-queue", "5", "--scheduler", "tcp://h:1"]
    r = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                       cwd=Path(__file__).resolve().parents[2])
    assert r.stdout.split() == ["False", "False"], r.stdout + r.stderr
    assert "no such file (LOG)" in r.stderr  # the line was parsed: the command ran and refused the log
