"""The ``metro diagnose`` job: export, plane and layout files in, a :class:`~metrology.diagnosis.decide.Diagnosis` out."""

from __future__ import annotations

from metrology.diagnosis.decide import Diagnosis, diagnose


def diagnose_files(export_path, plane_path, layout_path, **kw) -> Diagnosis:
    """:func:`diagnose` on the three files of a run (see :func:`metrology.dataset.load_dataset`)."""
    from metrology.calibration.dataset import load_dataset

    ds = load_dataset(export_path, plane_path, layout_path)
    return diagnose(ds, **kw)
