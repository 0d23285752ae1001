"""The calibrate fit report's tilt_e1, tilt_e2 are the nominal direction's error about the nominal's chart axes;
the certificate and the layout's direction_stderr_deg state the calibrated direction's tilt about its own, another
1 sigma under the same names e1, e2 (issue 51 item 9). The fit report's title names its chart, so the two are not
read as one number that disagrees (the walk, round 7: L3 0.14 against 0.1547 deg on one page)."""

import tomllib

from typer.testing import CliRunner

from cli.main import app
from tests.calibration.helpers import CAL, NOMINAL, PLANE, export_rows, write_rows

runner = CliRunner()


def test_the_fit_report_names_the_chart_its_tilts_are_about(tmp_path):
    export = write_rows(tmp_path / "cal.csv", export_rows(CAL)[:21])
    out = tmp_path / "calibrated.toml"
    r = runner.invoke(app, ["calibrate", str(export), "--plane", str(PLANE), "--layout", str(NOMINAL), "--out", str(out)])
    assert r.exit_code == 0, r.output
    titles = [ln.strip() for ln in r.output.splitlines() if "[[Fit Statistics]]" in ln]
    assert titles and all(t.endswith("(zero error, beam tilt about the nominal's e1, e2)") for t in titles), titles
    sensors = tomllib.loads(out.read_text(encoding="utf-8"))["sensors"]
    assert all("direction_stderr_deg" in s for s in sensors)
