"""The production loop: every drilled hole's normal, angle to the drill axis and its uncertainty,
the verdict against the tolerance, the drift watch, and the fleet summary (``metro measure``).

Modules: :mod:`.normals` (the micro-plane and its GUM uncertainty, pure arrays), :mod:`.holes`
(a batch of a log measured and judged: the rules), :mod:`.batch` (what a measured batch is, the status codes), :mod:`.chart` (the CUSUM drift watch),
:mod:`.surface` (the normal fitted with the panel's local surface known: ``surface_normal``, the
per-hole call of a cell's controller), :mod:`.panel` (each hole's local surface from the hole table),
:mod:`.summary` (the mergeable fleet summary), :mod:`.run` (the one driver; one process, in batches),
:mod:`.fleet` (the Dask engine, one task per partition). pyarrow and Dask load only when a log is
read or a cluster used.
"""

from metrology.measure.chart import Alarm, CusumChart, cusum_arl, cusum_h
from metrology.measure.holes import Settings, Status, measure_batch
from metrology.measure.normals import HoleNormals, drill_axis, hole_normals
from metrology.measure.surface import surface_normal

__all__ = ["Alarm", "CusumChart", "cusum_arl", "cusum_h", "Settings", "Status", "measure_batch", "HoleNormals",
           "drill_axis", "hole_normals", "surface_normal"]
