"""Open every command's HTML report in headless Chromium: a screenshot each, no console
message, no external request.

A developer's check, not a dependency: it needs a ``chromium`` binary on the PATH (Debian:
``apt-get install chromium``); metro itself never needs a browser.

    python benchmarks/check_reports_browser.py                 # runs `metro demo --report` first
    python benchmarks/check_reports_browser.py a.html b.html   # checks these reports
    python benchmarks/check_reports_browser.py --widths 412    # a phone's width only

Each report is checked at every width of ``--widths`` (default 1280 and 412 px). For each
report and width it checks, and prints one line:

* statically (html.parser): no ``src``/``href`` to ``http(s)://`` or ``//``, no ``<script>``,
  no ``<link>`` to a stylesheet, every ``<img>`` a ``data:`` URI;
* in Chromium (``--enable-logging=stderr --v=0``): no ``CONSOLE`` line on stderr (our pages
  have no script, so any console message is an error), and no request from the page to an
  ``http(s)`` URL in Chromium's network log (``--log-net-log``; Chromium's own background
  requests are told apart by their network partition);
* the layout, measured in the same Chromium run (one a report and width: the screenshot, the console,
  the network log and ``--dump-dom`` of a copy of the page with a measuring script added, the report
  itself has none; the script writes nothing to the console and asks for nothing): no clipped text, i.e. no text block (``pre``,
  ``p``, ``li``, a table cell, a ``div`` such as a table's scroll box) whose ``scrollWidth``
  exceeds its ``clientWidth``, and a page no wider than the window; and at widths of 1280 px
  and more, no figure whose smallest text shows below ``--min-figure-pt`` (9 pt), and at every
  width none below ``--min-figure-px`` (9 CSS px, a phone's least legible): the report states
  each figure's smallest text in image pixels (``data-min-font-px``), shown at ``clientWidth /
  naturalWidth`` of that (of the image the browser chose: a report may offer a narrow one),
  0.75 pt per CSS px; and no word broken across lines (its text's client rectangles on two
  lines): in a table cell or the command line, no word of at most :data:`WORD_CHARS` characters
  (a hole id, a time, an option such as ``--out``); in prose (paragraphs, list items,
  captions), no option (``--out``) or id (``C1-00012006``), while ``re-mounted`` may break as
  prose does;
* what a figure must show, read from its pixels in Chromium (a canvas): a figure may state boxes
  (``data-expect``: x0, y0, x1, y1 in image pixels, a colour, present or not) where ink of that
  colour must show or must not (the drift chart: its line reaches h at each alarm, and no line
  joins an alarm to the next baseline's first hole). A pixel is that colour's ink within 0.3 of
  it in RGB (0-1) distance. The boxes are the column figure's: checked where the page shows it
  (not the narrow figure a phone's window gets).

Screenshots go next to each report (``<report>.png``, or ``--shots DIR``). Exit status 1 when
any check fails.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from html.parser import HTMLParser
from pathlib import Path

CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                  "--disable-component-update", "--no-first-run", "--hide-scrollbars", "--enable-logging=stderr",
                  "--v=0")


class _Refs(HTMLParser):
    """Collect every URL-valued attribute and the tags that would load something."""

    def __init__(self):
        super().__init__()
        self.urls, self.scripts, self.stylesheets, self.images = [], 0, 0, []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        for key in ("src", "href", "srcset", "poster", "data", "action"):
            if a.get(key):
                self.urls.append(a[key])
        if tag == "script":
            self.scripts += 1
        if tag == "link" and "stylesheet" in (a.get("rel") or ""):
            self.stylesheets += 1
        if tag == "img":
            self.images.append(a.get("src") or "")


def static_problems(html: str) -> list:
    """What in the page's markup would reach outside it (list of str; empty when none)."""
    p = _Refs()
    p.feed(html)
    out = [f"external URL {u[:60]}" for u in p.urls if u.lower().startswith(("http://", "https://", "//"))]
    if p.scripts:
        out.append(f"{p.scripts} <script>")
    if p.stylesheets:
        out.append(f"{p.stylesheets} <link rel=stylesheet>")
    out += [f"<img> not embedded: {s[:60]}" for s in p.images if not s.startswith("data:")]
    if "url(http" in html.replace(" ", ""):
        out.append("CSS url() to the network")
    return out


