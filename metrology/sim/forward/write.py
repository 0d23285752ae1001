"""Writing a case as the files a user would have, plus the truth.

``write_case(case, directory)`` writes, each atomically:

- ``export.csv``: the tracker export (reported poses, readings; :mod:`metrology.io.export`);
- ``layout.toml``: the *nominal* (drawing) layout (:mod:`metrology.io.layout`);
- ``cloud.ply``: the datum scan, mm, tracker frame (:func:`metrology.io.clouds.write_ply`);
- ``truth.json``: :meth:`Case.truth_dict` (family, effects with size, meaning, unit and shape,
  true layout, datum, temperature profile, blanks).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from metrology.io.atomic import write_text
from metrology.io.clouds import write_ply
from metrology.io.export import write_export
from metrology.io.layout import save_layout
from metrology.sim.forward.cases import Case

__all__ = ["write_case", "CASE_FILES"]

CASE_FILES = ("export.csv", "layout.toml", "cloud.ply", "truth.json")


def _json_default(v):
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    raise TypeError(f"truth.json: cannot write {type(v).__name__}")


def write_case(case: Case, directory) -> dict:
    """Write the case's four files into ``directory`` (which must exist); returns name -> path."""
    directory = Path(directory)
    if not directory.is_dir():
        raise ValueError(f"{directory}: not a directory")
    paths = {name: directory / name for name in CASE_FILES}
    write_export(case.export, paths["export.csv"])
    save_layout(case.nominal, paths["layout.toml"], header=f"drawing layout of a simulated case ({case.family})")
    write_ply(paths["cloud.ply"], case.cloud, comments=("simulated datum scan, mm, tracker frame",))
    write_text(paths["truth.json"], json.dumps(case.truth_dict(), indent=1, sort_keys=True, default=_json_default,
                                               allow_nan=False) + "\n")
    return paths
