"""Results kept by the content of what they were computed from: the calibration's least-squares fits
(``estimators``: the export screen and ``calibrate`` fit the same sensors' problems), the held sensors'
readings at a start (``engine``: every candidate posed on one fold of a diagnosis starts from the same one),
and the diagnosis' fits (:func:`metrology.diagnosis.fit.memoised`).

A kept value is what the computation returns for the same inputs: a hit changes no bit. The key
(:func:`content_key`) is a digest of the inputs' content, so an equal array made elsewhere finds the same entry.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections import OrderedDict

import numpy as np

__all__ = ["Kept", "content_key"]


def content_key(*values) -> bytes:
    """A digest of ``values``: arrays by dtype, shape and bytes; dataclasses by class and fields;
    tuples, lists and dicts by their items; anything else by ``repr``."""
    h = hashlib.blake2b(digest_size=20)
    _feed(h, values)
    return h.digest()


def _feed(h, v):
    if isinstance(v, np.ndarray):
        h.update(f"a{v.dtype.str}{v.shape}".encode())
        h.update(np.ascontiguousarray(v).tobytes())
    elif dataclasses.is_dataclass(v) and not isinstance(v, type):
        h.update(_dataclass_digest(v))
    elif isinstance(v, (tuple, list)):
        h.update(b"(")
        for a in v:
            _feed(h, a)
        h.update(b")")
    elif isinstance(v, dict):
        h.update(b"{")
        for k in sorted(v, key=repr):
            _feed(h, k)
            _feed(h, v[k])
        h.update(b"}")
    else:
        h.update(f"{type(v).__qualname__}:{v!r};".encode())


def _dataclass_digest(v) -> bytes:
    """The digest of a dataclass instance by class and fields; a frozen one's is kept on the
    instance (its fields cannot be rebound), so the covariates and fold subsets keyed again at
    every fit are read once. The contract: an array inside a frozen instance keyed here is not
    written to afterwards (the diagnosis writes into none; an instance's digest read afresh at
    every call costs 16 % of a diagnosis)."""
    frozen = type(v).__dataclass_params__.frozen and hasattr(v, "__dict__")
    if frozen and _DIGEST in v.__dict__:
        return v.__dict__[_DIGEST]
    h = hashlib.blake2b(digest_size=20)
    h.update(f"d{type(v).__module__}.{type(v).__qualname__}(".encode())
    for f in dataclasses.fields(v):
        _feed(h, getattr(v, f.name))
    d = h.digest()
    if frozen:
        object.__setattr__(v, _DIGEST, d)
    return d


#: where a frozen dataclass keeps its digest (:func:`_dataclass_digest`)
_DIGEST = "_memo_content_digest"


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