def _requests(netlog: Path) -> list:
    """The http(s) URLs the page asked for, from Chromium's network log: the requests started
    in the page's network partition (``network_isolation_key`` of its ``file://`` origin).
    Chromium's own background requests (update checks, spelling dictionary, clock), which
    ``--disable-background-networking`` does not silence, have other keys and are not the
    page's."""
    data = json.loads(netlog.read_text(encoding="utf-8", errors="replace"))
    start = data["constants"]["logEventTypes"]["URL_REQUEST_START_JOB"]
    urls = set()
    for e in data.get("events", []):
        p = e.get("params") or {}
        u = p.get("url")
        if (e.get("type") == start and isinstance(u, str) and u.startswith(("http://", "https://"))
                and "file://" in str(p.get("network_isolation_key", ""))):
            urls.add(u)
    return sorted(urls)


#: headless Chromium keeps its window 500 px wide or more: a narrower page is drawn in an
#: iframe of that width (``srcdoc``: the page's own origin, its media queries at the iframe's width)
MIN_WINDOW = 500


def drawn_at(text: str, width: int, height: int) -> str:
    """``text`` (a page) as drawn ``width`` CSS px wide: itself, or inside an iframe that wide."""
    import html as html_lib

    if width >= MIN_WINDOW:
        return text
    return (f'<!DOCTYPE html><html><body style="margin:0"><iframe style="border:0;width:{width}px;height:{height}px" '
            f'srcdoc="{html_lib.escape(text, quote=True)}"></iframe></body></html>')


def browse(report: Path, shot: Path, width: int, height: int, chromium: str, min_pt: float = 9.0,
           min_px: float = 9.0) -> list:
    """``report`` in one headless Chromium run at ``width`` px: its screenshot, and the console lines, the
    requests and the layout's problems (:func:`layout_problems`) seen (list of str; empty when none)."""
    with tempfile.TemporaryDirectory() as profile:
        netlog = Path(profile) / "net.json"
        page = measuring_copy(report, Path(profile), width, height)
        cmd = [chromium, *CHROMIUM_FLAGS, f"--user-data-dir={profile}/p", f"--log-net-log={netlog}",
               "--virtual-time-budget=10000", f"--screenshot={shot}", "--dump-dom",
               f"--window-size={max(width, MIN_WINDOW)},{height}", page.as_uri()]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
        problems = [f"console: {line.split('CONSOLE', 1)[1][:100]}" for line in r.stderr.splitlines()
                    if ":CONSOLE" in line]
        problems += [f"request: {u[:80]}" for u in _requests(netlog)]
        if r.returncode != 0 or not shot.exists():
            problems.append(f"chromium exit {r.returncode}, no screenshot")
    return problems + layout_problems(r.stdout, r.returncode, width, min_pt, min_px)


#: the longest word (characters between spaces) that must never break across lines: ids, times,
#: numbers and options; longer ones (paths) may
WORD_CHARS = 20

