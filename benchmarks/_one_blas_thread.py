"""Imported first by the studies that run jobs in parallel: one BLAS thread a job.

With ``--jobs N`` a study already keeps N cores busy; OpenBLAS's own threads on top of that
oversubscribe them, and the solver threads spin (measured on this 2-core machine, loaded:
``tests/diagnosis/test_families.py`` and ``test_datum.py`` took 30 s CPU with one thread,
41 s with OpenBLAS's default). Set before numpy is imported; a value the user set wins.
"""

import os

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")
