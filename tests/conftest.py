import os

# xdist runs one worker a core: one BLAS thread each, or OpenBLAS's threads oversubscribe the
# cores and spin (benchmarks/_one_blas_thread.py has the measurement); set before numpy loads
for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np
import pytest

from tests.shared import once_a_run


@pytest.fixture
def rng():
    return np.random.default_rng(20181016)


def _diagnose_bundled(name, export, layout):
    """``metro diagnose``'s result on a bundled run (``metrology/data/NAME``), the README's defaults."""
    from metrology.io.data import DATA_DIR
    from metrology.jobs.diagnose import diagnose_files

    d = DATA_DIR / name
    return diagnose_files(d / export, d / "plane.json", d / layout)


@pytest.fixture(scope="module")
def hidden_diagnosis(tmp_path_factory):
    """The bundled hidden run (a temperature drift on L3) diagnosed once a run, for every module that
    reads it (tests/diagnosis/test_reasons.py, test_results.py, tests/report/test_diagnose_figures.py):
    3-6 s of CPU a diagnosis. Each module gets its own copy."""
    return once_a_run(tmp_path_factory, "diagnosis-hidden",
                      lambda _: _diagnose_bundled("hidden", "export.csv", "layout.toml"))
