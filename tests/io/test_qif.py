"""metro measure --qif: a QIF 3.0 Results document, validated against the QIF 3.0 XSD files of the
Quality Information Framework's public qif-community repository (tests/data/qif3/, see SOURCE.md)."""

import hashlib
import json
import math
import xml.etree.ElementTree as ET

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.layout import save_layout
from tests.io.qif_schema import qif_schema
from tests.measure.helpers import calibrated_layout, hole_log, write_log_csv

xmlschema = pytest.importorskip("xmlschema")
runner = CliRunner()
Q = "{http://qifstandards.org/xsd/qif3}"


@pytest.fixture(scope="session")
def schema(request):
    # built once a worker, or read from pytest's cache when an earlier run built the same one
    cache = getattr(request.config, "cache", None)  # None with -p no:cacheprovider
    return qif_schema(xmlschema, cache.mkdir("metro-qif3-schema") if cache is not None else None)


@pytest.fixture
def layout(tmp_path):
    p = tmp_path / "calibrated.toml"
    save_layout(calibrated_layout(), p)
    return p


def _measure(tmp_path, layout, log, *extra, out="h.parquet", qif="r.qif"):
    r = runner.invoke(app, ["measure", str(log), "--layout", str(layout), "--out", str(tmp_path / out),
                            "--qif", str(tmp_path / qif), "--json", *extra])
    return r


def _mixed_log(tmp_path):
    """Holes that conform, fail, are undecided and not measured (a blank reading pair)."""
    lay = calibrated_layout()
    cols, _, _ = hole_log(lay, n=120, seed=3, angle_deg=(0.5, 4), after_deg=(0.0, 0.9))
    cols["hole_id"][7] = "H<7>&'\""  # escaped in the document
    for s in ("L1", "L2"):
        cols[f"d_{s}"][11] = None
        cols[f"d_{s}_after"][11] = None
    cols["d_L3_after"][13] += 0.4  # a gross after-reading: the drilled angle not known (not measured)
    cols["d_L2_after"][17] += 0.04  # before and after disagree (rule 3)
    return write_log_csv(cols, tmp_path / "log.csv")


def test_a_valid_qif_results_document_with_every_hole(tmp_path, layout, schema):
    log = _mixed_log(tmp_path)
    r = _measure(tmp_path, layout, log)
    assert r.exit_code == 1, r.output  # some holes fail
    summary = json.loads(r.stdout)
    qif = tmp_path / "r.qif"
    schema.validate(str(qif))  # raises with the first error
    holes = pq.read_table(tmp_path / "h.parquet").to_pylist()
    root = ET.parse(qif).getroot()
    assert root.tag == Q + "QIFDocument" and root.get("versionQIF") == "3.0.0"
    items = root.findall(f"{Q}Characteristics/{Q}CharacteristicItems/{Q}AngleCharacteristicItem")
    meas = root.findall(f".//{Q}CharacteristicMeasurements/{Q}AngleCharacteristicMeasurement")
    assert len(items) == len(meas) == len(holes) == 120
    assert root.find(f"{Q}Characteristics/{Q}CharacteristicItems").get("n") == "120"
    assert int(root.get("idMax")) == max(int(e.get("id")) for e in root.iter() if e.get("id") is not None)
    want = {"conforms": "PASS", "fails": "FAIL", "undecided": "INDETERMINATE", "not_measured": "NOT_ANALYZED"}
    seen = set()
    for item, m, h in zip(items, meas, holes):
        assert item.findtext(f"{Q}Name") == h["hole_id"]
        assert m.findtext(f"{Q}CharacteristicItemId") == item.get("id")
        assert m.findtext(f"{Q}Status/{Q}CharacteristicStatusEnum") == want[h["status"]]
        seen.add(h["status"])
        after = h["angle_after_deg"] is not None
        angle = h["angle_after_deg"] if after else h["angle_deg"]
        u95 = h["U95_after_deg"] if after else h["U95_angle_deg"]
        value = m.findtext(f"{Q}Value")
        if h["status"] == "not_measured":  # no judged figure, in the results or the document (issue 51)
            assert value is None and m.find(f"{Q}Attributes") is None
            assert h["angle_after_deg"] is None and h["U95_after_deg"] is None
        else:
            assert float(value) == pytest.approx(angle, abs=5e-7)
            # QIF's own standard uncertainty on the value (U95 / k, k = 2), and the U95 itself
            v = m.find(f"{Q}Value")
            assert float(v.get("combinedUncertainty")) == pytest.approx(u95 / 2, abs=5e-7)
            assert v.get("meanError") == "0"
            attr = m.find(f"{Q}Attributes/{Q}AttributeD1")
            assert attr.get("name") == "U95_deg" and float(attr.get("value")) == pytest.approx(u95, abs=5e-7)
        assert m.findtext(f"{Q}TimeStamp").startswith(h["time"].strftime("%Y-%m-%dT%H:%M:%S"))  # a timestamp column
    assert seen == set(want), seen  # every status is exercised
    assert sum(h["status"] == "not_measured" for h in holes) >= 2
    assert summary["counts_detail"]["unknown_after"] >= 1  # a hole whose drilled angle is not known
    assert summary["counts"]["fails"] > 0
    assert root.find(f".//{Q}InspectionStatus/{Q}InspectionStatusEnum").text == "FAIL"
    tol = root.find(f".//{Q}AngleCharacteristicDefinition/{Q}Tolerance")
    assert float(tol.findtext(f"{Q}MaxValue")) == 0.5 and float(tol.findtext(f"{Q}MinValue")) == 0.0
    device = root.find(f"{Q}MeasurementResources/{Q}MeasurementDevices/{Q}MeasurementDevice")
    attrs = {a.get("name"): a.get("value") for a in device.find(f"{Q}Attributes")}
    assert attrs["calibration_sha256"] == hashlib.sha256(layout.read_bytes()).hexdigest()
    assert attrs["sensors"] == "L1 L2 L3 L4"
    uris = [e.text for e in root.iter(Q + "URI")]
    assert uris == [log.resolve().as_uri(), layout.resolve().as_uri()]
    assert root.find(f"{Q}StandardsDefinitions/{Q}Standard/{Q}Designator").text == "14253-1"


