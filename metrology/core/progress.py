"""Progress reporting of long library calls, without any display library.

A long function takes ``progress: ProgressFn | None = None`` and calls
``progress(done, total, what)`` as it goes: ``done`` steps of ``total`` finished (``total``
None when it is not known before the end: a log's holes, counted as they are read), ``what``
the step starting now (or ``"done"``), as ``"stage"`` or ``"stage: detail"`` (``metro -v``
notes the time of each stage). The command line turns the calls into a bar on
stderr (``cli/_common.py``); the library never imports a display library.
"""

from __future__ import annotations

from collections.abc import Callable

__all__ = ["ProgressFn", "notify"]

#: ``progress(done, total, what)``; ``total`` None: not known
ProgressFn = Callable[[int, "int | None", str], None]


def notify(progress: ProgressFn | None, done: int, total: int | None, what: str) -> None:
    """Call ``progress(done, total, what)`` unless ``progress`` is None (``total`` None: not known)."""
    if progress is not None:
        progress(int(done), None if total is None else int(total), str(what))
