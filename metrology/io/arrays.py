"""numpy arrays to Arrow arrays and back, through their buffers: the conversions ``metro measure`` makes on every
batch, without pandas.

pyarrow imports pandas, where it is installed, the first time ``pyarrow.array`` is given anything or an Arrow array
is turned into numpy (``to_numpy``, ``numpy.asarray``: its converters ask pandas for its types first), 0.35-0.4 s of
CPU a process spends for nothing it uses (benchmarks/results/measure_speed_issue49_r6.md). These functions give the
same arrays as those calls, bit for bit (a float's null reads NaN, as ``to_numpy(zero_copy_only=False)`` gives it;
a NaN written with ``nan_is_null`` is null, as ``pyarrow.array(x, from_pandas=True)`` writes it), from the buffers
alone. Types other than the few below go through pyarrow's own calls.
"""

from __future__ import annotations

import numpy as np

__all__ = ["to_numpy", "from_numpy", "strings", "bitmask"]

#: Arrow's fixed-width types this module converts by their buffers, by numpy dtype
_TYPES = {np.dtype(np.float64): "float64", np.dtype(np.int64): "int64", np.dtype(np.int32): "int32",
          np.dtype(np.int8): "int8"}


def _dtype(t) -> np.dtype:
    """The numpy dtype of the fixed-width numeric Arrow type ``t`` (what ``t.to_pandas_dtype()`` gives, which
    imports pandas in pyarrow 14, the lowest version allowed)."""
    import pyarrow as pa

    if pa.types.is_boolean(t):
        return np.dtype(bool)
    kind = "f" if pa.types.is_floating(t) else "i" if pa.types.is_signed_integer(t) else "u"
    return np.dtype(f"{kind}{t.bit_width // 8}")


def _valid(arr) -> np.ndarray | None:
    """(n,) bool, the rows of the Arrow array ``arr`` that are not null (None: no null)."""
    if arr.null_count == 0:
        return None
    bits = np.frombuffer(arr.buffers()[0], np.uint8)
    return np.unpackbits(bits, bitorder="little", count=arr.offset + len(arr))[arr.offset:].astype(bool)


def _one(arr) -> np.ndarray:
    """One Arrow array of a fixed-width numeric, timestamp or boolean type as numpy (a copy)."""
    import pyarrow as pa

    t = arr.type
    n, off = len(arr), arr.offset
    if pa.types.is_boolean(t):
        if arr.null_count:
            return np.asarray(arr.to_numpy(zero_copy_only=False))  # an object array of True/False/None, as pyarrow
        bits = np.frombuffer(arr.buffers()[1], np.uint8)
        return np.unpackbits(bits, bitorder="little", count=off + n)[off:].astype(bool)
    if pa.types.is_timestamp(t):
        dtype = np.dtype(f"datetime64[{t.unit}]")
        raw = np.dtype(np.int64)
    else:
        dtype = raw = _dtype(t)
    out = np.frombuffer(arr.buffers()[1], raw, count=off + n)[off:].copy()
    valid = _valid(arr)
    if valid is None:
        return out.view(dtype)
    if pa.types.is_floating(t):
        out[~valid] = np.nan
        return out
    if pa.types.is_timestamp(t):
        out[~valid] = np.iinfo(np.int64).min  # NaT
        return out.view(dtype)
    out = out.astype(np.float64)  # an integer column with nulls: float, NaN for the nulls (pyarrow's to_numpy)
    out[~valid] = np.nan
    return out


def to_numpy(col) -> np.ndarray:
    """``col.to_numpy(zero_copy_only=False)`` of a pyarrow Array or ChunkedArray of a numeric, timestamp or boolean
    type (a float's null NaN, an integer column with nulls float with NaN), without pandas; a fresh, writable array.
    Any other type goes through pyarrow's ``to_numpy``."""
    import pyarrow as pa

    t = col.type
    if not (pa.types.is_floating(t) or pa.types.is_integer(t) or pa.types.is_timestamp(t)
            or pa.types.is_boolean(t)) or pa.types.is_float16(t):
        return col.to_numpy(zero_copy_only=False)
    chunks = col.chunks if isinstance(col, pa.ChunkedArray) else [col]
    if not chunks:
        return np.empty(0, np.float64 if not pa.types.is_boolean(t) else bool).astype(
            _dtype(t) if not pa.types.is_timestamp(t) else f"datetime64[{t.unit}]")
    parts = [_one(c) for c in chunks]
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def bitmask(mask) -> "object":
    """A pyarrow buffer of the bits of ``mask`` (n,) bool, Arrow's order (least significant bit first)."""
    import pyarrow as pa

    return pa.py_buffer(np.packbits(np.asarray(mask, bool), bitorder="little"))


def from_numpy(x, type=None, nan_is_null: bool = False):
    """``pyarrow.array(x, type, from_pandas=nan_is_null)`` of ``x`` (n,) float64, int64, int32, int8 or bool (with
    ``type`` a timestamp: ``x`` its int64 ticks), without pandas: a pyarrow Array on a copy of ``x``'s memory."""
    import pyarrow as pa

    given = x
    x = np.ascontiguousarray(x)
    n = len(x)
    if x.dtype == bool:
        return pa.Array.from_buffers(pa.bool_(), n, [None, bitmask(x)])
    name = _TYPES.get(x.dtype)
    if name is None:
        raise TypeError(f"from_numpy: dtype {x.dtype} not supported")
    if type is None:
        type = getattr(pa, name)()
    elif not (pa.types.is_timestamp(type) and x.dtype == np.int64) and type != getattr(pa, name)():
        raise TypeError(f"from_numpy: {x.dtype} as {type} not supported")
    validity, nulls = None, 0
    if nan_is_null and x.dtype.kind == "f":
        nan = np.isnan(x)
        nulls = int(nan.sum())
        if nulls:
            validity = bitmask(~nan)
            x = np.where(nan, 0.0, x)  # a null's slot zeroed
    if x is given or x.base is not None:
        x = x.copy()  # the Arrow array owns its memory: the caller may write into ``x`` afterwards
    return pa.Array.from_buffers(type, n, [validity, pa.py_buffer(x)], null_count=nulls)


def strings(values):
    """A pyarrow StringArray of ``values`` (a sequence of str, no None), without pandas."""
    import pyarrow as pa

    data = [v.encode("utf-8") for v in values]
    offsets = np.zeros(len(data) + 1, np.int32)
    np.cumsum([len(b) for b in data], out=offsets[1:])
    return pa.Array.from_buffers(pa.string(), len(data), [None, pa.py_buffer(offsets), pa.py_buffer(b"".join(data))])
