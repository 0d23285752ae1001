"""``metro simulate``'s file job: a layout and a datum plane in, an export hiding an effect out
(and, if asked, a tracker scan of the datum)."""

from __future__ import annotations

__all__ = ["simulate_files"]


def simulate_files(layout_path, plane_path, out_path, effect=None, sensor=None, size=None, poses=80, seed=0,
                   cloud_path=None):
    """Write a synthetic export (and a datum cloud) hiding ``effect`` of ``size`` on ``sensor``.

    Both files or neither: each is written to a temporary beside it and moved at the end.

    Returns
    -------
    truth : dict, what was hidden (:func:`metrology.sim.synth.synth_run`)
    n_points : int or None, the datum points written to ``cloud_path``
    """
    from pathlib import Path

    import numpy as np

    from metrology.core.plane import Plane
    from metrology.io.atomic import atomic_path
    from metrology.io.clouds import write_ply
    from metrology.io.export import write_export
    from metrology.io.layout import load_layout
    from metrology.sim.synth import HiddenEffect, synth_cloud, synth_run

    if (effect is None) != (size is None):
        raise ValueError("--effect and --size go together")
    lay = load_layout(layout_path)
    pl = Plane.from_json(plane_path)
    effects = [] if effect is None else [HiddenEffect(effect, sensor, size)]
    if effect is None and sensor is not None:
        raise ValueError("--sensor needs --effect")
    cloud = None if cloud_path is None else Path(cloud_path)
    if cloud is not None and cloud.suffix.lower() != ".ply":
        raise ValueError(f"--cloud {cloud}: expected a .ply path")
    if cloud is not None and not cloud.parent.is_dir():
        raise ValueError(f"--cloud {cloud}: directory {cloud.parent} does not exist")
    rng = np.random.default_rng(seed)
    export, truth = synth_run(rng, lay, pl, poses, effects)
    points = None if cloud is None else synth_cloud(rng, pl, effects)
    if points is None:
        write_export(export, out_path)
    else:
        with atomic_path(out_path) as tmp_out, atomic_path(cloud) as tmp_cloud:
            write_export(export, tmp_out)
            write_ply(tmp_cloud, points, [f"metro simulate: tracker scan of the datum, mm, tracker frame (seed {seed})"])
    return truth, None if points is None else len(points)
