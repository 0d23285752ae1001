"""What several test modules compute identically and only read, computed once a run and shared by
pytest-xdist's workers.

pytest-xdist's documented pattern for a session fixture whose result is a file: under a lock in the
folder the workers share (``tmp_path_factory.getbasetemp().parent`` in a worker), the first worker to ask
computes the value and pickles it there; a worker asking later waits for the lock, then unpickles it.
Without xdist (``-n 0``) the folder is the session's own. Each call unpickles a fresh copy, so a module
gets its own object, as when it computed it itself. Where ``fcntl`` is missing (Windows) there is no lock:
two workers asking at once may both compute it (each writes atomically), which costs time, never a
wrong value.
"""

from __future__ import annotations

import contextlib
import os
import pickle
from pathlib import Path

try:
    import fcntl
except ImportError:  # Windows
    fcntl = None


def shared_root(tmp_path_factory) -> Path:
    """The folder every worker of this run sees (the session's base temp without xdist)."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


@contextlib.contextmanager
def locked(path: Path):
    """An exclusive lock on ``path`` (created) while the block runs; none without ``fcntl``."""
    with open(path, "a+b") as f:
        if fcntl is not None:
            fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            if fcntl is not None:
                fcntl.flock(f, fcntl.LOCK_UN)


def once_a_run(tmp_path_factory, name: str, make):
    """``make(folder)``'s value, computed by the first worker of the run to ask; ``folder`` is a
    folder of the shared root for the files it writes (their paths may be in the value)."""
    root = shared_root(tmp_path_factory)
    path = root / f"once-{name}.pickle"
    with locked(root / f"once-{name}.lock"):
        if path.is_file():
            return pickle.loads(path.read_bytes())
        folder = root / f"once-{name}"
        folder.mkdir(exist_ok=True)
        value = make(folder)
        data = pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL)
        tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
        tmp.write_bytes(data)
        os.replace(tmp, path)
    return pickle.loads(data)
