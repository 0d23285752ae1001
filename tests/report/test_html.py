"""Each command's ``--report FILE.html``: one self-contained page that parses, embeds its
figures, names no external URL, says the verdict first and lists each input's SHA-256."""

from __future__ import annotations

import hashlib
import html as html_lib
import json
import re
import shutil
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.data import DATA_DIR
from tests.calibration.helpers import CAL, NOMINAL, PLANE, TRUTH, VAL, export_rows, write_rows

runner = CliRunner()


class _Page(HTMLParser):
    def __init__(self):
        super().__init__()
        self.urls, self.imgs, self.tags, self.text = [], [], [], []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        self.tags.append(tag)
        self.urls += [v for k, v in attrs if k in ("src", "href") and v]
        if tag == "img":
            self.imgs.append(a.get("src", ""))

    def handle_data(self, data):
        self.text.append(data)


def plain(html: str) -> str:
    """The page without its no-wrap spans (``<span class="nb">``: words kept whole on a line)."""
    return re.sub(r'<span class="nb">(.*?)</span>', r"\1", html)


def _sha(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def verdict_word(html: str) -> str:
    """What the page's first verdict box (the overall one when there are several sections) says
    first: its finding when it has one (beside the word passed, FAILED or information), else the
    word."""
    m = re.search(r'<p class="word">(.*?)</p>\s*(?:<p class="finding">(.*?)</p>)?', html, re.S)
    assert m, "no verdict"
    return html_lib.unescape(re.sub(r"<[^>]+>", "", m.group(2) or m.group(1))).strip()


def check_page(path, inputs, n_figures, verdict):
    """The page parses, holds ``n_figures`` embedded PNGs and no external URL, its first
    verdict (before any figure) says exactly ``verdict``, and it lists each input's SHA-256."""
    html = plain(Path(path).read_text(encoding="utf-8"))
    p = _Page()
    p.feed(html)
    p.close()
    assert p.tags[0] == "html" and "script" not in p.tags and "link" not in p.tags
    assert '<meta name="viewport"' in html and "@media print" in html
    assert len(p.imgs) == n_figures and all(s.startswith("data:image/png;base64,") for s in p.imgs)
    assert not [u for u in p.urls if u.lower().startswith(("http:", "https:", "//"))]
    text = " ".join(p.text)
    first_fig = html.index("<img") if n_figures else len(html)
    assert verdict_word(html[:first_fig]) == verdict
    for f in inputs:
        assert _sha(f) in text
    return text


def _ok(r):
    assert r.exit_code == 0, r.output
    return r


def test_fit_plane_report(tmp_path):
    cloud = DATA_DIR / "measured" / "datum.ply"
    out = tmp_path / "fit.html"
    _ok(runner.invoke(app, ["fit-plane", str(cloud), "--report", str(out), "--seed", "3"]))
    # no flatness tolerance is stated: the verdict says what was found, never "tolerance"
    text = check_page(out, [cloud], 1, "flat within the noise")
    html = plain(out.read_text(encoding="utf-8"))
    assert "tolerance" not in html[:html.index("<img")]
    assert "<tr><th>seed</th><td>3</td></tr>" in html and f"numpy {np.__version__}" in text
    assert f'class="command">$ metro fit-plane {cloud} --seed 3 --report {out}<' in html
    d = json.loads(_ok(runner.invoke(app, ["fit-plane", str(cloud), "--seed", "3", "--json"])).output)
    assert f"RMS {d['rms_mm']:.4f} mm, flatness (P-V) {d['flatness_mm']:.4f} mm over {d['n_inliers']} of 2500 points" in text


def test_fit_plane_report_names_the_form_of_a_bowed_plate(tmp_path):
    """A plate bowed by a known paraboloid (analytic truth, 5 µm noise): the verdict is the
    form detected with its P-V in µm, within 10 % of the truth's P-V over the same points."""
    rng = np.random.default_rng(7)
    u, v = rng.uniform(-100.0, 100.0, (2, 3000))  # mm
    bow = 2.5e-6 * (u**2 + v**2)  # mm: 50 µm at the corners
    xyz = np.column_stack([u + 500.0, v - 200.0, 40.0 + bow + rng.normal(0.0, 0.005, u.size)])
    cloud = tmp_path / "bowed.xyz"
    np.savetxt(cloud, xyz, fmt="%.6f")
    out = tmp_path / "fit.html"
    _ok(runner.invoke(app, ["fit-plane", str(cloud), "--report", str(out)]))
    word = verdict_word(out.read_text(encoding="utf-8"))
    m = re.fullmatch(r"form detected: ([0-9.]+) µm P-V", word)
    assert m, word
    truth_um = 1e3 * (bow.max() - bow.min())
    assert abs(float(m.group(1)) - truth_um) < 0.1 * truth_um, (word, truth_um)


@pytest.fixture(scope="module")
def calibrate_report(tmp_path_factory):
    """``metro calibrate --report --plot`` on 16 poses (a fast fit): the result, the report, the export, the folder;
    made once for the report's text checks and its check in Chromium."""
    folder = tmp_path_factory.mktemp("calibrate")
    export = write_rows(folder / "cal.csv", export_rows(CAL)[:17])
    out = folder / "calibrate.html"
    r = _ok(runner.invoke(app, ["calibrate", str(export), "--plane", str(PLANE), "--layout", str(NOMINAL),
                                "--report", str(out), "--plot", str(folder / "c.pdf")]))
    return r, out, export, folder


def test_calibrate_report_names_the_cause_and_the_next_command(calibrate_report):
    """And ``--plot c.pdf`` is one PDF file, a page per figure (as fit-plane writes one file)."""
    r, out, export, folder = calibrate_report
    pdf = (folder / "c.pdf").read_bytes()
    assert pdf.startswith(b"%PDF") and b"/Count 2" in pdf
    # no target set: the residuals against the stated noise (model adequacy) and the default
    # precision target are information, each its own line, not a failed tolerance
    text = check_page(out, [export, PLANE, NOMINAL], 2, "overall: information")  # the certificate, the calibration
    html = plain(out.read_text(encoding="utf-8"))
    assert "tolerance" not in html[:html.index("<img")].lower()
    assert re.search(r'<li class="note"><span class="tag">note</span> model adequacy: L1 residual RMS', html)
    assert re.search(r'<li class="note"><span class="tag">note</span> precision target: zero points', html)
    # the measured run's residuals exceed the stated noise (its truth has effects the base model lacks)
    assert "metro diagnose" in text and "reduced χ²" in text
    assert r.stderr.strip().splitlines()[-1] == f"report: {out}"
    # with a precision target met, "overall: passed": checked on the report of the test below
    assert "[[Fit Statistics]]" in r.output and "reduced chi-square" in r.output and "[[Correlations]]" in r.output


def test_validate_report_judges_the_tolerance_and_names_the_poses_left_out(tmp_path):
    out = tmp_path / "val.html"
    r = _ok(runner.invoke(app, ["validate", str(VAL), "--plane", str(PLANE), "--layout", str(TRUTH), "--layout-before",
                                str(NOMINAL), "--report", str(out), "--tolerance-deg", "0.1"]))
    text = check_page(out, [VAL, PLANE, TRUTH, NOMINAL], 1, "passed")
    d = json.loads(_ok(runner.invoke(app, ["validate", str(VAL), "--plane", str(PLANE), "--layout", str(TRUTH),
                                           "--json"])).output)
    gone = [p for p, n in zip(d["pose_id"], d["n_readings"]) if n < 3]
    assert gone and all(p in text for p in gone) and all(p in r.output for p in gone)
    assert "truth.toml (validated)" in text and "nominal.toml (before)" in text
    # the text output names the layouts in the same words (not the internal labels)
    rows = [line.split()[:2] for line in r.output.splitlines()[1:3]]
    assert rows == [["nominal.toml", "(before)"], ["truth.toml", "(validated)"]] and "layout_before" not in r.output
    # a tolerance below the largest deviation turns the verdict
    tight = d["layouts"]["layout"]["max_deg"] / 2
    r = runner.invoke(app, ["validate", str(VAL), "--plane", str(PLANE), "--layout", str(TRUTH), "--report", str(out),
                            "--tolerance-deg", f"{tight:.6f}"])
    assert r.exit_code == 1, r.output
    check_page(out, [VAL], 1, "FAILED")
    assert '<li class="fail"><span class="tag">FAIL</span> drilling tolerance: max normal deviation' in out.read_text()


def test_same_inputs_same_bytes(tmp_path, monkeypatch):
    """With ``SOURCE_DATE_EPOCH`` set (the time written), a report is byte-identical run to run."""
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    pages = []
    out = tmp_path / "v.html"
    for _ in range(2):
        _ok(runner.invoke(app, ["validate", str(VAL), "--plane", str(PLANE), "--layout", str(TRUTH), "--report", str(out)]))
        pages.append(out.read_bytes())
    assert pages[0] == pages[1] and "2023-11-14 22:13:20 UTC" in plain(pages[0].decode("utf-8"))


@pytest.mark.slow
def test_demo_report_end_to_end(tmp_path):
    """The real demo with ``--report``: one page of the steps that write one (simulate-log writes a
    log), each step's own report beside it."""
    out = tmp_path / "demo.html"
    _ok(runner.invoke(app, ["demo", "--out", str(tmp_path / "o"), "--report", str(out)]))
    # fit-plane 1, calibrate 2, validate 1, diagnose 2, the calibration with diagnose's terms 2, normals 1, measure 2
    text = check_page(out, [CAL.parent / "datum.ply", CAL, VAL, NOMINAL], 11, "overall: passed")
    for name in ("fit-plane", "calibrate", "validate", "diagnose", "normals", "measure"):
        assert f"(metro {name})" in text and (tmp_path / "o" / f"{name}.html").exists()


def test_normals_report(tmp_path):
    out = tmp_path / "n.html"
    panel, layout = DATA_DIR / "panel_cyl800.stl", DATA_DIR / "layout_table6.toml"
    _ok(runner.invoke(app, ["normals", str(panel), "--layout", str(layout), "--grid", "80", "--report", str(out),
                            "--engine", "trimesh"]))
    text = check_page(out, [panel, layout], 1, "passed")
    # every fact of the text output is on the page, and the caption promises no mark it does not draw
    r = _ok(runner.invoke(app, ["normals", str(panel), "--layout", str(layout), "--grid", "80", "--engine", "trimesh"]))
    page = html_lib.unescape(" ".join(text.split()))
    for line in r.stdout.splitlines():
        if not line.startswith(("verdict:", "  [")):
            assert " ".join(line.split()) in page, line
    assert "grey ×" not in text and "each method on its own colour scale" in text


def test_demo_report_gathers_each_step_and_links_its_own(tmp_path):
    """``run_demo(report=...)`` with steps that each write a report: one page of every step's
    section, each linked to the step's own report (the steps themselves are tested above)."""
    from metrology.jobs.demo import DEMO_STEPS, STEP_REPORTS, run_demo
    from metrology.report.html import Headline, Section, run_info, write_report

    def step(args):
        if "--report" not in args:  # a step that writes no report (simulate-log)
            return 0
        path = args[args.index("--report") + 1]
        write_report(path, args[0], run_info({"export": CAL}, "metro " + " ".join(args)),
                     [Section(f"step {args[0]}", Headline(args[0] != "validate", f"{args[0]} headline"))])
        return 0

    out = tmp_path / "demo.html"
    assert run_demo(DATA_DIR, tmp_path / "o", step, lambda *a: None, report=out) == 0
    text = check_page(out, [CAL], 0, "overall: FAILED")  # one step failed: the overall verdict
    for (cmd, _), name in zip((line.split(maxsplit=1) for _, line in DEMO_STEPS), STEP_REPORTS):
        if name is None:
            continue
        assert f"{cmd} headline" in text and (tmp_path / "o" / name).exists()
        assert f'href="o/{name}"' in out.read_text()


@pytest.mark.parametrize("name", ["r.txt", "nodir/r.html"])
def test_a_bad_report_path_is_one_line_exit_2_before_any_work(tmp_path, name):
    r = runner.invoke(app, ["validate", str(VAL), "--plane", str(PLANE), "--layout", str(TRUTH), "--report",
                            str(tmp_path / name)])
    assert r.exit_code == 2 and r.output.startswith("error: --report") and len(r.output.splitlines()) == 1
    assert sorted(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args", [
    ["calibrate", str(CAL), "--plane", str(PLANE), "--layout", str(NOMINAL), "--plot", "{tmp}/c.png"],
    ["calibrate", str(CAL), "--plane", str(PLANE), "--layout", str(NOMINAL), "--plot", "{tmp}/no/c.pdf"],
    ["demo", "--out", "{tmp}/o", "--report", "{tmp}/demo.txt"],
])
def test_a_bad_output_is_refused_before_any_work(tmp_path, args):
    r = runner.invoke(app, [a.format(tmp=tmp_path) for a in args])
    assert r.exit_code == 2 and r.output.startswith("error: ") and len(r.output.splitlines()) == 1
    assert sorted(tmp_path.iterdir()) == []


