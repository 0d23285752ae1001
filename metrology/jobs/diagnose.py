"""``metro diagnose``'s file job: the three files of a run in, a :class:`~metrology.diagnosis.Diagnosis` out."""

from __future__ import annotations

from metrology.diagnosis.decide import Diagnosis, diagnose

__all__ = ["diagnose_files"]


def diagnose_files(export_path, plane_path, layout_path, **kw) -> Diagnosis:
    """:func:`diagnose` on the three files of a run (see :func:`metrology.calibration.dataset.load_dataset`)."""
    from metrology.calibration.dataset import load_dataset

    ds = load_dataset(export_path, plane_path, layout_path)
    return diagnose(ds, **kw)

