"""``metro calibrate --report``'s calibration certificate: its values are the calibrated TOML's,
its SHA-256 the file's, its header fields (``--meta``, ``--meta-file``) carried into the TOML."""

from __future__ import annotations

import hashlib
import html as html_lib
import json
import re
import tomllib

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.layout import load_layout
from tests.calibration.helpers import CAL, NOMINAL, PLANE, export_rows, write_rows
from tests.report.test_html import plain

runner = CliRunner()


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cert")
    export = write_rows(tmp / "cal.csv", export_rows(CAL)[:21])  # 20 poses: fast
    (tmp / "meta.toml").write_text('part = "EE-7 pressure foot"\nserial = 4711\ntemperature = "20.3 °C"\n'
                                   'operator = "overridden"\n', encoding="utf-8")
    out, page = tmp / "calibrated.toml", tmp / "calibrate.html"
    r = runner.invoke(app, ["calibrate", str(export), "--plane", str(PLANE), "--layout", str(NOMINAL), "--out", str(out),
                            "--report", str(page), "--json", "--meta-file", str(tmp / "meta.toml"),
                            "--meta", "operator=J. Smith", "--meta", "instrument=Leica AT960 \"LT-2\""])
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout)["certificate"], out, plain(page.read_text(encoding="utf-8"))


def test_the_certificates_values_are_the_calibrated_tomls(run):
    cert, out, page = run
    raw = {s["name"]: s for s in tomllib.loads(out.read_text(encoding="utf-8"))["sensors"]}
    params = cert["parameters"]
    assert {p["sensor"] for p in params} == set(raw) == {"L1", "L2", "L3", "L4"}
    cells = [html_lib.unescape(re.sub(r"<[^>]+>", "", c)) for c in re.findall(r"<td>(.*?)</td>", page)]
    n = 0
    for p in params:
        s = raw[p["sensor"]]
        if p["parameter"].startswith("zero point"):
            j = "xyz".index(p["parameter"][-1])
            assert p["value"] == s["zero"][j] and p["u"] == s["zero_stderr_mm"][j] and p["U"] == 2 * p["u"]
            row = [p["sensor"], p["parameter"], f"{p['value']:.6f}", f"{p['u']:.6f}", f"{p['U']:.6f}", "mm"]
        elif p["parameter"].startswith("direction"):
            assert p["value"] == s["direction"]["ijk".index(p["parameter"][10])]
            row = [p["sensor"], p["parameter"], f"{p['value']:.9f}", "—", "—", "1"]
        else:
            # the tilts' u in the chart of the calibrated direction, as the file's covariance (one
            # convention with the correlations beneath)
            j = ("e1", "e2").index(p["parameter"][-2:])
            i = ["L1", "L2", "L3", "L4"].index(p["sensor"])
            var = load_layout(out).covariance[5 * i + 3 + j, 5 * i + 3 + j]
            assert p["u"] == pytest.approx(float(np.degrees(np.sqrt(var))), rel=1e-12) and p["U"] == 2 * p["u"]
            row = [p["sensor"], p["parameter"], "—", f"{p['u']:.6f}", f"{p['U']:.6f}", "deg"]
        # the page's row says the same numbers (the TOML's digits)
        assert any(cells[k:k + 6] == row for k in range(len(cells))), row
        n += 1
    assert n == 4 * (3 + 3 + 2)
    # the zero points' printed digits are the TOML's own text
    text = out.read_text(encoding="utf-8")
    for p in params:
        if p["parameter"] == "zero point x":
            assert f"{p['value']:.6f}" in text


def test_the_certificate_names_the_file_by_its_sha256_and_carries_the_header(run):
    cert, out, page = run
    sha = hashlib.sha256(out.read_bytes()).hexdigest()
    assert cert["sha256"] == sha and sha in page and cert["number"] == f"metro-{sha[:12]}"
    meta = {"part": "EE-7 pressure foot", "serial": "4711", "temperature": "20.3 °C", "operator": "J. Smith",
            "instrument": 'Leica AT960 "LT-2"'}
    # the header states the datum's part of U, or that the plane was taken as exact (issue 40)
    assert cert["header"]["datum"].startswith("datum plane")
    full = {"datum": cert["header"]["datum"], **meta}
    assert cert["header"] == full
    assert tomllib.loads(out.read_text(encoding="utf-8"))["certificate"] == full
    assert load_layout(out).certificate == full  # read back into the layout
    for words in ("item calibrated (part)", "serial number", "operator", "temperature", "date of issue",
                  "k = 2", "coverage probability of about 95 %", "relate only to the sensor head calibrated"):
        assert words in html_lib.unescape(page), words
    # the certificate comes first, then the calibration's own section
    assert page.index("Calibration certificate") < page.index("Sensor calibration (metro calibrate)")
    # the correlations summarised are those of the file's covariance
    assert cert["correlations"] and all(abs(c["r"]) > 0.5 for c in cert["correlations"])


@pytest.mark.parametrize("args, words", [
    (["--meta", "no-equals"], "--meta 'no-equals': expected key=value"),
    (["--meta", "1x=y"], "expected key=value"),
    (["--meta-file", "missing.toml"], "missing.toml: no such file (--meta-file)"),
])
def test_bad_meta_is_one_line_exit_2(args, words, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = runner.invoke(app, ["calibrate", str(CAL), "--plane", str(PLANE), "--layout", str(NOMINAL), "--out", "c.toml",
                            *args])
    assert r.exit_code == 2 and r.stderr.startswith("error: ") and words in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not (tmp_path / "c.toml").exists()


def test_the_tilts_are_stated_in_one_chart_the_calibrated_directions(run):
    """The statement under the certificate and the note under its correlation table name the same
    axes: e1, e2 of each sensor's calibrated direction (the file's covariance), never the nominal's."""
    cert, _, page = run
    text = " ".join(html_lib.unescape(re.sub(r"<[^>]+>", " ", page)).split())
    assert cert["tilt_chart"] == "calibrated"
    assert "e1, e2 of its calibrated direction" in text
    assert text.count("e1, e2 of its calibrated direction") == 2
    assert "nominal direction" not in text


def test_the_tomls_direction_stderr_is_the_certificates_tilt_u(run):
    """Issue 51, item 9: the TOML's direction_stderr_deg and the certificate's beam-tilt u are one chart's."""
    cert, out, _ = run
    raw = {s["name"]: s for s in tomllib.loads(out.read_text(encoding="utf-8"))["sensors"]}
    for p in cert["parameters"]:
        if p["parameter"].startswith("beam tilt"):
            j = ("e1", "e2").index(p["parameter"][-2:])
            assert raw[p["sensor"]]["direction_stderr_deg"][j] == pytest.approx(p["u"], abs=1e-6)
    assert "e1, e2 of the calibrated direction" in out.read_text(encoding="utf-8")
