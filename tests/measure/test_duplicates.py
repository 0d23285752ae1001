"""A batch's repeated ``hole_id``s (metrology.measure.holes._duplicates): rising ids skip the hash, and any other
order is hashed, so a repeat is found whatever the order."""

import numpy as np
import pyarrow as pa

from metrology.measure.holes import _duplicates


def _ids(values, chunks=1):
    k = -(-len(values) // chunks)
    return pa.chunked_array([pa.array(values[i:i + k], pa.string()) for i in range(0, len(values), k)])


def test_rising_ids_have_no_repeat_and_a_repeat_is_found_in_any_order():
    rising = [f"C1-{i:08d}" for i in range(5000)]
    for chunks in (1, 3):
        dup, orig = _duplicates(_ids(rising, chunks))
        assert dup.size == 0 and orig.size == 0
    repeated = rising[:2500] + [rising[2499]] + rising[2500:]  # rising but for one repeat beside its first
    dup, orig = _duplicates(_ids(repeated, 3))
    np.testing.assert_array_equal(dup, [2500])
    np.testing.assert_array_equal(orig, [2499])
    shuffled = list(reversed(rising[:100])) + [rising[50]]
    dup, orig = _duplicates(_ids(shuffled))
    np.testing.assert_array_equal(dup, [100])
    np.testing.assert_array_equal(orig, [49])
    assert _duplicates(_ids(["a"]))[0].size == 0
