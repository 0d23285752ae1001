import os

# xdist runs one worker a core: one BLAS thread each, or OpenBLAS's threads oversubscribe the
# cores and spin (benchmarks/_one_blas_thread.py has the measurement); set before numpy loads
for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np
import pytest


@pytest.fixture
def rng():
    return np.random.default_rng(20181016)