def test_escaping_and_backticks():
    from metrology.report.html import Headline, Section, render_html, run_info

    html = render_html("t <x>", run_info({}, "metro x"), [Section("s", Headline(None, "a < b & c", "run `metro diagnose`"))])
    assert "a &lt; b &amp; c" in html and "<code>metro diagnose</code>" in html and "t &lt;x&gt;" in html


def _report_of(command, tmp_path, request) -> Path:
    """``command``'s HTML report on a small input (seconds each; the real demo takes half a minute)."""
    out = tmp_path / f"{command}.html"
    if command == "calibrate":  # the report the text checks read (the same command, with --plot)
        shutil.copy(request.getfixturevalue("calibrate_report")[1], out)
        return out
    if command == "fit-plane":
        args = ["fit-plane", str(DATA_DIR / "measured" / "datum.ply")]
    elif command == "validate":
        args = ["validate", str(VAL), "--plane", str(PLANE), "--layout", str(TRUTH), "--layout-before", str(NOMINAL)]
    elif command == "normals":
        args = ["normals", str(DATA_DIR / "panel_cyl800.stl"), "--layout", str(DATA_DIR / "layout_table6.toml"),
                "--grid", "80", "--engine", "trimesh"]
    elif command == "diagnose":
        layout = DATA_DIR / "hidden" / "layout.toml"
        plane = DATA_DIR / "hidden" / "plane.json"
        _ok(runner.invoke(app, ["simulate", "--layout", str(layout), "--plane", str(plane), "--out",
                                str(tmp_path / "x.csv"), "--effect", "drift", "--sensor", "L3", "--size", "0.01",
                                "--poses", "40", "--seed", "2"]))
        args = ["diagnose", str(tmp_path / "x.csv"), "--plane", str(plane), "--layout", str(layout), "--folds", "3"]
    elif command == "measure":  # a drift alarm: its tables (issue 51: clipped at 1280 and 412 px)
        _ok(runner.invoke(app, ["simulate-log", "--holes", "3600", "--shift", "L3:0.015@3000", "--seed", "1",
                                "--out", str(tmp_path / "log.csv"), "--no-truth"]))
        args = ["measure", str(tmp_path / "log.csv"), "--layout", str(DATA_DIR / "measured" / "nominal.toml"),
                "--min-radius-mm", "inf", "--out", str(tmp_path / "h.csv")]
    elif command == "measure-panel":  # the panel map
        wing, holes = str(DATA_DIR / "panels" / "wing.stl"), str(DATA_DIR / "panels" / "wing.holes.csv")
        _ok(runner.invoke(app, ["simulate-log", "--panel", wing, "--points", holes, "--holes", "40", "--seed", "1",
                                "--out", str(tmp_path / "log.csv"), "--no-truth"]))
        args = ["measure", str(tmp_path / "log.csv"), "--layout", str(DATA_DIR / "measured" / "nominal.toml"),
                "--panel", wing, "--points", holes, "--out", str(tmp_path / "h.csv")]
    else:
        args = ["demo", "--out", str(tmp_path / "o")]
    r = runner.invoke(app, args + ["--report", str(out)])
    assert r.exit_code in ((0, 1) if command.startswith("measure") else (0,)), r.output  # measure: holes may fail
    return out


