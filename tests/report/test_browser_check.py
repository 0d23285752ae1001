"""The project's browser check judges the report, not itself: a figure with two ``data-expect`` boxes
(a drift chart whose alarm has a next baseline) read back twice from one canvas made Chromium print a
``willReadFrequently`` hint on the console, which the check counted as the report's console error (a
measure report with one drift alarm failed at 1280 px; issue 51, item 12)."""

import base64
import importlib.util
import shutil
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(shutil.which("chromium") is None,
                                reason="needs a chromium binary (a developer's check)")


def _checker():
    spec = importlib.util.spec_from_file_location(
        "check_reports_browser", Path(__file__).parents[2] / "benchmarks" / "check_reports_browser.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _png(width, height):
    """A white PNG with a blue square at (10..30, 10..30) px, made with zlib alone."""
    import struct
    import zlib

    rows = []
    for y in range(height):
        row = bytearray(b"\x00")
        for x in range(width):
            row += bytes((31, 119, 180)) if 10 <= x <= 30 and 10 <= y <= 30 else b"\xff\xff\xff"
        rows.append(bytes(row))

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    head = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", head) + chunk(b"IDAT", zlib.compress(b"".join(rows)))
            + chunk(b"IEND", b""))


def test_a_figure_with_two_expected_boxes_passes_without_a_console_line(tmp_path):
    img = base64.b64encode(_png(200, 100)).decode()
    boxes = '[[10, 10, 30, 30, "#1f77b4", true], [60, 10, 190, 90, "#1f77b4", false]]'
    page = tmp_path / "two_boxes.html"
    page.write_text("<!doctype html><html><head><meta charset='utf-8'><title>t</title></head><body>"
                    f"<p>a figure</p><img alt='a chart' src='data:image/png;base64,{img}' data-min-font-px='12' "
                    f"data-expect='{boxes}'></body></html>", encoding="utf-8")
    assert _checker().main([str(page), "--widths", "1280", "--shots", str(tmp_path)]) == 0
