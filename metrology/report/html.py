"""One self-contained HTML report per run: what was run, the verdict first, the figures that
made the case, the numbers with their uncertainties and units, what the data could not
determine and what to do next.

The page is rendered with Jinja2 (imported lazily) from ``templates/report.html.j2``,
shipped as package data. It holds everything it shows: CSS inline, figures embedded as
base64 PNG, no script, no external URL; it reads on a phone (viewport meta, fluid layout)
and prints to PDF from a browser (print CSS). It is written atomically.

A report is a list of :class:`Section` (one per command; the demo's report has one per
step) under one :class:`RunInfo`.
"""

from __future__ import annotations

import base64
import os
import platform
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from metrology.io.names import display_name, sha256_file

__all__ = ["COLUMN_IN", "MIN_FIGURE_PT", "NARROW_IN", "NARROW_MEDIA", "fit_to_column", "written", "Figure", "Table", "Headline", "verdict_box", "Section", "RunInfo", "run_info", "sha256_file", "versions",
           "figure_from_matplotlib", "figure_from_png", "expect_ink", "render_html", "write_report", "check_report_path", "command_line",
           "collect",
           "REPORT_SUFFIXES"]

#: suffixes ``--report`` accepts for an HTML file
REPORT_SUFFIXES = (".html", ".htm")

#: the packages whose versions a report names (distribution names; the first installed of
#: each group is shown)
_VERSIONED = (("metro",), ("numpy",), ("scipy",), ("open3d-cpu", "open3d"), ("trimesh",), ("matplotlib",))


#: the page's column at a 1280 px window (62 rem less the padding, 16 px rem), in inches at 96
#: px per inch: a report's figure is drawn this wide, so it shows at its own size
COLUMN_IN = 960 / 96
#: the smallest text in a report's figure, pt, at the figure's own size (as it shows at 1280 px)
MIN_FIGURE_PT = 9.0
#: a phone's column (a 412 px window less the narrow page's padding and the image's border, with
#: room for a 360 px phone to show it at 90 %), in inches at 96 px per inch: each figure is drawn
#: again this wide for windows up to :data:`NARROW_MEDIA`, so its text keeps 9 pt (12 px), not
#: the 40 % of it a 960 px figure would show at
NARROW_IN = 380 / 96
#: the windows that get the narrow figure: up to 50 rem, where the column figure would show at
#: less than 80 % (9.6 px for 12 px text)
NARROW_MEDIA = "(max-width: 50rem)"


@dataclass(frozen=True)
class Figure:
    """A figure embedded in the page: ``data_uri`` (``data:image/png;base64,...``) with its caption;
    ``min_font_px``: its smallest text's height in the image's pixels (0: not known), which
    ``benchmarks/check_reports_browser.py`` turns into points as the page shows it;
    ``expect``: tuple of (x0, y0, x1, y1, colour, present), boxes in the image's pixels (y down)
    where ink of ``colour`` must show (``present``) or must not, which the browser check reads
    from the image (:func:`expect_ink`); ``narrow_uri``: the same figure drawn :data:`NARROW_IN`
    wide for a phone (empty: none), its text as large in its pixels as the column figure's."""

    caption: str
    data_uri: str
    alt: str = ""
    min_font_px: float = 0.0
    expect: tuple = ()
    narrow_uri: str = ""


@dataclass(frozen=True)
class Table:
    """A table of numbers: ``header`` (tuple of str, units in the header) and ``rows`` (tuple of
    tuples of str, already formatted); ``note`` under it; ``wrap``: a table of words (its cells
    wrap and align left, as the "what was run" table) rather than of numbers."""

    caption: str
    header: tuple
    rows: tuple
    note: str = ""
    wrap: bool = False


@dataclass(frozen=True)
class Headline:
    """The first thing a report says (drawn from a command's
    :class:`metrology.core.verdict.Verdict` by :func:`verdict_box`).

    ok : True (within tolerance), False (not), None (no tolerance applies: information)
    headline : str, one sentence (the numbers against the tolerance)
    cause : str, the cause named (or why it passed); empty when there is nothing to add
    label : str, the finding, shown beside the verdict's word (never instead of it): what was
        found where no tolerance was stated ("flat within the noise"), the cause named ("cause:
        drift on L3"), the drift alarms; the demo's overview gives it after the word
    checks : tuple of (tag, words), one line per judged quantity, each coloured by its tag:
        ``pass``, ``FAIL`` (a limit the user set), ``info`` or ``note`` (information within
        or beyond a limit the user did not set) (:func:`metrology.report.verdicts.check_words`)
    """

    ok: bool | None
    headline: str
    cause: str = ""
    label: str = ""
    checks: tuple = ()

    @property
    def word(self) -> str:
        """passed, FAILED or information: the terminal's word (:func:`metrology.report.verdicts.verdict_word`)."""
        return WORDS[self.ok]

    @property
    def finding(self) -> str:
        return self.label


