"""The production loop: every drilled hole's normal, angle to the drill axis and its uncertainty,
the verdict against the tolerance, the drift watch, and the fleet summary (``metro measure``).

Modules: :mod:`.normals` (the micro-plane and its GUM uncertainty, pure arrays), :mod:`.holes`
(a batch of a log measured and judged: the rules; :mod:`.placement` each row's local surface in the TCS,
:mod:`.columns` the per-hole table written), :mod:`.batch` (what a measured batch is, the status codes),
:mod:`.chart` (the CUSUM drift watch; :mod:`.series` its plotted series),
:mod:`.surface` (the normal fitted with the panel's local surface known; ``surface_normal``, the
per-hole call of a cell's controller, applies the layout's head terms first: :mod:`.effects`), :mod:`.panel` (each hole's local surface from the hole table),
:mod:`.summary` (the mergeable fleet summary), :mod:`.run` (the one driver; one process, in batches),
:mod:`.fleet` (the Dask engine, one task per partition), :mod:`.preload` (what the forkserver its
workers are forked from imports). pyarrow and Dask load only when a log is read or a cluster used.
"""

from metrology import lazy_names

#: public name -> the module that defines it, imported on first use (PEP 562, as ``metrology``):
#: importing one module of the package (the workers' preload, which sets their environment before
#: numpy loads: :mod:`.preload`) loads no other
_LAZY = {
    "Alarm": "metrology.measure.chart", "CusumChart": "metrology.measure.chart",
    "cusum_arl": "metrology.measure.chart", "cusum_h": "metrology.measure.chart",
    "Settings": "metrology.measure.holes", "Status": "metrology.measure.holes",
    "measure_batch": "metrology.measure.holes",
    "HoleNormals": "metrology.measure.normals", "drill_axis": "metrology.measure.normals",
    "hole_normals": "metrology.measure.normals",
    "surface_normal": "metrology.measure.effects",
}


__getattr__, __dir__ = lazy_names(__name__, _LAZY, globals())


__all__ = ["Alarm", "CusumChart", "cusum_arl", "cusum_h", "Settings", "Status", "measure_batch", "HoleNormals",
           "drill_axis", "hole_normals", "surface_normal"]
