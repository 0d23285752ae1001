"""Per-hole results as a QIF 3.0 Results document (ANSI/DMSC QIF 3.0, ISO 23952:2020): what a
factory's quality system imports.

The document (``metro measure --qif RESULTS.qif``; its shape is shown in docs/measure.md):

- ``MeasurementResources``: the head as one ``MeasurementDevice``, its sensors, and the SHA-256 of
  its calibrated layout file (the calibration it measured with) as attributes;
- ``Characteristics``: one definition (the angle between drill axis and surface normal, tolerance
  ``0 .. tolerance_deg``, deg), one nominal (target 0 deg), and one ``AngleCharacteristicItem`` per
  hole, named by its ``hole_id``;
- ``Results``: one ``MeasurementResults`` whose traceability names the log, the layout and, with
  ``--panel``/``--points``, the CAD panel and the hole table (file references with their SHA-256,
  metro's version), with one ``AngleCharacteristicMeasurement`` per hole: the ISO
  14253-1 status (conforms PASS, fails FAIL, undecided INDETERMINATE, not measured NOT_ANALYZED),
  the hole's time, the judged angle (deg) as ``Value`` with QIF's own ``combinedUncertainty`` (the
  standard uncertainty U95 / 2, :data:`COVERAGE_K`; ``meanError`` 0) and its U95 (deg) as the
  attribute ``U95_deg``; a hole not measured has no ``Value`` and no ``U95_deg``; the whole inspection's status (FAIL if a hole fails, else UNKNOWN if a hole is
  undecided or not measured, else PASS).

Why an angle characteristic: QIF's perpendicularity and angularity characteristics are tolerance
zones in length units, whose value needs a reference length (the hole's depth) that a log does not
carry; the measurand here is an angle, and QIF's ``AngleCharacteristic`` carries it, in degrees,
with its angular tolerance.

Written streamed and atomically: the holes' items and measurements go, batch by batch, to two
spool files beside the target as pyarrow string arrays formatted in bulk (no tree of all holes in
memory); :meth:`QifResults.close` writes the head (which needs the counts), the two spools and
the tail into a temporary file renamed onto the target. ``id`` numbers: the standard (ISO 14253-1) 1,
metro as software 2, definition 3, nominal 4, device 5, results 6, then hole ``k`` (0-based, in log
order) item ``7 + 2k``, measurement ``8 + 2k``.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import uuid
from pathlib import Path
from xml.sax.saxutils import escape, quoteattr

import numpy as np

from metrology.io.names import sha256_file, utc

__all__ = ["QifResults", "QIF_STATUS", "check_qif_path", "write_device_document"]

NS = "http://qifstandards.org/xsd/qif3"
#: metro's hole status -> QIF CharacteristicStatusEnum (ISO 14253-1's three outcomes, and no outcome)
QIF_STATUS = {"conforms": "PASS", "fails": "FAIL", "undecided": "INDETERMINATE", "not_measured": "NOT_ANALYZED"}
_FIRST_HOLE_ID = 7
#: holes formatted at once: their text (~600 bytes a hole) and its temporaries stay small
SLICE_ROWS = 32768
_DIGITS = 6  # decimals of an angle in deg (1e-6 deg: far below any U95)
#: how the traceability describes an input file by its role
INPUT_SPECS = {"CAD panel": "CAD panel (STL, OBJ, PLY, GLB or STEP), mm",
               "hole table": "hole table (CSV or Parquet: hole_id,x,y,z,i,j,k), mm"}
#: QIF's ``combinedUncertainty`` is a standard uncertainty (GUM's u_c): the U95 over the coverage factor k = 2
#: of a 95 % interval; ``meanError`` 0 beside it (the schema asks for both: the calibration removed the bias)
COVERAGE_K = 2.0


def check_qif_path(path) -> Path:
    """Refuse, before any work, a QIF path that cannot be written (ValueError, one line)."""
    from metrology.io.atomic import check_output_file

    return check_output_file(path, "--qif", {".qif", ".xml"})


def _decimal(x: np.ndarray):
    """(N,) float >= 0 -> pyarrow strings in fixed point with :data:`_DIGITS` decimals (xs:decimal has
    no exponent), null where NaN."""
    import pyarrow as pa
    import pyarrow.compute as pc

    ok = np.isfinite(x)
    q = np.where(ok, np.round(np.abs(np.where(ok, x, 0.0)) * 10 ** _DIGITS), 0).astype(np.int64)
    whole = pa.array(q // 10 ** _DIGITS).cast(pa.string())
    frac = pc.utf8_lpad(pa.array(q % 10 ** _DIGITS).cast(pa.string()), _DIGITS, "0")
    sign = pa.array(np.where(ok & (x < 0) & (q > 0), "-", ""))
    return pc.if_else(pa.array(ok), pc.binary_join_element_wise(sign, whole, ".", frac, ""), pa.nulls(len(x), pa.string()))


def _join(*parts):
    """Element-wise concatenation of string arrays and plain strings."""
    import pyarrow.compute as pc

    return pc.binary_join_element_wise(*parts, "")


def _write_strings(fh, arr) -> None:
    """Write the concatenation of a string array without nulls (its data buffer, no Python strings)."""
    import pyarrow as pa

    arr = arr.combine_chunks() if isinstance(arr, pa.ChunkedArray) else arr
    if len(arr) == 0:
        return
    if arr.null_count:
        raise AssertionError("a QIF line is null")
    offsets = np.frombuffer(arr.buffers()[1], dtype=np.int32 if arr.type == pa.string() else np.int64)
    lo, hi = int(offsets[arr.offset]), int(offsets[arr.offset + len(arr)])
    fh.write(memoryview(arr.buffers()[2])[lo:hi])


def _times(col):
    """xs:dateTime strings (UTC, microseconds) of a ``time`` column (seconds, timestamps or ISO 8601),
    and the seconds (N,) float since 1970-01-01 UTC."""
    import pyarrow as pa
    import pyarrow.compute as pc

    from metrology.io.holelog_reader import time_seconds

    s = time_seconds(col)
    us = pa.array(np.round(s * 1e6).astype(np.int64)).cast(pa.timestamp("us", tz="UTC"))
    return _join(pc.strftime(us, format="%Y-%m-%dT%H:%M:%S", locale="C"), "Z"), s


class QifResults:
    """A QIF 3.0 Results document written as holes come (a context manager).

    Parameters
    ----------
    path : the ``.qif`` file (written only when the block ends without error)
    tolerance_deg : float, deg, the angle tolerance the holes were judged against
    layout_path : the calibrated layout file (its SHA-256 identifies the calibration)
    sensors : tuple of str, the head's sensors
    log : str, the log as named on the command line (traceability)
    certificate : dict, the layout's ``[certificate]`` fields (device name, serial, ...)
    version : str, metro's version
    inputs : dict, role -> path of the other input files (the CAD panel, the hole table): each listed
        with its SHA-256 in the traceability
    """

    def __init__(self, path, *, tolerance_deg: float, layout_path, sensors, log: str, certificate=None,
                 version: str = "", inputs=None):
        self.path = Path(path)
        self.tolerance_deg = float(tolerance_deg)
        self.layout_path = Path(layout_path)
        self.layout_sha256 = sha256_file(layout_path)
        self.sensors = tuple(sensors)
        self.log = str(log)
        self.certificate = dict(certificate or {})
        self.version = version
        self.inputs = tuple((role, Path(p), sha256_file(p)) for role, p in (inputs or {}).items() if p is not None)
        self.n = 0
        self.counts = dict.fromkeys(QIF_STATUS, 0)
        self.t_first = self.t_last = None
        self._dir = None

    def __enter__(self):
        self._dir = tempfile.mkdtemp(prefix=f".{self.path.name}.", dir=self.path.resolve().parent)
        self._items = open(os.path.join(self._dir, "items"), "wb")
        self._meas = open(os.path.join(self._dir, "measurements"), "wb")
        return self

    def write(self, table) -> None:
        """Add the holes of a per-hole results table (``hole_id``, ``angle_deg``, ``U95_angle_deg``,
        ``angle_after_deg``, ``U95_after_deg``, ``status``, ``time``), in log order."""
        for start in range(0, table.num_rows, SLICE_ROWS):  # the text of a slice: ~20 MB at most
            self._write(table.slice(start, SLICE_ROWS))

    def _write(self, table) -> None:
        import pyarrow as pa
        import pyarrow.compute as pc

        m = table.num_rows
        if m == 0:
            return
        k = self.n + np.arange(m, dtype=np.int64)
        item_id = pa.array(_FIRST_HOLE_ID + 2 * k).cast(pa.string())
        meas_id = pa.array(_FIRST_HOLE_ID + 1 + 2 * k).cast(pa.string())

        def num(c):
            return table.column(c).to_numpy().astype(float)

        after, u_after = num("angle_after_deg"), num("U95_after_deg")
        use_after = np.isfinite(after)
        angle = np.where(use_after, after, num("angle_deg"))
        u95 = np.where(use_after, u_after, num("U95_angle_deg"))
        status = table.column("status").combine_chunks()
        for s, q in QIF_STATUS.items():
            self.counts[s] += int(pc.sum(pc.equal(status, s)).as_py() or 0)
        qstatus = pa.array(list(QIF_STATUS.values())).take(pc.index_in(status, value_set=pa.array(list(QIF_STATUS))))
        if qstatus.null_count:
            raise ValueError(f"--qif {self.path}: a hole's status is none of {', '.join(QIF_STATUS)}")
        name = table.column("hole_id").combine_chunks().cast(pa.string())
        for a, b in (("&", "&amp;"), ("<", "&lt;"), (">", "&gt;")):
            name = pc.replace_substring(name, a, b)
        # control characters are not allowed in XML 1.0: shown as U+FFFD (the per-hole results keep the id)
        name = pc.replace_substring_regex(name, "[\\x00-\\x08\\x0b\\x0c\\x0e-\\x1f]", "\ufffd")
        times, seconds = _times(table.column("time"))
        lo, hi = float(seconds.min()), float(seconds.max())
        self.t_first = lo if self.t_first is None else min(self.t_first, lo)
        self.t_last = hi if self.t_last is None else max(self.t_last, hi)
        # a hole not measured carries no value (whatever figures its row may hold), NOT_ANALYZED alone
        ok = np.isfinite(angle) & np.asarray(pc.not_equal(status, "not_measured").to_numpy(zero_copy_only=False))
        angle, u95 = np.where(ok, angle, np.nan), np.where(ok, u95, np.nan)
        value = _decimal(angle)
        u = _decimal(u95)
        uc = _decimal(u95 / COVERAGE_K)  # the standard uncertainty QIF's combinedUncertainty states
        measured = pa.array(ok)
        attrs = pc.if_else(pc.is_valid(u), _join('<Attributes n="1"><AttributeD1 name="U95_deg" value="',
                                                  pc.fill_null(u, ""), '"/></Attributes>'), "")
        opening = pc.if_else(pc.is_valid(uc), _join('<Value combinedUncertainty="', pc.fill_null(uc, ""),
                                                      '" meanError="0">'), "<Value>")
        val = pc.if_else(measured, _join(opening, pc.fill_null(value, ""), "</Value>"), "")
        items = _join('<AngleCharacteristicItem id="', item_id, '"><Name>', name,
                      "</Name><CharacteristicNominalId>4</CharacteristicNominalId></AngleCharacteristicItem>\n")
        meas = _join('<AngleCharacteristicMeasurement id="', meas_id, '">', attrs,
                     "<Status><CharacteristicStatusEnum>", qstatus, "</CharacteristicStatusEnum></Status>"
                     "<CharacteristicItemId>", item_id, "</CharacteristicItemId><TimeStamp>", times,
                     '</TimeStamp><MeasurementDeviceIds n="1"><Id>5</Id></MeasurementDeviceIds>', val,
                     "</AngleCharacteristicMeasurement>\n")
        _write_strings(self._items, items)
        _write_strings(self._meas, meas)
        self.n += m

    def _qpid(self, what: str) -> str:
        """A QIF persistent id, the same for the same inputs and results (same bytes out)."""
        key = f"metro:{what}:{self.log}:{self.layout_sha256}:{self.tolerance_deg!r}:{self.n}:{sorted(self.counts.items())}"
        return str(uuid.uuid5(uuid.NAMESPACE_URL, key))

    def _head(self) -> str:
        c = self.counts
        inspection = "FAIL" if c["fails"] else "UNKNOWN" if (c["undecided"] or c["not_measured"]) else "PASS"
        id_max = _FIRST_HOLE_ID + 2 * self.n - 1 if self.n else _FIRST_HOLE_ID - 1
        cert = self.certificate
        device_attrs = [("calibration_sha256", self.layout_sha256), ("calibration_file", self.layout_path.name),
                        ("sensors", " ".join(self.sensors))] + [(f"certificate.{k}", str(v)) for k, v in sorted(cert.items())]
        attrs = "".join(f"<AttributeStr name={quoteattr(k)} value={quoteattr(v)}/>" for k, v in device_attrs)
        name = cert.get("part") or cert.get("head") or "drilling end-effector normal-sensor head"
        serial = f"<SerialNumber>{escape(str(cert['serial']))}</SerialNumber>" if "serial" in cert else ""
        trace = ""
        if self.t_first is not None:
            trace = (f"<InspectionStart>{utc(self.t_first)}</InspectionStart>"
                     f"<InspectionEnd>{utc(self.t_last)}</InspectionEnd>")
        refs = [(Path(self.log).resolve().as_uri() if self.log not in ("-", "<stdin>") else "urn:metro:stdin",
                 "metro hole log (CSV, Parquet or a folder of hive-partitioned Parquet)", "the hole log measured"),
                (self.layout_path.resolve().as_uri(), "metro calibrated layout (TOML)",
                 f"the calibrated layout, SHA-256 {self.layout_sha256}")]
        refs += [(p.resolve().as_uri(), INPUT_SPECS.get(role, role), f"the {role}, SHA-256 {digest}")
                 for role, p, digest in self.inputs]
        ext = "".join(f"<ExternalFileReference><URI>{escape(u)}</URI><FileSpec><OtherFileSpec>{escape(s)}"
                      f"</OtherFileSpec></FileSpec><Description>{escape(d)}</Description></ExternalFileReference>"
                      for u, s, d in refs)
        tol = f"{self.tolerance_deg:.{_DIGITS}f}"
        return (
            '<?xml version="1.0" encoding="UTF-8"?>\n'
            f'<QIFDocument xmlns="{NS}" xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" versionQIF="3.0.0" '
            f'idMax="{id_max}" xsi:schemaLocation="{NS} ../QIFApplications/QIFDocument.xsd">\n'
            f"<QPId>{self._qpid('document')}</QPId>\n"
            "<Header><Application><Name>metro</Name>"
            f"<Organization>metro (open source)</Organization></Application>"
            "<Description>Drilled holes' normality: the angle between drill axis and surface normal measured by "
            "the pressure foot's laser sensors, with U95, judged by ISO 14253-1</Description></Header>\n"
            '<StandardsDefinitions n="1"><Standard id="1"><Organization><StandardsOrganizationEnum>ISO'
            "</StandardsOrganizationEnum></Organization><Designator>14253-1</Designator><Year>2017</Year>"
            "<Title>Decision rules for verifying conformity or nonconformity with specifications</Title>"
            "</Standard></StandardsDefinitions>\n"
            '<SoftwareDefinitions n="1"><Software id="2"><VendorName>metro</VendorName>'
            f"<ApplicationName>metro measure</ApplicationName><Version>{escape(self.version or 'unknown')}</Version>"
            "</Software></SoftwareDefinitions>\n"
            "<FileUnits><PrimaryUnits><AngularUnit><UnitName>degree</UnitName></AngularUnit>"
            "<LinearUnit><UnitName>mm</UnitName></LinearUnit></PrimaryUnits></FileUnits>\n"
            '<MeasurementResources><MeasurementDevices n="1"><MeasurementDevice id="5">'
            f"<Name>{escape(str(name))}</Name><Description>laser displacement sensors on the pressure foot "
            f"({escape(' '.join(self.sensors))}), calibrated layout {escape(self.layout_path.name)}</Description>"
            f'{serial}<Attributes n="{len(device_attrs)}">{attrs}</Attributes>'
            "</MeasurementDevice></MeasurementDevices></MeasurementResources>\n"
            "<Characteristics><FormalStandardId>1</FormalStandardId>\n"
            '<CharacteristicDefinitions n="1"><AngleCharacteristicDefinition id="3">'
            "<Description>drilling normality: angle between the drill axis and the surface normal (ISO 14253-1: "
            "conforms if angle + U95 &lt;= tolerance, fails if angle - U95 &gt; tolerance); each measurement's "
            "Value's combinedUncertainty is its standard uncertainty (U95 / 2), deg, and the attribute U95_deg its "
            "expanded uncertainty (95 % coverage), deg</Description>"
            "<Name>normality</Name>"
            f"<Tolerance><MaxValue>{tol}</MaxValue><MinValue>0.{'0' * _DIGITS}</MinValue>"
            "<DefinedAsLimit>false</DefinedAsLimit></Tolerance></AngleCharacteristicDefinition>"
            "</CharacteristicDefinitions>\n"
            '<CharacteristicNominals n="1"><AngleCharacteristicNominal id="4"><CharacteristicDefinitionId>3'
            f"</CharacteristicDefinitionId><Name>normality</Name><TargetValue>0.{'0' * _DIGITS}</TargetValue>"
            "</AngleCharacteristicNominal></CharacteristicNominals>\n"
            f'<CharacteristicItems n="{self.n}">\n'
        ), (
            "</CharacteristicItems>\n</Characteristics>\n"
            '<Results><MeasurementResultsSet n="1"><MeasurementResults id="6">'
            "<InspectionTraceability>"
            f'{trace}<InspectionSoftwareItems><AnalysisSoftware n="1"><Id>2</Id></AnalysisSoftware>'
            "</InspectionSoftwareItems>"
            "</InspectionTraceability>"
            f"<ThisResultsInstanceQPId>{self._qpid('results')}</ThisResultsInstanceQPId>"
            f'<ExternalFileReferences n="{len(refs)}">{ext}</ExternalFileReferences>\n'
            f'<MeasuredCharacteristics><CharacteristicMeasurements n="{self.n}">\n'
        ), (
            "</CharacteristicMeasurements></MeasuredCharacteristics>"
            f"<InspectionStatus><InspectionStatusEnum>{inspection}</InspectionStatusEnum></InspectionStatus>"
            "</MeasurementResults></MeasurementResultsSet></Results>\n</QIFDocument>\n"
        )

    def __exit__(self, exc_type, exc, tb):
        from metrology.io.atomic import atomic_path

        try:
            self._items.close()
            self._meas.close()
            if exc_type is None:
                if self.n == 0:
                    raise ValueError(f"--qif {self.path}: the log has no rows, nothing to write")
                head, middle, tail = self._head()
                with atomic_path(self.path) as tmp, open(tmp, "wb") as out:
                    out.write(head.encode())
                    with open(self._items.name, "rb") as fh:
                        shutil.copyfileobj(fh, out, 1 << 22)
                    out.write(middle.encode())
                    with open(self._meas.name, "rb") as fh:
                        shutil.copyfileobj(fh, out, 1 << 22)
                    out.write(tail.encode())
        finally:
            shutil.rmtree(self._dir, ignore_errors=True)
        return False


def _d(x) -> str:
    return repr(float(x))


def write_device_document(path, layout, sha256: str, file_name: str | None, version: str = "",
                          method: str = "", poses: int | None = None) -> None:
    """``metro calibrate --qif``: the calibrated head as a QIF 3.0 measurement resource (atomically).

    One ``MeasurementDevice`` (id 1) whose attributes carry the calibration's SHA-256 (of the
    calibrated layout's TOML text: the bytes ``--out`` writes), its file name, the method and the
    poses, and per sensor its zero point (mm, TCS), beam direction (unit, TCS), their 1-sigma
    standard errors (mm; deg about the chart axes), its reading noise and range (mm): the device
    that ``metro measure --qif`` names by the same SHA-256."""
    from metrology.io.atomic import write_text

    attrs = [f'<AttributeStr name="calibration_sha256" value="{sha256}"/>']
    if file_name:
        attrs.append(f"<AttributeStr name=\"calibration_file\" value={quoteattr(file_name)}/>")
    if method:
        attrs.append(f"<AttributeStr name=\"method\" value={quoteattr(method)}/>")
    if poses is not None:
        attrs.append(f'<AttributeI1 name="poses" value="{int(poses)}"/>')
    attrs.append(f"<AttributeStr name=\"sensors\" value={quoteattr(' '.join(layout.names))}/>")
    for j, nm in enumerate(layout.names):
        attrs.append(f'<AttributeD3 name="{escape(nm)}.zero_mm" value="{" ".join(_d(v) for v in layout.zero[j])}"/>')
        attrs.append(f'<AttributeD3 name="{escape(nm)}.direction" value="{" ".join(_d(v) for v in layout.direction[j])}"/>')
        if layout.zero_stderr_mm is not None:
            attrs.append(f'<AttributeD3 name="{escape(nm)}.zero_stderr_mm" '
                         f'value="{" ".join(_d(v) for v in layout.zero_stderr_mm[j])}"/>')
        if layout.direction_stderr_deg is not None:
            attrs.append(f'<AttributeD2 name="{escape(nm)}.direction_stderr_deg" '
                         f'value="{" ".join(_d(v) for v in layout.direction_stderr_deg[j])}"/>')
        if layout.noise_mm is not None and np.isfinite(layout.noise_mm[j]):
            attrs.append(f'<AttributeD1 name="{escape(nm)}.noise_mm" value="{_d(layout.noise_mm[j])}"/>')
        if layout.range_mm is not None and np.all(np.isfinite(layout.range_mm[j])):
            attrs.append(f'<AttributeD2 name="{escape(nm)}.range_mm" value="{" ".join(_d(v) for v in layout.range_mm[j])}"/>')
    cert = dict(layout.certificate or {})
    attrs += [f"<AttributeStr name={quoteattr('certificate.' + k)} value={quoteattr(str(v))}/>"
              for k, v in sorted(cert.items())]
    name = cert.get("part") or cert.get("head") or "drilling end-effector normal-sensor head"
    serial = f"<SerialNumber>{escape(str(cert['serial']))}</SerialNumber>" if "serial" in cert else ""
    qpid = uuid.uuid5(uuid.NAMESPACE_URL, f"metro:device:{sha256}")
    write_text(path, (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        f'<QIFDocument xmlns="{NS}" xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" versionQIF="3.0.0" '
        f'idMax="1" xsi:schemaLocation="{NS} ../QIFApplications/QIFDocument.xsd">\n'
        f"<QPId>{qpid}</QPId>\n"
        "<Header><Application><Name>metro</Name><Organization>metro (open source)</Organization></Application>"
        "<Description>A drilling end-effector's laser normal sensors, calibrated by metro calibrate</Description>"
        "</Header>\n"
        "<FileUnits><PrimaryUnits><AngularUnit><UnitName>degree</UnitName></AngularUnit>"
        "<LinearUnit><UnitName>mm</UnitName></LinearUnit></PrimaryUnits></FileUnits>\n"
        '<MeasurementResources><MeasurementDevices n="1"><MeasurementDevice id="1">'
        f"<Name>{escape(str(name))}</Name><Description>laser displacement sensors on the pressure foot "
        f"({escape(' '.join(layout.names))}), calibrated by metro calibrate {escape(version)}; zero points and beam "
        "directions in the tool frame (TCS), standard errors 1 sigma</Description>"
        f'{serial}<Attributes n="{len(attrs)}">{"".join(attrs)}</Attributes>'
        "</MeasurementDevice></MeasurementDevices></MeasurementResources>\n</QIFDocument>\n"))