#: the verdict's words: passed (every gating check passed), FAILED, information (nothing gated)
WORDS = {True: "passed", False: "FAILED", None: "information"}


def verdict_box(verdict, headline: str, cause: str = "", label: str = "") -> "Headline":
    """The report's :class:`Headline` of a :class:`metrology.core.verdict.Verdict`, in the
    terminal's words (:func:`metrology.report.verdicts.verdict_word`); one line per check."""
    from metrology.report.verdicts import check_words, verdict_word

    ok = {"passed": True, "FAILED": False, "information": None}[verdict_word(verdict)]
    return Headline(ok, headline, cause, label, tuple(check_words(c) for c in verdict.checks))


@dataclass(frozen=True)
class Section:
    """What one command found.

    title : str; verdict : Headline; figures : tuple of Figure; tables : tuple of Table;
    text : tuple of str, preformatted blocks (the command's text output, a fit report);
    limits : tuple of str, what the data could not determine; next_steps : tuple of str,
    what to do next (poses to add, a command to run, a datum to re-measure);
    link : str, a relative link to this section's own report (the demo's index);
    statements : tuple of str, what the section states (a certificate's conditions)
    """

    title: str
    verdict: Headline
    figures: tuple = ()
    tables: tuple = ()
    text: tuple = ()
    limits: tuple = ()
    next_steps: tuple = ()
    link: str = ""
    statements: tuple = ()


@dataclass(frozen=True)
class RunInfo:
    """What was run: the command line, each input with its SHA-256, the versions, the seed.

    inputs : tuple of (role, path, sha256 hex, size in bytes); versions : tuple of (name,
    version); seed : int or None; written : str, UTC time (``SOURCE_DATE_EPOCH`` when set,
    for byte-identical reports)
    """

    command: str
    inputs: tuple = ()
    versions: tuple = ()
    seed: int | None = None
    written: str = ""
    python: str = field(default_factory=platform.python_version)


def versions(extra=()) -> tuple:
    """(name, version) of metro and the libraries its numbers depend on, from the installed
    distributions' metadata (no import of the libraries themselves); ``extra``: more
    distributions a command's numbers depend on (measure: pyarrow, dask)."""
    from importlib.metadata import PackageNotFoundError, version

    out = []
    for group in (*_VERSIONED, *((e,) for e in extra)):
        for dist in group:
            try:
                out.append((dist, version(dist)))
                break
            except PackageNotFoundError:
                continue
        else:
            out.append((group[-1], "not installed"))
    return tuple(out)


def _written() -> str:
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    t = datetime.fromtimestamp(int(epoch), timezone.utc) if epoch else datetime.now(timezone.utc)
    return t.strftime("%Y-%m-%d %H:%M:%S UTC")


def written() -> str:
    """The time a file is written, UTC (``SOURCE_DATE_EPOCH`` when set)."""
    return _written()


def command_line() -> str:
    """This process's command line, as a shell would take it back (``metro ...``)."""
    import shlex
    import sys

    return shlex.join(["metro", *sys.argv[1:]])


def run_info(inputs: dict, command: str | None = None, seed: int | None = None, extra_versions=()) -> RunInfo:
    """A :class:`RunInfo` for ``inputs`` (role -> path; None values are skipped; a path that is
    not a file, such as a generated grid, is listed without checksum). ``command`` None: this
    process's :func:`command_line`."""
    command = command_line() if command is None else command
    rows = []
    for role, path in inputs.items():
        if path is None:
            continue
        p = Path(path)
        if p.is_file():
            rows.append((role, display_name(path), sha256_file(p), p.stat().st_size))
        else:
            rows.append((role, display_name(path), "", 0))
    return RunInfo(command=command, inputs=tuple(rows), versions=versions(extra_versions), seed=seed, written=_written())


