"""Open every command's HTML report in headless Chromium: a screenshot each, no console
message, no external request.

A developer's check, not a dependency: it needs a ``chromium`` binary on the PATH (Debian:
``apt-get install chromium``); metro itself never needs a browser.

    python benchmarks/check_reports_browser.py                 # runs `metro demo --report` first
    python benchmarks/check_reports_browser.py a.html b.html   # checks these reports
    python benchmarks/check_reports_browser.py --width 412     # a phone's width

For each report it checks, and prints one line:

* statically (html.parser): no ``src``/``href`` to ``http(s)://`` or ``//``, no ``<script>``,
  no ``<link>`` to a stylesheet, every ``<img>`` a ``data:`` URI;
* in Chromium (``--enable-logging=stderr --v=0``): no ``CONSOLE`` line on stderr (our pages
  have no script, so any console message is an error), and no request from the page to an
  ``http(s)`` URL in Chromium's network log (``--log-net-log``; Chromium's own background
  requests are told apart by their network partition).

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


def browse(report: Path, shot: Path, width: int, height: int, chromium: str) -> list:
    """Screenshot ``report`` in headless Chromium; return the console lines and requests seen."""
    with tempfile.TemporaryDirectory() as profile:
        netlog = Path(profile) / "net.json"
        cmd = [chromium, *CHROMIUM_FLAGS, f"--user-data-dir={profile}/p", f"--log-net-log={netlog}",
               f"--screenshot={shot}", f"--window-size={width},{height}", report.resolve().as_uri()]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        problems = [f"console: {line.split('CONSOLE', 1)[1][:100]}" for line in r.stderr.splitlines()
                    if ":CONSOLE" in line]
        problems += [f"request: {u[:80]}" for u in _requests(netlog)]
        if r.returncode != 0 or not shot.exists():
            problems.append(f"chromium exit {r.returncode}, no screenshot")
    return problems


def _demo_reports(folder: Path) -> list:
    out = folder / "demo"
    cmd = [sys.executable, "-m", "cli.main", "demo", "--out", str(out), "--report", str(folder / "demo.html")]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return [folder / "demo.html"] + sorted(out.glob("*.html"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("reports", nargs="*", type=Path, help="HTML reports (default: run `metro demo --report`)")
    ap.add_argument("--width", type=int, default=1000, help="window width, px (412: a phone)")
    ap.add_argument("--height", type=int, default=2400, help="window height, px (the screenshot's)")
    ap.add_argument("--shots", type=Path, default=None, help="folder for the screenshots (default: beside each report)")
    ap.add_argument("--work", type=Path, default=None, help="folder for the demo's reports (default: a temporary one)")
    args = ap.parse_args(argv)
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
        shot = (args.shots / f"{rep.stem}.png") if args.shots else rep.with_suffix(".png")
        if args.shots:
            args.shots.mkdir(parents=True, exist_ok=True)
        problems = static_problems(rep.read_text(encoding="utf-8")) + browse(rep, shot, args.width, args.height,
                                                                            chromium)
        failed += bool(problems)
        print(f"{'FAIL' if problems else 'ok  '} {rep} ({rep.stat().st_size // 1024} KiB) -> {shot}"
              + "".join(f"\n      {p}" for p in problems))
    if tmp is not None and args.work is None:
        print(f"reports and screenshots in {tmp}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
