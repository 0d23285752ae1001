"""The calibration certificate of ``metro calibrate --report``: what an ISO/IEC 17025
calibration certificate states (clause 7.8.2.1 and 7.8.4.1), from the calibrated layout file as
written.

Every number is read back from the calibrated TOML's text (:func:`certificate_from_toml`), so the
certificate and the file cannot disagree: the calibrated zero points and directions, the standard
uncertainty ``u`` (1 σ) and the expanded uncertainty ``U = k u`` (k = 2) of each parameter, the
correlations of each sensor's parameters, the file's SHA-256. The header fields (part,
instrument, serial, operator, temperature, ...) come from ``--meta key=value`` / ``--meta-file``
and are carried in the TOML's ``[certificate]`` table.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from metrology.core.layout import PARAMS_TANGENT
from metrology.core.tolerances import CORRELATION_REPORT

__all__ = ["Certificate", "certificate_from_toml", "certificate_section", "HEADER_FIELDS", "COVERAGE_K"]

#: coverage factor of the expanded uncertainty (about 95 % for a normal distribution; GUM 6.2)
COVERAGE_K = 2.0

#: the header fields a certificate names, in its order, with their words (any other key is listed after)
HEADER_FIELDS = (
    ("certificate", "certificate number"), ("laboratory", "laboratory"), ("location", "place of calibration"),
    ("customer", "customer"), ("part", "item calibrated (part)"), ("instrument", "instrument (laser tracker)"),
    ("serial", "serial number"), ("traceability", "traceability (the instrument's own certificate)"),
    ("operator", "operator"), ("date", "date of calibration"), ("temperature", "temperature"),
    ("datum", "datum plane's uncertainty (its part of U)"), ("approved_by", "authorised by"), ("valid_until", "valid until (as agreed)"), ("notes", "notes"),
)

#: (TOML key, parameter words, unit, digits the TOML holds) of each sensor's parameters
_PARAMS = (("x", "zero point x", "mm"), ("y", "zero point y", "mm"), ("z", "zero point z", "mm"))


@dataclass(frozen=True)
class Certificate:
    """A calibration certificate.

    Attributes
    ----------
    header : tuple of (key, words, value), the header fields given (``--meta``), known ones first
    rows : tuple of (sensor, parameter, value, u, U, unit), floats as read from the TOML;
        ``u``/``U`` None for a direction component (its uncertainty is the tilt rows'); the head's
        effect terms (``scale.L2 k``, ...) after each sensor's own rows
    correlations : tuple of (sensor, a, b, r), pairs of one sensor's parameters with
        ``|r| > CORRELATION_REPORT`` from the TOML's ``[calibration]`` covariance
    file : str or None, the calibrated TOML's name (None: not written, no ``--out``)
    sha256 : str, of the TOML's bytes as written (or as they would be)
    method, n_poses : the estimator and the poses it used
    standoff_mm : (2,) float, the readings' range over the calibration, mm
    tilt_max_deg : float, the largest tilt of the tool axis from the datum normal, deg
    issued : str, the time the certificate was made (UTC)
    tilt_chart : str, the direction whose chart axes e1, e2 the tilts' u and the correlations are
        about: ``calibrated`` (the file's ``[calibration]`` covariance, as ``metro measure`` reads
        it), or ``nominal`` (a file without covariance: its ``direction_stderr_deg``, the fit's chart)
    """

    header: tuple
    rows: tuple
    correlations: tuple
    file: str | None
    sha256: str
    method: str
    n_poses: int
    standoff_mm: tuple
    tilt_max_deg: float
    issued: str
    tilt_chart: str = "calibrated"

    @property
    def number(self) -> str:
        """The certificate number given (``--meta certificate=...``), else ``metro-`` and the
        first 12 hex digits of the file's SHA-256 (unique to the calibrated values)."""
        given = dict((k, v) for k, _, v in self.header).get("certificate")
        return given or f"metro-{self.sha256[:12]}"

    def to_dict(self) -> dict:
        return {"number": self.number, "file": self.file, "sha256": self.sha256, "coverage_factor": COVERAGE_K,
                "header": {k: v for k, _, v in self.header}, "method": self.method, "n_poses": self.n_poses,
                "standoff_mm": list(self.standoff_mm), "tilt_max_deg": self.tilt_max_deg, "issued": self.issued,
                "tilt_chart": self.tilt_chart,
                "parameters": [{"sensor": s, "parameter": p, "value": v, "u": u, "U": U, "unit": unit}
                               for s, p, v, u, U, unit in self.rows],
                "correlations": [{"sensor": s, "a": a, "b": b, "r": r} for s, a, b, r in self.correlations]}


def _header(meta: dict) -> tuple:
    known = dict(HEADER_FIELDS)
    keys = [k for k, _ in HEADER_FIELDS if k in meta] + [k for k in meta if k not in known]
    return tuple((k, known.get(k, k.replace("_", " ")), str(meta[k])) for k in keys)


def certificate_from_toml(text: str, layout, file, method: str, n_poses: int, standoff_mm, tilt_max_deg: float,
                          issued: str) -> Certificate:
    """The certificate of a calibrated layout file.

    Parameters
    ----------
    text : str, the calibrated TOML as written (its UTF-8 bytes are hashed)
    layout : SensorLayout, ``text`` read back (:func:`metrology.io.layout.load_layout`, which
        checks it): the sensors' order, the header fields and the covariance; the values and
        their uncertainties are the numbers as the text holds them
    file : str or None, the file's name (None: not written)
    """
    import tomllib

    sha = hashlib.sha256(text.encode("utf-8")).hexdigest()
    raw = {s["name"]: s for s in tomllib.loads(text)["sensors"]}  # the numbers as written, not renormalised
    rows, corr = [], []
    names = PARAMS_TANGENT
    for i, name in enumerate(layout.names):
        s = raw[name]
        zse = s.get("zero_stderr_mm")
        for j, (_, words, unit) in enumerate(_PARAMS):
            u = None if zse is None else float(zse[j])
            rows.append((name, words, float(s["zero"][j]), u, None if u is None else COVERAGE_K * u, unit))
        for j, c in enumerate("ijk"):
            rows.append((name, f"direction {c} (unit vector)", float(s["direction"][j]), None, None, ""))
        cov = None if layout.covariance is None else layout.covariance[5 * i:5 * i + 5, 5 * i:5 * i + 5]
        if cov is not None:  # the calibrated direction's chart, as the correlations beneath
            tilt_u = np.degrees(np.sqrt(np.maximum(np.diag(cov)[3:], 0.0)))
        elif "direction_stderr_deg" in s:  # no covariance: the fit's own chart, the nominal direction's
            tilt_u = [float(x) for x in s["direction_stderr_deg"]]
        else:
            tilt_u = None
        if tilt_u is not None:
            for j, e in enumerate(("e1", "e2")):
                u = float(tilt_u[j])
                rows.append((name, f"beam tilt about {e}", 0.0, u, COVERAGE_K * u, "deg"))
        for comp in () if layout.effects is None else layout.effects.on(name):  # the head's terms, as written
            t = s["effects"][comp.name]
            for pn, unit in zip(comp.param_names, comp.param_units):
                u = float(t[pn + "_stderr"])
                rows.append((name, f"{comp.label} {pn}", float(t[pn]), u, COVERAGE_K * u, "" if unit == "1" else unit))
        if cov is not None:
            se = np.sqrt(np.maximum(np.diag(cov), 0.0))
            for a in range(5):
                for b in range(a + 1, 5):
                    if se[a] > 0 and se[b] > 0:
                        r = float(cov[a, b] / (se[a] * se[b]))
                        if abs(r) > CORRELATION_REPORT:
                            corr.append((name, names[a], names[b], r))
    return Certificate(_header(layout.certificate), tuple(rows), tuple(corr), None if file is None else str(file), sha,
                       method, int(n_poses), tuple(float(x) for x in standoff_mm), float(tilt_max_deg), issued,
                       "nominal" if layout.covariance is None else "calibrated")


def _v(x, unit) -> str:
    if x is None:
        return "—"
    return f"{x:.9f}" if unit == "" else f"{x:.6f}"


def certificate_section(cert: Certificate):
    """The certificate as a report :class:`~metrology.report.html.Section` (placed first)."""
    from metrology.report.html import Headline, Section, Table

    head = [("certificate number", cert.number)]
    head += [(words, value) for key, words, value in cert.header if key != "certificate"]
    head += [("date of issue", cert.issued), ("method", f"metro calibrate --method {cert.method}: the zero point and "
                                              f"beam direction of each sensor fitted to {cert.n_poses} poses "
                                              "on the datum plane"),
             ("calibrated layout", f"{cert.file or 'not written (no --out)'}"), ("its SHA-256", cert.sha256)]
    rows = tuple((s, p, _v(v, unit) if not p.startswith("beam tilt") else "—", _v(u, unit), _v(U, unit), unit or "1")
                 for s, p, v, u, U, unit in cert.rows)
    corr = tuple((s, f"C({a}, {b})", f"{r:+.3f}") for s, a, b, r in cert.correlations)
    statements = (
        f"The expanded uncertainty U = k·u with k = {COVERAGE_K:g}, which for a normal distribution corresponds to a "
        "coverage probability of about 95 %. The standard uncertainty u is the fit's 1 σ, scaled by the residuals' "
        "scatter where it exceeds the stated noise; effects the model lacks (see model adequacy) are not in it.",
        "The results relate only to the sensor head calibrated, as mounted during the measurement. They hold over the "
        f"calibrated range: readings {cert.standoff_mm[0]:.3f} to {cert.standoff_mm[1]:.3f} mm, tool-axis tilts up "
        f"to {cert.tilt_max_deg:.1f} deg from the datum normal. A sensor re-mounted, replaced or struck voids them.",
        "No calibration interval is stated unless agreed (valid until)." if not any(k == "valid_until" for k, _, _ in
                                                                                    cert.header) else
        "The calibration interval is the one agreed (valid until).",
        "Values are those of the calibrated layout file named, whose SHA-256 is given: zero points in mm (TCS), "
        f"directions as unit vectors (TCS), tilt uncertainties about the chart axes e1, e2 of its {cert.tilt_chart} "
        "direction" + (" (the file's [calibration] covariance)." if cert.tilt_chart == "calibrated" else
                       " (the file has no covariance: its direction_stderr_deg)."),
    )
    return Section("Calibration certificate", Headline(None, f"{cert.number}: calibrated layout "
                                                             f"{cert.file or '(not written)'}, SHA-256 {cert.sha256[:16]}…"),
                   tables=(Table("Certificate", ("field", "value"), tuple(head), wrap=True),
                           Table(f"Calibrated values, standard uncertainty u (1 σ) and expanded uncertainty U "
                                 f"(k = {COVERAGE_K:g})", ("sensor", "parameter", "value", "u", "U", "unit"), rows),
                           Table(f"Correlations of each sensor's parameters with |r| > {CORRELATION_REPORT:g}",
                                 ("sensor", "pair", "r"), corr, "x, y, z: the zero point; a, b: the beam's tilt about "
                                 "the chart axes e1, e2 of its calibrated direction (the file's [calibration] "
                                 "covariance)." if cert.tilt_chart == "calibrated" else
                                 "None: the file has no [calibration] covariance.")),
                   statements=statements)