def _png_uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def figure_from_png(png: bytes, caption: str, alt: str = "", min_font_px: float = 0.0, expect: tuple = (),
                    narrow_png: bytes = b"") -> Figure:
    """Embed PNG bytes as a :class:`Figure` (``narrow_png``: its phone version, optional)."""
    return Figure(caption, _png_uri(png), alt or caption, min_font_px, tuple(expect),
                  _png_uri(narrow_png) if narrow_png else "")


def expect_ink(ax, xs, ys, colour, present: bool, pad_px=(0, 0)) -> None:
    """State that ``ax``'s figure shows (``present``) or does not show ink of ``colour`` within
    the box ``xs`` x ``ys`` (data coordinates), grown by ``pad_px`` (x, y; image pixels; negative
    shrinks it). :func:`figure_from_matplotlib` turns it into image pixels once the figure is
    laid out (:attr:`Figure.expect`)."""
    ax.figure.__dict__.setdefault("_metro_expect", []).append((ax, tuple(xs), tuple(ys), colour, bool(present),
                                                              tuple(pad_px)))


def _expected_boxes(fig, dpi) -> tuple:
    """The figure's :func:`expect_ink` boxes in the pixels of its image at ``dpi``."""
    fig.set_dpi(dpi)
    height = fig.get_size_inches()[1] * dpi
    out = []
    for ax, xs, ys, colour, present, (px, py) in fig.__dict__.get("_metro_expect", []):
        (x0, y0), (x1, y1) = ax.transData.transform([(min(xs), min(ys)), (max(xs), max(ys))])
        out.append((round(x0 - px, 1), round(height - y1 - py, 1), round(x1 + px, 1), round(height - y0 + py, 1),
                    colour, present))
    return tuple(out)


def fit_to_column(fig) -> float:
    """Draw ``fig`` for the page: no wider than :data:`COLUMN_IN` (the height kept), every text at
    least :data:`MIN_FIGURE_PT`, laid out again; returns its smallest text size, pt."""
    from matplotlib.text import Text

    w, h = fig.get_size_inches()
    if w > COLUMN_IN:
        fig.set_size_inches(COLUMN_IN, h)
    texts = [t for t in fig.findobj(Text) if t.get_visible() and t.get_text().strip()]
    for t in texts:
        if t.get_fontsize() < MIN_FIGURE_PT:
            t.set_fontsize(MIN_FIGURE_PT)
    _relayout(fig)
    return min((t.get_fontsize() for t in texts), default=MIN_FIGURE_PT)


def figure_from_matplotlib(fig, caption: str, alt: str = "", dpi: int = 96) -> Figure:
    """Embed a matplotlib figure as PNG (and close it), drawn for the page (:func:`fit_to_column`)."""
    import io

    from metrology.report.style import close

    buf, narrow = io.BytesIO(), io.BytesIO()
    try:
        pt = fit_to_column(fig)
        expect = _expected_boxes(fig, dpi)
        fig.savefig(buf, format="png", dpi=dpi)
        _narrow(fig)
        fig.savefig(narrow, format="png", dpi=dpi)
    finally:
        close(fig)
    return figure_from_png(buf.getvalue(), caption, alt, pt * dpi / 72.0, expect, narrow.getvalue())


def _narrow(fig) -> None:
    """Lay ``fig`` out again :data:`NARROW_IN` wide, its text as it is: taller by the square root
    of the narrowing (a row of panels gets room to breathe), no more than twice; an axis label or
    title longer than its axes is wrapped onto more lines."""
    w, h = fig.get_size_inches()
    fig.set_size_inches(NARROW_IN, h * min(2.0, max(1.0, (w / NARROW_IN) ** 0.5)))
    _relayout(fig)
    if _wrap_long_labels(fig):
        _relayout(fig)


def _relayout(fig) -> None:
    """Lay ``fig`` out for its size: its own layout engine (constrained) does at each draw; else
    ``tight_layout`` once more (one called earlier leaves only a placeholder engine)."""
    import warnings

    from matplotlib.layout_engine import ConstrainedLayoutEngine

    if isinstance(fig.get_layout_engine(), ConstrainedLayoutEngine):
        return
    with warnings.catch_warnings():  # a figure tight_layout cannot improve is drawn as it is
        warnings.simplefilter("ignore")
        fig.tight_layout()