#: added to a copy of the page: measures the layout once the page has loaded and writes the
#: result, as JSON, into a <pre id="metro-check"> that --dump-dom prints
MEASURE = r"""<script>
window.addEventListener("load", () => {
  const out = {window: window.innerWidth, page: document.documentElement.scrollWidth, clipped: [], figures: []};
  for (const el of document.querySelectorAll("pre, p, li, td, th, caption, figcaption, h1, h2, h3, div, table")) {
    if (el.clientWidth > 0 && el.scrollWidth > el.clientWidth + 1) {
      out.clipped.push(el.tagName.toLowerCase() + (el.className ? "." + el.className : "") + " by "
                       + (el.scrollWidth - el.clientWidth) + " px: " + el.textContent.trim().slice(0, 50));
    }
  }
  for (const img of document.querySelectorAll("img[data-min-font-px]")) {
    const px = parseFloat(img.dataset.minFontPx) * img.clientWidth / img.naturalWidth;
    out.figures.push({alt: img.alt.slice(0, 60), pt: 0.75 * px, px: px});
  }
  out.broken = [];
  for (const el of document.querySelectorAll("td, th, li, .command, p, figcaption, caption")) {
    const cell = el.matches("td, th, .command");
    const walker = document.createTreeWalker(el, NodeFilter.SHOW_TEXT);
    for (let node = walker.nextNode(); node; node = walker.nextNode()) {
      if (!cell && node.parentElement.closest("td, th, .command") !== el.closest("td, th, .command")) continue;
      for (const m of node.data.matchAll(/\S+/g)) {
        if (m[0].length > WORD_CHARS || m[0].length < 2) continue;
        if (!cell && !/^[(\[]?(--?[A-Za-z]|[A-Za-z]\w*-\d)/.test(m[0])) continue;  // prose: options and ids only
        const r = document.createRange();
        r.setStart(node, m.index); r.setEnd(node, m.index + m[0].length);
        const tops = new Set([...r.getClientRects()].filter(q => q.width > 0).map(q => Math.round(q.top)));
        if (tops.size > 1) out.broken.push(el.tagName.toLowerCase() + ": " + m[0]);
      }
    }
  }
  out.broken = [...new Set(out.broken)];
  out.ink = [];
  for (const img of document.querySelectorAll("img[data-expect]")) {
    if (img.currentSrc !== img.src) continue;  // the boxes are the column figure's, not the narrow one's
    const c = document.createElement("canvas");
    c.width = img.naturalWidth; c.height = img.naturalHeight;
    const g = c.getContext("2d", {willReadFrequently: true});  // else Chromium warns on the console at a second box
    g.drawImage(img, 0, 0);
    for (const [x0, y0, x1, y1, colour, present] of JSON.parse(img.dataset.expect)) {
      const want = [1, 3, 5].map(i => parseInt(colour.slice(i, i + 2), 16));
      const X0 = Math.max(0, Math.floor(x0)), Y0 = Math.max(0, Math.floor(y0));
      const w = Math.min(c.width, Math.ceil(x1) + 1) - X0, h = Math.min(c.height, Math.ceil(y1) + 1) - Y0;
      let found = false;
      if (w > 0 && h > 0) {
        const d = g.getImageData(X0, Y0, w, h).data;
        for (let i = 0; i < d.length && !found; i += 4) {
          const e = Math.hypot(d[i] - want[0], d[i + 1] - want[1], d[i + 2] - want[2]) / 255;
          found = e < 0.3;
        }
      }
      if (found !== present) {
        out.ink.push((present ? "no " : "") + colour + " ink in [" + [x0, y0, x1, y1].join(", ") + "] of "
                     + img.alt.slice(0, 50));
      }
    }
  }
  const pre = document.createElement("pre");
  pre.id = "metro-check";
  pre.hidden = true;  // in the dumped DOM, not in the screenshot
  pre.textContent = JSON.stringify(out);
  (window.parent !== window ? window.parent.document : document).body.appendChild(pre);
});
</script>"""


def measuring_copy(report: Path, folder: Path, width: int, height: int) -> Path:
    """A copy of ``report`` in ``folder`` with the measuring script (:data:`MEASURE`) added, drawn ``width`` px wide
    (:func:`drawn_at`)."""
    text = report.read_text(encoding="utf-8")
    copy = folder / report.name
    script = MEASURE.replace("WORD_CHARS", str(WORD_CHARS))
    copy.write_text(drawn_at(text.replace("</body>", script + "\n</body>"), width, height), encoding="utf-8")
    return copy


