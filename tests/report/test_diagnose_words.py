"""The detectable sizes in words (the text and HTML reports of ``metro diagnose``)."""

from __future__ import annotations

from metrology.report.diagnose import detectable_words


def test_detectable_words_range_and_sensors_no_member_sees():
    D = {"detectable": {
        "drift": {"sensors": {"L1": 0.0060, "L2": 0.0061}, "meaning": "m1"},
        "incidence": {"sensors": {"L1": 0.394, "L2": float("inf"), "L3": 0.454, "L4": None}, "meaning": "m2"},
        "scale": {"sensors": {}, "meaning": "m3"},
    }}
    words = detectable_words(D).split("; ")  # one family a line in the text report
    assert words == ["drift 6 µm (m1)", "incidence 394-454 µm, not detectable on L2, L4 (m2)"]