def _wrap_long_labels(fig) -> bool:
    """Wrap each axis label and title wider than its axes (a y label: taller), and the figure's
    title wider than the figure, at spaces; True when one was."""
    import textwrap

    renderer = fig.canvas.get_renderer()
    changed = False
    width = fig.get_size_inches()[0] * fig.dpi * 0.96
    boxes = [(fig._suptitle, width, "width")] if fig._suptitle is not None else []
    for ax in fig.axes:
        box = ax.get_window_extent(renderer)
        boxes += [(ax.xaxis.label, box.width, "width"), (ax.title, box.width, "width"),
                  (ax.yaxis.label, box.height, "height")]
    for text, room, along in boxes:
        lines = text.get_text().split("\n")
        size = getattr(text.get_window_extent(renderer), along)
        if any(lines) and size > room > 0:
            chars = max(8, int(max(map(len, lines)) * room / size * 0.95))
            text.set_text("\n".join(textwrap.fill(line, chars) for line in lines))
            changed = True
    return changed


def check_report_path(path) -> None:
    """Refuse a ``--report`` path before any work: not ``.html``/``.htm``, a folder, or in a
    folder that does not exist (ValueError naming the path)."""
    from metrology.io.atomic import check_output_file

    check_output_file(path, "--report", REPORT_SUFFIXES)


#: the pages rendered inside :func:`collect` (title, run, sections), else None
_COLLECTED: list | None = None


@contextmanager
def collect():
    """Keep every page rendered inside the block: yields a list that receives (title, RunInfo,
    sections) per :func:`render_html` call (``metro demo --report`` gathers its steps' pages
    this way into one report)."""
    global _COLLECTED
    saved, _COLLECTED = _COLLECTED, []
    try:
        yield _COLLECTED
    finally:
        _COLLECTED = saved


def render_html(title: str, run: RunInfo, sections) -> str:
    """The page (str) of ``sections`` under ``run``, rendered from ``templates/report.html.j2``."""
    import jinja2

    sections = list(sections)
    if _COLLECTED is not None:
        _COLLECTED.append((title, run, sections))
    env = jinja2.Environment(loader=jinja2.PackageLoader("metrology.report", "templates"),
                             autoescape=jinja2.select_autoescape(["html", "j2"]), trim_blocks=True, lstrip_blocks=True,
                             undefined=jinja2.StrictUndefined)
    env.filters["ticks"] = _ticks
    env.filters["words"] = _words
    overall = [s.verdict.ok for s in sections]
    ok = False if False in overall else (True if True in overall else None)
    return env.get_template("report.html.j2").render(title=title, run=run, sections=list(sections), overall=ok,
                                                     words=WORDS, narrow_media=NARROW_MEDIA)


#: words of prose kept on one line: an option (``--out``, ``-n``) or an id with a number after
#: a hyphen (``C1-00012006``); prose may break ``re-mounted`` at its hyphen, not these
_WHOLE = r"(?<![\w-])(?:--?[A-Za-z][\w.-]*|[A-Za-z]\w*-\d[\w.:-]*)"


def _keep_whole(escaped: str) -> str:
    import re

    return re.sub(_WHOLE, lambda m: f'<span class="nb">{m.group(0)}</span>', escaped)


def _ticks(text):
    """Escape ``text``, show its `backticked` spans as code and keep its options and ids whole
    (:data:`_WHOLE`)."""
    import re

    import markupsafe

    out = re.sub(r"`([^`]+)`", r"<code>\1</code>", str(markupsafe.escape(text)))
    return markupsafe.Markup(_keep_whole(out))


#: the longest word a report never breaks across lines (an id, a time, an option such as
#: ``--out``, a short path); a longer one (a long path) breaks where the line ends
NOWRAP_CHARS = 20


def _words(text):
    """Escape ``text`` and keep each of its words of at most :data:`NOWRAP_CHARS` characters on
    one line (``<span class="nb">``): a table cell or a command line breaks between words, never
    inside a hole id or at the ``-`` of ``--out``. The text is unchanged (to copy)."""
    import markupsafe

    return markupsafe.Markup(" ").join(markupsafe.Markup('<span class="nb">{}</span>').format(w)
                                      if 0 < len(w) <= NOWRAP_CHARS else markupsafe.escape(w)
                                      for w in str(text).split(" "))


def write_report(path, title: str, run: RunInfo, sections) -> Path:
    """Render and write the report to ``path`` atomically; return the path."""
    from metrology.io.atomic import write_text

    write_text(path, render_html(title, run, sections))
    return Path(path)
