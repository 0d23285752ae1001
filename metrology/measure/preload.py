"""What a LocalCluster's worker process imports before its first partition, once for all of them.

:func:`metrology.measure.fleet.connect` starts Python's forkserver with this module as its preload
and has Dask fork the cluster's worker processes from it (``multiprocessing-method: forkserver``).
A spawned worker starts a new interpreter, imports Dask (0.4 s) and, in its first partition, the
reader, the measuring and the U95 table's interpolation (0.3 s): each worker paid both, on cores
the other workers needed. Here they are paid once, in the forkserver, while the client still reads
its inputs; a forked worker starts with them in memory (shared until written).

Importing this module changes the importing process: the environment Dask's nanny gives a spawned
worker (``distributed.nanny.pre-spawn-environ``: one BLAS thread a worker, set before numpy loads:
it reads it once), and glibc's heap kept (:func:`metrology.measure.run.tune_allocator`); the forked
workers inherit both. It is meant for the forkserver alone; nothing else imports it.
"""

from __future__ import annotations

import os

import dask.config  # the user's config (no numpy: distributed imports it)


def _pre_spawn_environ() -> dict:
    """Dask's ``distributed.nanny.pre-spawn-environ`` (str values): the user's config, else
    distributed's defaults, read from its ``distributed.yaml`` (importing distributed loads numpy)."""
    import importlib.util
    from pathlib import Path

    import yaml

    seen = dask.config.get("distributed.nanny.pre-spawn-environ", default=None)
    if seen is None:
        folder = importlib.util.find_spec("distributed").submodule_search_locations[0]
        seen = yaml.safe_load((Path(folder) / "distributed.yaml").read_text())["distributed"]["nanny"]["pre-spawn-environ"]
    return {k: str(v) for k, v in seen.items()}


os.environ.update(_pre_spawn_environ())

import distributed  # noqa: E402,F401  (the worker's code)
import numpy  # noqa: E402,F401
import pyarrow.compute  # noqa: E402,F401
import pyarrow.parquet  # noqa: E402,F401
import scipy.ndimage  # noqa: E402,F401  (magnitude._lookup)

import metrology.measure.fleet  # noqa: E402,F401
import metrology.measure.magnitude  # noqa: E402,F401
from metrology.measure.run import tune_allocator  # noqa: E402

tune_allocator()
