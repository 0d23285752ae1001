"""``metro diagnose``'s file job: the three files of a run in, a :class:`~metrology.diagnosis.Diagnosis` out."""

from __future__ import annotations

from metrology.diagnosis.decide import Diagnosis, diagnose

__all__ = ["diagnose_files"]


def diagnose_files(export_path, plane_path, layout_path, quaternion_order="wxyz", position_units="mm", no_reading=None,
                   warn=None, **kw) -> Diagnosis:
    """:func:`diagnose` on the three files of a run, read and screened as for ``metro calibrate``
    (:func:`metrology.jobs.calibrate.load_checked`: a gross mismatch is refused, naming the mistake)."""
    from metrology.jobs.calibrate import load_checked

    ds = load_checked(export_path, plane_path, layout_path, quaternion_order, position_units, no_reading, warn)
    return diagnose(ds, **kw)

