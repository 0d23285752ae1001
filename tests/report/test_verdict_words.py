"""One set of verdict words, the same in the terminal and in the HTML: ``passed`` (a check that
gates passed), ``FAILED``, ``information`` (nothing judged against a limit the user set); the
demo's overview names each step with those words, its finding and its headline once."""

from __future__ import annotations

import re

from metrology.core.verdict import Check, Verdict
from metrology.report.html import Headline as Box, RunInfo, Section, render_html, verdict_box
from metrology.report.verdicts import verdict_text, verdict_word

GATED = Verdict((Check("drilling tolerance: x", 0.1, 0.5, "deg", True),))
FAILED = Verdict((Check("drilling tolerance: x", 0.7, 0.5, "deg", False),))
UNGATED = Verdict((Check("model adequacy: y", 2.0, 1.0, "", False, gate=False),))


def test_the_terminal_and_the_page_say_the_same_word():
    for v, word in ((GATED, "passed"), (FAILED, "FAILED"), (UNGATED, "information")):
        assert verdict_word(v) == word
        assert verdict_text(v).splitlines()[0].startswith(f"verdict: {word} (exit code {0 if v.passed else 1}")
        box = verdict_box(v, "headline")
        assert box.word == word
        page = render_html("t", RunInfo(command="metro x"), [Section("s", box)])
        assert re.search(r'<p class="word">(.*?)</p>', page).group(1) == word


def test_a_finding_is_shown_beside_the_word_never_instead_of_it():
    box = verdict_box(GATED, "held-out normal deviation 0.01 deg", label="cause: drift on L3")
    assert box.word == "passed" and box.finding == "cause: drift on L3"
    page = render_html("t", RunInfo(command="metro x"), [Section("s", box)])
    assert '<p class="word">passed</p>' in page and '<p class="finding">cause: drift on L3</p>' in page


def test_the_overview_names_each_step_in_the_same_words_with_its_finding_once():
    secs = [Section("Diagnosis", verdict_box(GATED, "held-out normal deviation 0.01 deg", label="cause: drift on L3")),
            Section("Measure", verdict_box(GATED, "200 of 200 holes conform", label="1 drift alarm: recalibrate")),
            Section("Calibration", verdict_box(UNGATED, "4 sensors calibrated"))]
    page = render_html("t", RunInfo(command="metro demo"), secs)
    items = re.findall(r'<li><a href="#s\d">[^<]*</a>: (.*?)</li>', page)
    assert items == ["passed: cause: drift on L3. held-out normal deviation 0.01 deg",
                     "passed: 1 drift alarm: recalibrate. 200 of 200 holes conform",
                     "information. 4 sensors calibrated"]
    assert page.count("cause: drift on L3") == 2  # the overview and the section's box
    assert isinstance(secs[0].verdict, Box)
