"""The QIF 3.0 XSD as an ``xmlschema`` object, built once and kept in pytest's cache.

Building it (xmlschema reading the 23 XSD files of tests/data/qif3/) costs ~3.6 s of CPU a process, ~7.3 s
when the XSD files are also checked against the XSD meta-schema (:data:`BUILD`); loading the pickled object
~1.5 s. The pickle is keyed
by the bytes of every XSD file and the versions of xmlschema and Python, so a changed schema or
library builds afresh; an unreadable pickle is rebuilt. A clean clone (CI) builds it once a run:
a worker that asks while another builds it waits for the build (a lock beside the pickle) and reads it.
"""

from __future__ import annotations

import hashlib
import os
import pickle
import sys
from pathlib import Path

from tests.shared import locked

QIF3 = Path(__file__).resolve().parents[1] / "data" / "qif3"
XSD = QIF3 / "QIFApplications" / "QIFDocument.xsd"
#: how xmlschema builds the schema: "skip" leaves out checking the XSD files themselves against the meta-schema
#: (they are the published QIF 3.0 files, fixed in tests/data: that check tests the standard and xmlschema, not
#: metro; half the build's CPU). The documents metro writes are validated against the schema all the same, and
#: test_qif's broken documents are still refused
BUILD = "skip"


def _key(xmlschema) -> str:
    h = hashlib.sha256(f"{xmlschema.__version__} {sys.version}".encode())
    for p in sorted(QIF3.rglob("*.xsd")):
        h.update(p.relative_to(QIF3).as_posix().encode() + b"\0" + p.read_bytes())
    return h.hexdigest()[:32]


def qif_schema(xmlschema, cache_dir: Path | None):
    """``xmlschema.XMLSchema`` of QIFDocument.xsd; from ``cache_dir`` when it holds this build."""
    if cache_dir is None:
        return xmlschema.XMLSchema(str(XSD), validation=BUILD)
    path = Path(cache_dir) / f"qif3-{_key(xmlschema)}.pickle"
    with locked(path.with_suffix(".lock")):  # a second worker asking meanwhile waits and reads the pickle
        return _read_or_build(xmlschema, path)


def _read_or_build(xmlschema, path: Path):
    try:
        with open(path, "rb") as f:
            schema = pickle.load(f)
        if isinstance(schema, xmlschema.XMLSchemaBase):
            return schema
    except Exception:  # absent, half-written by an older run, or from another build: built below
        pass
    schema = xmlschema.XMLSchema(str(XSD), validation=BUILD)
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            pickle.dump(schema, f, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)  # atomic: a concurrent worker reads the old state or the whole file
    except (OSError, RecursionError, pickle.PicklingError, TypeError, AttributeError):
        # not kept: the disk refused it, or this xmlschema's objects do not pickle (its lowest version allowed
        # recurses too deep): the next run builds it again, as without a cache
        tmp.unlink(missing_ok=True)
    return schema