def layout_problems(dom: str, returncode: int, width: int, min_pt: float, min_px: float = 9.0) -> list:
    """Clipped text blocks and small figure text, from the measuring script's result in the page's dumped ``dom``
    at ``width`` px (list of str)."""
    import html as html_lib
    import re

    m = re.search(r'<pre id="metro-check"[^>]*>(.*?)</pre>', dom, re.S)
    if m is None:
        return [f"layout not measured (chromium exit {returncode})"]
    d = json.loads(html_lib.unescape(m.group(1)))
    out = [f"clipped: {c}" for c in d["clipped"]]
    out += [f"figure: {c}" for c in d.get("ink", [])]
    out += [f"word broken across lines: {w}" for w in d.get("broken", [])[:12]]
    out += [f"figure text {f['px']:.1f} px < {min_px:g} px: {f['alt']}" for f in d["figures"] if f["px"] < min_px - 0.05]
    if d["window"] != width:
        out.append(f"the page was drawn {d['window']} px wide, not {width} px")
    if d["page"] > d["window"]:
        out.append(f"page {d['page']} px wider than the window {d['window']} px")
    if width >= 1280:
        out += [f"figure text {f['pt']:.1f} pt < {min_pt:g} pt: {f['alt']}" for f in d["figures"]
                if f["pt"] < min_pt - 0.05]
    return out


def _demo_reports(folder: Path) -> list:
    out = folder / "demo"
    folder.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "cli.main", "demo", "--out", str(out), "--report", str(folder / "demo.html")]
    r = subprocess.run(cmd, stdout=subprocess.DEVNULL)
    if r.returncode not in (0, 1):  # 1: a step's verdict failed; its report is still written
        raise SystemExit(f"metro demo exited {r.returncode}")
    return [folder / "demo.html"] + sorted(out.glob("*.html"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("reports", nargs="*", type=Path, help="HTML reports (default: run `metro demo --report`)")
    ap.add_argument("--widths", default="1280,412", help="window widths, px, comma-separated (412: a phone)")
    ap.add_argument("--height", type=int, default=2400, help="window height, px (the screenshot's)")
    ap.add_argument("--min-figure-pt", type=float, default=9.0, help="smallest figure text at 1280 px and more, pt")
    ap.add_argument("--min-figure-px", type=float, default=9.0, help="smallest figure text at every width, CSS px")
    ap.add_argument("--shots", type=Path, default=None, help="folder for the screenshots (default: beside each report)")
    ap.add_argument("--work", type=Path, default=None, help="folder for the demo's reports (default: a temporary one)")
    args = ap.parse_args(argv)
    widths = [int(w) for w in args.widths.split(",")]
    chromium = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if chromium is None:
        print("error: no chromium on the PATH (Debian: apt-get install chromium)", file=sys.stderr)
        return 2
    reports = args.reports
    tmp = None
    if not reports:
        work = args.work or Path(tmp := tempfile.mkdtemp(prefix="metro-reports-"))
        reports = _demo_reports(work)
    failed = 0
    for rep in reports:
        for width in widths:
            name = f"{rep.stem}-{width}.png"
            shot = (args.shots / name) if args.shots else rep.with_name(name)
            if args.shots:
                args.shots.mkdir(parents=True, exist_ok=True)
            problems = (static_problems(rep.read_text(encoding="utf-8"))
                        + browse(rep, shot, width, args.height, chromium, args.min_figure_pt, args.min_figure_px))
            failed += bool(problems)
            print(f"{'FAIL' if problems else 'ok  '} {rep} at {width} px ({rep.stat().st_size // 1024} KiB) -> {shot}"
                  + "".join(f"\n      {p}" for p in problems))
    if tmp is not None and args.work is None:
        print(f"reports and screenshots in {tmp}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
