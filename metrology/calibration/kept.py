"""Results kept by the content of what they were computed from: the calibration's least-squares fits
(``estimators``: the export screen and ``calibrate`` fit the same sensors' problems) and the held sensors'
readings at a start (``engine``: every candidate posed on one fold of a diagnosis starts from the same one).

A kept value is what the computation returns for the same inputs: a hit changes no bit. The key is a
digest of the inputs' bytes and shapes, so an equal array made elsewhere finds the same entry.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict

import numpy as np

__all__ = ["Kept", "array_key"]


def array_key(*arrays, text: str = "") -> bytes:
    """A digest of ``arrays`` (each taken as contiguous float64: shape and bytes) and ``text``."""
    h = hashlib.blake2b(digest_size=20)
    for a in arrays:
        a = np.ascontiguousarray(a, float)
        h.update(repr(a.shape).encode())
        h.update(a.tobytes())
    h.update(text.encode())
    return h.digest()


class Kept:
    """At most ``size`` values by key, the least recently used dropped first."""

    def __init__(self, size: int):
        self.size = size
        self._values: OrderedDict = OrderedDict()

    def get(self, key: bytes, make):
        """The value kept under ``key``, or ``make()``'s, kept."""
        if key in self._values:
            self._values.move_to_end(key)
            return self._values[key]
        value = self._values[key] = make()
        if len(self._values) > self.size:
            self._values.popitem(last=False)
        return value

    def clear(self) -> None:
        self._values.clear()

    def __len__(self) -> int:
        return len(self._values)
