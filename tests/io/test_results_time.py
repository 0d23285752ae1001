"""A results file's ``time`` column read back (by ``metro measure --qif`` and the Q-DAS writer): the same seconds as a
log's batch gets, and an error naming the row as a log's reader does."""

import numpy as np
import pyarrow as pa
import pytest

from metrology.io.holelog_reader import time_seconds


def test_iso_text_seconds_and_timestamps_give_the_same_seconds():
    want = np.array([1795593600.0, 1795593600.0, 1795593601.5])
    zoned = pa.chunked_array([pa.array(["2026-11-25T08:00:00Z", "2026-11-25T09:00:00+01:00", "2026-11-25T08:00:01.5Z"])])
    np.testing.assert_array_equal(time_seconds(zoned), want)
    naive = pa.chunked_array([pa.array(["2026-11-25T08:00:00", "2026-11-25T08:00:00", "2026-11-25T08:00:01.5"])])
    np.testing.assert_array_equal(time_seconds(naive), want)  # without a zone: UTC
    np.testing.assert_array_equal(time_seconds(pa.chunked_array([pa.array(want)])), want)
    stamps = pa.chunked_array([pa.array((want * 1e6).astype(np.int64), pa.timestamp("us", tz="UTC"))])
    np.testing.assert_array_equal(time_seconds(stamps), want)


def test_a_bad_value_is_named_by_its_row_and_a_bad_type_or_mixed_formats_by_the_file():
    with pytest.raises(ValueError, match=r"^<results> row 2: time 'soon' is neither ISO 8601"):
        time_seconds(pa.chunked_array([pa.array(["2026-11-25T08:00:00Z", "soon"])]))
    with pytest.raises(ValueError, match=r"^<results>: time column of type bool, expected ISO 8601"):
        time_seconds(pa.chunked_array([pa.array([True])]))
    with pytest.raises(ValueError, match=r"^<results>: the time column mixes formats"):
        time_seconds(pa.chunked_array([pa.array(["2026-11-25T08:00:00Z", "2026-11-25T08:00:00"])]))