@pytest.mark.skipif(shutil.which("chromium") is None, reason="needs a chromium binary (a developer's check)")
@pytest.mark.parametrize("command", ["fit-plane", "calibrate", "validate", "normals", "measure", "measure-panel",
                                     pytest.param("diagnose", marks=pytest.mark.slow),
                                     pytest.param("demo", marks=pytest.mark.slow)])
def test_reports_open_in_chromium_without_console_error_or_request(tmp_path, command, request):
    """Every command's report in headless Chromium at 1280 px and a phone's width: no console
    message, no request, no clipped text, figure text of 9 pt or more at 1280 px, a screenshot
    each (diagnose and the real demo are slow: marked so)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "check_reports_browser", Path(__file__).parents[2] / "benchmarks" / "check_reports_browser.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = _report_of(command, tmp_path, request)
    assert mod.main([str(out), "--widths", "1280,412", "--height", "900"]) == 0
    for width in (1280, 412):
        assert out.with_name(f"{out.stem}-{width}.png").stat().st_size > 0


def test_report_figures_are_drawn_to_the_column_with_9_pt_text():
    """A figure wider than the page's column is drawn at the column's width, every text at 9 pt
    or more, and the page states its smallest text (what the Chromium check turns into pt)."""
    from metrology.report.html import COLUMN_IN, MIN_FIGURE_PT, figure_from_matplotlib
    from metrology.report.style import pyplot

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(13, 4))
    ax.plot([0, 1], [0, 1], label="a line")
    ax.legend(fontsize=6)
    ax.set_title("small", fontsize=5)
    f = figure_from_matplotlib(fig, "caption")
    import base64
    import io

    from matplotlib.image import imread

    png = imread(io.BytesIO(base64.b64decode(f.data_uri.split(",", 1)[1])))
    assert png.shape[1] == round(COLUMN_IN * 96)  # 960 px: shown at its own size at 1280 px
    assert f.min_font_px == pytest.approx(MIN_FIGURE_PT * 96 / 72)


def test_calibrate_report_tables_name_each_sensor_from_its_fit_not_its_title(tmp_path, monkeypatch):
    """The tables' sensor column is each fit's ``sensor`` field: a title that does not begin with
    the sensor's name (it was read back with ``title.split()[0]``) changes nothing. The same report
    (one calibrate less a run) is the one with a precision target met: ``overall: passed``."""
    from dataclasses import replace

    import metrology.report.calibration as calib

    made = calib.fit_summaries

    def retitled(report):
        fits = made(report)
        assert [f.sensor for f in fits] == list(report.calibration.layout.names)
        return [replace(f, title=f"zero error and beam tilt of {f.sensor}") for f in fits]

    monkeypatch.setattr(calib, "fit_summaries", retitled)
    export = write_rows(tmp_path / "cal.csv", export_rows(CAL)[:17])
    out = tmp_path / "cal.html"
    _ok(runner.invoke(app, ["calibrate", str(export), "--plane", str(PLANE), "--layout", str(NOMINAL),
                            "--report", str(out), "--target-mm", "1", "--target-deg", "1"]))
    check_page(out, [export], 2, "overall: passed")
    assert '<li class="pass"><span class="tag">pass</span> precision target: zero points' in out.read_text()
    html = plain(out.read_text(encoding="utf-8"))
    table = html[html.index("Fit statistics per sensor"):]
    table = table[:table.index("</table>")]
    assert re.findall(r"<tr><td>([^<]*)</td>", table) == ["L1", "L2", "L3", "L4"]
    assert "<td>zero</td>" not in html