def test_the_schema_catches_a_broken_document(tmp_path, layout, schema):
    """The validation is not a formality: a dangling reference and an unknown status are refused."""
    log = _mixed_log(tmp_path)
    assert _measure(tmp_path, layout, log).exit_code == 1
    text = (tmp_path / "r.qif").read_text(encoding="utf-8")
    assert schema.is_valid(text)
    dangling = text.replace("<CharacteristicItemId>7</CharacteristicItemId>",
                            "<CharacteristicItemId>999999</CharacteristicItemId>", 1)
    assert dangling != text and not schema.is_valid(dangling)
    unknown = text.replace("<CharacteristicStatusEnum>PASS<", "<CharacteristicStatusEnum>OK<", 1)
    assert unknown != text and not schema.is_valid(unknown)


def test_same_inputs_same_bytes_and_a_partitioned_log(tmp_path, layout, schema):
    """A folder log into a folder output: the document is made from the partitions' files, in
    the log's order; two runs give the same bytes."""
    lay = calibrated_layout()
    for k, cell in enumerate(("C1", "C2")):
        cols, _, _ = hole_log(lay, n=150, seed=k, cells=(cell,), angle_deg=(1, 4), after_deg=(0.0, 0.3))
        d = tmp_path / "log" / f"cell={cell}"
        d.mkdir(parents=True)
        pq.write_table(pa.table(cols).drop_columns(["cell"]), d / "part-0.parquet")
    r1 = _measure(tmp_path, layout, tmp_path / "log", out="one", qif="one.qif")
    r2 = _measure(tmp_path, layout, tmp_path / "log", out="two", qif="two.qif")
    assert r1.exit_code == r2.exit_code == 0, r1.output
    a, b = (tmp_path / "one.qif").read_bytes(), (tmp_path / "two.qif").read_bytes()
    assert a == b
    schema.validate(str(tmp_path / "one.qif"))
    names = [e.text for e in ET.fromstring(a).iter(Q + "Name") if e.text.startswith("C")]
    assert names == [f"C1-{i:06d}" for i in range(150)] + [f"C2-{i:06d}" for i in range(150)]


def test_bad_qif_paths_exit_2_before_anything_is_written(tmp_path, layout):
    log = _mixed_log(tmp_path)
    for qif, says in ((tmp_path / "no" / "r.qif", "does not exist"), (tmp_path / "r.txt", "must be one of")):
        r = runner.invoke(app, ["measure", str(log), "--layout", str(layout), "--out", str(tmp_path / "h.parquet"),
                                "--qif", str(qif)])
        assert r.exit_code == 2, r.output
        assert says in r.output and "Traceback" not in r.output
    assert not (tmp_path / "h.parquet").exists()


