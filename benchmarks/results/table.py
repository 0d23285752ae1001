"""Tabulate the blind studies saved here (``study_blind.py --json``) as ``diagnose.md`` beside them.

    python benchmarks/results/table.py            # writes benchmarks/results/diagnose.md

Every ``*.json`` of this folder written by ``benchmarks/study_blind.py`` is one section: the
command's arguments, its wall time, and per family the rates of its ``summary`` (nothing is
recomputed from the records). The hand-written history of earlier rounds is
``diagnose_history.md``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _pct(k, n):
    return f"{k}/{n}" if n else "-"


def section(name: str, data: dict) -> list:
    a, s = data["args"], data["summary"]
    cmd = (f"python benchmarks/study_blind.py --draws {a['draws']} --nulls {a['nulls']} --pairs {a['pairs']} "
           f"--seed {a['seed']} --jobs {a['jobs']}" + (f" --families {a['families']}" if a.get("families") else "")
           + (f" --size-range {a['size_range']}" if a.get("size_range") else ""))
    wall = "" if data.get("wall_s") is None else f" in {data['wall_s']:.0f} s"
    code = f" (code: {data['code']})" if data.get("code") else ""
    out = [f"## {name}", "", f"`{cmd}`: {len(data['records'])} cases{wall}{code}", "",
           "| family | right cause and sensor | above the case's detectable size | a wrong cause | size within 2σ "
           "| median detectable (mm) |", "| --- | --- | --- | --- | --- | --- |"]
    for f, r in s["families"].items():
        if not r["n"]:
            continue
        out.append(f"| `{f}` | {_pct(r['right'], r['n'])} | {_pct(r['right_detectable'], r['n_detectable'])} | "
                   f"{r['wrong_named']} | {_pct(r['covered_2sigma'], r['n_size']) if r['n_size'] else 'n/a'} | "
                   f"{r['detectable_median']:.3g} |")
    n = s["null"]
    out += ["", f"- nulls: {n['n'] - n['false_cause']} of {n['n']} `none`; a catalogued cause named on "
                f"{n['named_catalogued']}; confusion {s['confusion'].get('none', {})}"]
    if s.get("false_shift"):
        fs = s["false_shift"]
        out.append(f"- `shift` named where no sensor was knocked: {fs['named']} of {fs['n']} cases "
                   f"({fs['nulls']} of {fs['n_nulls']} nulls)")
    if s.get("datum_flat") and s["datum_flat"]["n"]:
        df = s["datum_flat"]
        out.append(f"- datum check 'disagrees' on flat datums: {df['disagrees']} of {df['n']} cases; nulls "
                   f"{df['disagrees_nulls']} of {df['n_nulls']} (p < 0.05: {df['p_below_0.05_nulls']})")
    if s["ooc"]["n"]:
        o = s["ooc"]
        out.append(f"- out of the catalogue named as a catalogued cause: {o['catalogued_named']} of {o['n']}; "
                   f"{o['by_family']}")
    h = s["high_precision"]
    out.append(f"- `confidence: high` right (nulls and singles): {_pct(h['right'], h['n'])}")
    return out + [""]


def main(argv=None):
    lines = ["# Blind studies of `metro diagnose` (machine-written: `python benchmarks/results/table.py`)", ""]
    for p in sorted(HERE.glob("*.json")):
        data = json.loads(p.read_text())
        if "summary" in data and "records" in data:
            lines += section(p.stem, data)
    text = "\n".join(lines)
    if argv and "--stdout" in argv:
        sys.stdout.write(text)
        return
    (HERE / "diagnose.md").write_text(text)


if __name__ == "__main__":
    main(sys.argv[1:])
