"""Two runs of the blind study on the same seed, case by case (``study_blind.py --json``).

    python benchmarks/results/compare.py BEFORE.json AFTER.json [--out FILE.md]

The runs must hold the same cases (the same ``--draws --nulls --pairs --seed``). Printed as
markdown: the per-family rates of both runs side by side (from each run's ``summary``, nothing
recomputed), then every case whose verdict changed (cause, confidence or the causes named, with
their sensors), with its truth, so a change of code is judged on the same draws.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _key(r: dict) -> tuple:
    return tuple(r["seed"])


def _verdict(r: dict) -> str:
    named = ", ".join(f"{c}" + (f" ({'+'.join(s)})" if s else "") for c, s in r["named"]) or "-"
    return f"`{r['cause']}` {r['confidence']}; named: {named}"


def _truth(r: dict) -> str:
    if not r["truth"]:
        return "null"
    return ", ".join(f"{t['family']}" + (f" ({'+'.join(t['sensors'])})" if t["sensors"] else "")
                     + (f" {t['size']:.3g} mm" if isinstance(t.get("size"), (int, float)) else "")
                     + ("" if t.get("inside") is None else (" above" if t["inside"] else " below") + " detectable")
                     for t in r["truth"])


def _rate(x: dict, k: str, n: str) -> str:
    return f"{x[k]}/{x[n]}" if x[n] else "-"


def compare(before: dict, after: dict, names=("before", "after")) -> list:
    rb, ra = {_key(r): r for r in before["records"]}, {_key(r): r for r in after["records"]}
    if set(rb) != set(ra):
        raise SystemExit(f"error: the runs hold different cases ({len(set(rb) ^ set(ra))} not in both)")
    sb, sa = before["summary"], after["summary"]
    out = [f"| family | right, {names[0]} | right, {names[1]} | above detectable, {names[0]} "
           f"| above detectable, {names[1]} | wrong cause, {names[0]} | wrong cause, {names[1]} |",
           "| --- | --- | --- | --- | --- | --- | --- |"]
    for f, x in sb["families"].items():
        y = sa["families"][f]
        if not x["n"]:
            continue
        out.append(f"| `{f}` | {_rate(x, 'right', 'n')} | {_rate(y, 'right', 'n')} | "
                   f"{_rate(x, 'right_detectable', 'n_detectable')} | {_rate(y, 'right_detectable', 'n_detectable')} | "
                   f"{x['wrong_named']} | {y['wrong_named']} |")
    nb, na = sb["null"], sa["null"]
    out += ["", f"- nulls `none`: {nb['n'] - nb['false_cause']}/{nb['n']} {names[0]}, "
                f"{na['n'] - na['false_cause']}/{na['n']} {names[1]}; a catalogued cause named: "
                f"{nb['named_catalogued']} and {na['named_catalogued']}"]
    if sb.get("false_shift") and sa.get("false_shift"):
        out.append(f"- `shift` where no sensor was knocked: {sb['false_shift']['named']} and "
                   f"{sa['false_shift']['named']} (nulls: {sb['false_shift']['nulls']} and {sa['false_shift']['nulls']})")
    pb, pa = sb.get("pairs") or {}, sa.get("pairs") or {}
    if pb.get("n"):
        out.append(f"- pairs both named: {pb['both_right']}/{pb['n']} and {pa['both_right']}/{pa['n']}; both above "
                   f"detectable: {_rate(pb, 'both_right_detectable', 'n_detectable')} and "
                   f"{_rate(pa, 'both_right_detectable', 'n_detectable')}; a wrong cause added: "
                   f"{pb['wrong_added']} and {pa['wrong_added']}")
    if sb["ooc"]["n"]:
        out.append(f"- out of the catalogue named as a catalogued cause: {sb['ooc']['catalogued_named']} and "
                   f"{sa['ooc']['catalogued_named']} of {sb['ooc']['n']}")
    hb, ha = sb["high_precision"], sa["high_precision"]
    out.append(f"- `confidence: high` right: {_rate(hb, 'right', 'n')} and {_rate(ha, 'right', 'n')}")
    changed = [k for k in rb if (rb[k]["cause"], rb[k]["confidence"], rb[k]["named"])
               != (ra[k]["cause"], ra[k]["confidence"], ra[k]["named"])]
    out += ["", f"{len(changed)} of {len(rb)} verdicts changed" + (":" if changed else ".")]
    if changed:
        out += ["", f"| case (seed) | truth | {names[0]} | {names[1]} |", "| --- | --- | --- | --- |"]
        for k in changed:
            out.append(f"| {rb[k]['kind']} {list(k)} | {_truth(rb[k])} | {_verdict(rb[k])} | {_verdict(ra[k])} |")
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before")
    ap.add_argument("after")
    ap.add_argument("--names", default="before,after", help="the two runs' names in the table")
    ap.add_argument("--out", help="write the markdown here (default: standard output)")
    a = ap.parse_args(argv)
    before, after = (json.loads(Path(p).read_text()) for p in (a.before, a.after))
    text = "\n".join(compare(before, after, tuple(a.names.split(",")))) + "\n"
    if a.out:
        Path(a.out).write_text(text)
    else:
        sys.stdout.write(text)


if __name__ == "__main__":
    main()