def test_a_failed_run_leaves_no_document(tmp_path, layout):
    """Another head's layout (the readings disagree with one plane): refused, no file, no spool."""
    lay = calibrated_layout()
    other = lay.with_params(lay.zero + [[0.4, 0, 0], [0, 0.4, 0], [0, 0, 0.4], [0.2, 0.2, 0]], lay.direction)
    save_layout(other, layout)
    cols, _, _ = hole_log(lay, n=60, seed=1, angle_deg=(0.5, 2))
    log = write_log_csv(cols, tmp_path / "log.csv")
    r = _measure(tmp_path, layout, log, "--min-radius-mm", "inf")
    assert r.exit_code == 2, r.output
    assert "disagree with one plane" in r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["calibrated.toml", "log.csv"]


def test_decimal_formatting_has_no_exponent():
    from metrology.io.qif import _decimal

    got = _decimal(np.array([1e-7, 2.6e-6, 0.5, 12.3456789, math.nan, 0.0])).to_pylist()
    assert got == ["0.000000", "0.000003", "0.500000", "12.345679", None, "0.000000"]


def test_calibrate_qif_is_the_device_measure_qif_names(tmp_path, schema):
    """calibrate --qif: the calibrated head as a QIF measurement device, valid, whose SHA-256 is the
    calibrated layout's, the one measure --qif names."""
    from metrology.io.data import data_path

    d = data_path("measured", "calibration.csv").parent
    r = runner.invoke(app, ["calibrate", str(d / "calibration.csv"), "--plane", str(d / "plane.json"), "--layout",
                            str(d / "nominal.toml"), "--out", str(tmp_path / "cal.toml"), "--qif",
                            str(tmp_path / "cal.qif"), "--meta", "part=EE-7 foot", "--meta", "serial=SN42"])
    assert r.exit_code in (0, 1), r.output
    schema.validate(str(tmp_path / "cal.qif"))
    dev = ET.parse(tmp_path / "cal.qif").getroot().find(f".//{Q}MeasurementDevice")
    attrs = {a.get("name"): a.get("value") for a in dev.find(f"{Q}Attributes")}
    sha = hashlib.sha256((tmp_path / "cal.toml").read_bytes()).hexdigest()
    assert attrs["calibration_sha256"] == sha and attrs["method"] == "lsq"
    assert dev.findtext(f"{Q}Name") == "EE-7 foot" and dev.findtext(f"{Q}SerialNumber") == "SN42"
    from metrology.io.layout import load_layout

    lay = load_layout(tmp_path / "cal.toml")
    assert [float(v) for v in attrs["L2.zero_mm"].split()] == pytest.approx(lay.zero[1], abs=1e-6)
    cols, _, _ = hole_log(lay, n=50, seed=2, angle_deg=(0.1, 0.3))
    log = write_log_csv(cols, tmp_path / "log.csv")
    r = runner.invoke(app, ["measure", str(log), "--layout", str(tmp_path / "cal.toml"), "--out",
                            str(tmp_path / "h.csv"), "--qif", str(tmp_path / "r.qif")])
    assert r.exit_code in (0, 1), r.output
    dev = ET.parse(tmp_path / "r.qif").getroot().find(f".//{Q}MeasurementDevice")
    assert {a.get("name"): a.get("value") for a in dev.find(f"{Q}Attributes")}["calibration_sha256"] == sha


def test_an_id_with_a_control_character_still_makes_well_formed_xml(tmp_path, schema):
    from metrology.io.qif import QifResults

    t = pa.table({"hole_id": ["A\x01B", "C"], "angle_deg": [0.1, 0.2], "U95_angle_deg": [0.01, 0.01],
                  "angle_after_deg": [None, None], "U95_after_deg": [None, None],
                  "status": ["conforms", "conforms"], "time": [1.7e9, 1.7e9 + 1]},
                 schema=pa.schema([("hole_id", pa.string()), ("angle_deg", pa.float64()),
                                   ("U95_angle_deg", pa.float64()), ("angle_after_deg", pa.float64()),
                                   ("U95_after_deg", pa.float64()), ("status", pa.string()), ("time", pa.float64())]))
    lay = tmp_path / "l.toml"
    save_layout(calibrated_layout(), lay)
    with QifResults(tmp_path / "r.qif", tolerance_deg=0.5, layout_path=lay, sensors=("L1", "L2", "L3", "L4"),
                    log="log.csv") as q:
        q.write(t)
    schema.validate(str(tmp_path / "r.qif"))
    items = ET.parse(tmp_path / "r.qif").getroot().findall(f".//{Q}AngleCharacteristicItem/{Q}Name")
    assert [e.text for e in items] == ["A\ufffdB", "C"]
