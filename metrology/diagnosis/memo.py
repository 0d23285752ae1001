"""No fit computed twice: results of the diagnosis' fits kept by the content of their inputs.

A diagnosis fits the same model to the same poses many times over: every one-sensor candidate's
k-fold refits the other sensors' base model on each fold, and a selection scores a candidate
again given the same causes. :func:`memoised` keeps a function's results in a bounded store
keyed by a digest of everything the result depends on (:func:`content_key`: the bytes and shape
of every array, the class and fields of every dataclass, the ``repr`` of every other value), so
a hit returns what the call would have computed. The arrays of a kept result are made read-only:
a caller that wrote into a shared result would raise instead of changing another's.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import inspect
from collections import OrderedDict

import numpy as np

__all__ = ["content_key", "memoised", "freeze", "clear_all", "new_store", "MAX_KEPT"]

#: results kept per memoised function (least recently used dropped first)
MAX_KEPT = 4096

_STORES: list = []  # every memoised function's store (clear_all)


def new_store() -> OrderedDict:
    """An empty store of kept results that :func:`clear_all` clears too."""
    store: OrderedDict = OrderedDict()
    _STORES.append(store)
    return store


def clear_all() -> None:
    """Forget every kept result (a benchmark timing one diagnosis as a fresh process runs it)."""
    for store in _STORES:
        store.clear()


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
    every fit are read once. The contract: an array inside a frozen instance passed to a
    memoised function is not written to afterwards (the diagnosis writes into none; an
    instance's digest read afresh at every call costs 16 % of a diagnosis)."""
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


_DIGEST = "_memo_content_digest"


def freeze(v):
    """Make the arrays of ``v`` (a dataclass, tuple or array, nested) read-only; returns ``v``."""
    if isinstance(v, np.ndarray):
        v.flags.writeable = False
    elif dataclasses.is_dataclass(v) and not isinstance(v, type):
        for f in dataclasses.fields(v):
            freeze(getattr(v, f.name))
    elif isinstance(v, (tuple, list)):
        for a in v:
            freeze(a)
    return v


def memoised(fn):
    """Decorator: keep the results of ``fn`` by the content of every argument it is called with
    (bound to its signature, defaults applied, passed to :func:`content_key`), at most
    :data:`MAX_KEPT` of them. An argument given as a list where an array was given before is a
    different key (a miss, never a wrong hit)."""
    sig = inspect.signature(fn)
    store = new_store()

    @functools.wraps(fn)
    def inner(*args, **kwargs):
        bound = sig.bind(*args, **kwargs)
        bound.apply_defaults()
        key = content_key(tuple(bound.arguments.values()))
        hit = store.get(key)
        if hit is not None:
            store.move_to_end(key)
            return hit
        out = freeze(fn(*args, **kwargs))
        store[key] = out
        if len(store) > MAX_KEPT:
            store.popitem(last=False)
        return out

    inner.cache_clear = store.clear
    inner.uncached = fn
    return inner
