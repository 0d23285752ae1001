"""Shared by the calibration tests: the bundled measured run as CSV rows, and a writer of
rewritten rows (the way a user's mistaken or malformed export is made from a good one)."""

from __future__ import annotations

import csv

from metrology.io.data import DATA_DIR

FIX = DATA_DIR / "measured"
CAL, VAL = FIX / "calibration.csv", FIX / "validation.csv"
PLANE, NOMINAL, TRUTH = FIX / "plane.json", FIX / "nominal.toml", FIX / "truth.toml"


def export_rows(path=CAL) -> list:
    """The export's rows (header first), each a list of str."""
    with open(path, newline="") as fh:
        return list(csv.reader(fh))


def write_rows(path, rows):
    """Write ``rows`` as CSV with ``\\n`` line ends; returns ``path``."""
    with open(path, "w", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerows(rows)
    return path
