"""Blind study of ``metro diagnose`` on the independent forward simulator (issues 12 and 15).

Cases are drawn by :mod:`metrology.sim.forward` (3- and 4-sensor heads, 3-10 um noise, 40-150
poses, random shapes within each family), written through the public file contract
(``export.csv``, ``layout.toml``, the datum scan ``cloud.ply`` passed as the plane) and diagnosed
by :func:`metrology.jobs.diagnose.diagnose_files` (what ``metro diagnose`` calls). Only the JSON
fields ``cause``, ``sensors``, ``confidence`` and, when present, ``causes`` are read.

Reports: confusion matrix (true family x named cause); right cause AND sensor per family, over
all draws and over the draws whose size is above the case's own detectable size (``detectable``
in the JSON of ``metro diagnose``: the size its test detects at 95 % power on these poses,
:mod:`metrology.diagnosis.detectable`; the truth taken in the same definition, see
:func:`_detect_size`), and, for comparison with earlier runs, inside the upper two thirds of the
family's drawn size range; draws where a wrong catalogued cause was named first, and those where
one was named beside the right one (still counted right in the family's rates); null
false-cause rate with a 95 % Clopper-Pearson interval; the rate of catalogued causes named for
out-of-catalogue effects; precision of ``confidence: high`` (right: the truth named and nothing
else) and of a cause named with ``confidence: moderate``; coverage of the true size by the
reported size +/- 2 stderr (only where the JSON reports a ``size`` in the family's unit;
otherwise "n/a"); for pairs, both-right (over all pairs, over the pairs whose two sizes are
both above their detectable sizes, and both in the upper two thirds, as issue 15 asks) and
wrong-cause-added rates.

    python benchmarks/study_blind.py [--draws 20] [--nulls 200] [--pairs 20] [--jobs 1] [--seed 0] [--json out.json]
        [--families scale,...] [--tilt-max-deg 14] [--size-range LO,HI] [--scan hand] [--poses 30,45]
        [--datum-tilts 20]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections import Counter

import _one_blas_thread  # noqa: F401  (first: one BLAS thread a job; same directory)
import numpy as np

# catalogued families and their pairs, out-of-catalogue effects (metrology.sim.forward.families)
FAMILY_ORDER = ("pose_error", "scale", "nonlinearity", "drift", "incidence", "plane_form", "outliers", "shift")
OOC = ("periodic", "crosstalk")
PAIRS = (("drift", "outliers"), ("scale", "drift"), ("pose_error", "drift"), ("nonlinearity", "outliers"),
         ("plane_form", "drift"), ("scale", "incidence"), ("drift", "drift"), ("pose_error", "outliers"))
#: families acting on every sensor (the sensor list is not scored)
ALL_SENSORS = ("pose_error", "plane_form", "datum_tilt")


def detectable_ranges() -> dict:
    """Stated detectable range per family: upper two thirds of the drawn size range (see module doc)."""
    from metrology.sim.forward import FAMILIES

    out = {}
    for f in FAMILY_ORDER + OOC:
        lo, hi = FAMILIES[f].size_range
        out[f] = (lo + (hi - lo) / 3.0, hi)
    return out


def clopper_pearson(k: int, n: int, alpha: float = 0.05) -> tuple:
    """Exact two-sided (1 - alpha) interval of a binomial rate ``k / n``."""
    from scipy.stats import beta

    if n == 0:
        return (float("nan"), float("nan"))
    lo = 0.0 if k == 0 else float(beta.ppf(alpha / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - alpha / 2, k + 1, n - k))
    return lo, hi


def jobs_for(draws: int, nulls: int, pairs: int, seed: int, families=None, tilts: int = 0) -> list:
    """The study's cases as (kind, families, seed entropy) tuples, in a fixed order; ``families``
    (optional) keeps the single and out-of-catalogue draws of those families only (each case
    keeps the seed it has in the full study); ``tilts`` nulls whose datum scan is tilted off the
    true datum by more than its uncertainty (:func:`tilt_scan`), last (the others keep their seeds)."""
    keep = (lambda f: True) if not families else (lambda f: f in families)
    jobs = [("null", ("none",), (seed, 0, 0, i)) for i in range(nulls)]
    for k, f in enumerate(FAMILY_ORDER):
        jobs += [("single", (f,), (seed, 1, k, i)) for i in range(draws) if keep(f)]
    for k, f in enumerate(OOC):
        jobs += [("ooc", (f,), (seed, 2, k, i)) for i in range(draws) if keep(f)]
    for i in range(pairs):
        jobs.append(("pair", PAIRS[i % len(PAIRS)], (seed, 3, i % len(PAIRS), i)))
    jobs += [("datum", ("datum_tilt",), (seed, 4, 0, i)) for i in range(tilts)]
    return jobs


def _named(result: dict) -> list:
    """[(cause, sensors)] named by the JSON: ``causes`` if given, else the single ``cause``."""
    causes = result.get("causes")
    if causes:
        return [(c["cause"], tuple(c.get("sensors") or ())) for c in causes]
    if result["cause"] in ("none", "unexplained"):
        return []
    return [(result["cause"], tuple(result.get("sensors") or ()))]


def _size(result: dict, family: str):
    """(value, stderr) of the size in the family's unit if the JSON reports one, else None."""
    for c in result.get("causes") or [result.get("extended") or {}]:
        if c and (c.get("cause") or c.get("component")) == family and isinstance(c.get("size"), dict):
            s = c["size"]
            if s.get("value") is not None and s.get("stderr") is not None:
                return float(s["value"]), float(s["stderr"])
    return None


def _true_characteristic(case, effect):
    """(the drawn characteristic curve of a ``scale``/``nonlinearity`` effect, the true distances
    its sensor saw (p,) mm)."""
    from metrology.sim.forward.characteristic import Characteristic

    sh = dict(effect.shape)
    shape, lo, hi = sh.pop("shape"), sh.pop("lo_mm"), sh.pop("hi_mm")
    i = list(case.nominal.names).index(effect.sensors[0])
    return Characteristic(shape, lo, hi, sh), case.d_true[:, i]


def _seen_size(case, effect):
    """The true size in the definition ``metro diagnose`` reports (what the data can show), or None:

    - scale, nonlinearity: peak-to-valley of the true characteristic over the true distances the
      sensor saw (the drawn size is over the whole range, which the poses may not cover);
    - plane_form: peak-to-valley, over the scanned points, of the true datum height less its
      best-fit plane there (a tilt is the plane's own business, and the scan covers what it covers);
    - drift, incidence, shift: the drawn size (already defined on what the run saw);
    - pose_error: RMS over every reading of what the pose error changes (the beams cast from
      the reported pose less those from the true one, the true head): its offset and tilts.
    """
    if effect.family == "pose_error":
        from metrology.sim.forward import cast_beams

        ex = case.export
        hit = cast_beams(case.surface, case.true.zero, case.true.direction, ex.tcs2tracker_rot, ex.tcs2tracker_trans)
        return float(np.sqrt(np.nanmean((hit.d - case.d_true) ** 2)))
    if effect.family in ("drift", "incidence", "shift"):
        return float(effect.size)
    if effect.family in ("scale", "nonlinearity"):
        curve, d = _true_characteristic(case, effect)
        e = curve(np.linspace(np.nanmin(d), np.nanmax(d), 401))
        return float(e.max() - e.min())
    if effect.family == "plane_form":
        s, t, _ = case.surface.plane_coords(case.cloud)
        h = case.surface.height(s, t)
        A = np.stack([np.ones_like(s), s, t], axis=1)
        r = h - A @ np.linalg.lstsq(A, h, rcond=None)[0]
        return float(r.max() - r.min())
    return None


def _detect_size(case, effect):
    """The truth in the definition of ``metro diagnose``'s ``detectable`` (what its test sees):

    - nonlinearity: peak-to-valley of the true characteristic less its best straight line over
      the true distances the sensor saw (the gain is the scale's business);
    - outliers: the smallest gross reading (mm);
    - the others: as :func:`_seen_size`.
    """
    if effect.family == "nonlinearity":
        curve, d = _true_characteristic(case, effect)
        x = np.linspace(np.nanmin(d), np.nanmax(d), 401)
        e = curve(x)
        r = e - np.polyval(np.polyfit(x, e, 1), x)
        return float(r.max() - r.min())
    if effect.family == "outliers":
        return float(min(abs(c[2]) for c in effect.shape["cells"]))
    return _seen_size(case, effect)


def _detectable_for(res: dict, effect) -> float | None:
    """The case's detectable size (``metro diagnose --json``'s ``detectable``) for the effect."""
    fam = (res.get("detectable") or {}).get(effect.family)
    if not fam:
        return None
    vals = fam["sensors"]
    if effect.family == "outliers":
        return max(vals[c[1]] for c in effect.shape["cells"])
    key = "all" if "all" in vals else (effect.sensors[0] if effect.sensors else None)
    return vals.get(key)


#: the datum scan of every case (``--scan``: ``tracker`` or ``hand``, a hand-held probe's noisy scan,
#: :func:`metrology.sim.forward.surface.sample_hand_scan`) and the poses' count range (``--poses``;
#: None: the simulator's 40-150); set by :func:`main` before the cases run
CASE_OPTIONS = {"scan": "tracker", "poses": None}


#: a datum-tilt case's scan is tilted off the true datum by this many of its own stated 1-sigma
#: tilts (drawn uniformly): beyond what the scan's covariance allows
TILT_SIGMAS = (5.0, 10.0)


def tilt_scan(case, rng):
    """``case`` with its datum scan turned about its centroid, about an in-plane axis drawn at
    random, by ``TILT_SIGMAS`` of the scan's 1-sigma tilt about that axis (as the plate moved, or
    the scan's registration slipped, after it was scanned; the readings see the true datum).

    The 1-sigma tilt is from the physics of the scan, not from metro's fit: the points' noise
    normal to the true surface (1.4826 MAD of their true heights' errors, so strays do not count)
    over the root sum of squares of their lever arms along the axis. Returns ``(case, truth)``,
    ``truth`` the record's entry ``{"family": "datum_tilt", "size": rad, "sigmas": k, ...}``."""
    from dataclasses import replace

    surf = case.surface
    pts = np.asarray(case.cloud, float)
    c = pts.mean(axis=0)
    rel = pts - c
    n = surf.normal
    a = rng.uniform(0.0, 2.0 * np.pi)
    axis = np.cos(a) * surf.axis_s + np.sin(a) * surf.axis_t
    lever = rel @ np.cross(n, axis)  # distance along the in-plane direction the tilt lifts
    err = (pts - surf.origin) @ n - surf.height((pts - surf.origin) @ surf.axis_s, (pts - surf.origin) @ surf.axis_t)
    noise = 1.4826 * float(np.median(np.abs(err - np.median(err))))
    sigma_rad = noise / float(np.sqrt(np.sum((lever - lever.mean()) ** 2)))
    k = float(rng.uniform(*TILT_SIGMAS))
    ang = k * sigma_rad
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R = np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K  # Rodrigues
    cloud = c + rel @ R.T
    truth = {"family": "datum_tilt", "sensors": [], "size": ang, "sigmas": k, "sigma_rad": sigma_rad,
             "seen_size": None, "detect_size": None, "detectable": None, "inside": None}
    return replace(case, cloud=cloud), truth


def run_case(job) -> dict:
    """Draw one case, write its files, diagnose them; the record of truth and verdict."""
    from metrology.jobs.diagnose import diagnose_files
    from metrology.sim.forward import draw_case, draw_pair, write_case

    kind, fams, entropy = job[:3]
    tilt = {"tilt_max_deg": float(job[3])} if len(job) > 3 else {}
    if CASE_OPTIONS["scan"] != "tracker":
        tilt["scan"] = CASE_OPTIONS["scan"]
    if CASE_OPTIONS["poses"] is not None:  # its own stream: the case's is the same as without
        lo, hi = CASE_OPTIONS["poses"]
        tilt["n_poses"] = int(np.random.default_rng(list(entropy) + [7]).integers(lo, hi + 1))
    rng = np.random.default_rng(list(entropy))
    if kind == "datum":
        case = draw_case(rng, "none", **tilt)
        case, hidden = tilt_scan(case, rng)
    else:
        case = draw_pair(rng, *fams, **tilt) if kind == "pair" else draw_case(rng, fams[0], **tilt)
    with tempfile.TemporaryDirectory() as d:
        paths = write_case(case, d)
        try:
            res = diagnose_files(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"]).to_dict()
        except ValueError as e:  # refused as a mistaken export: a verdict of its own, counted as not right
            res = {"cause": "refused", "sensors": [], "confidence": "none", "summary": str(e), "detectable": {}}
    named = _named(res)
    seen = [_seen_size(case, e) for e in case.effects]
    det = [(_detect_size(case, e), _detectable_for(res, e)) for e in case.effects]
    truth = [{"family": e.family, "sensors": list(e.sensors), "size": e.size, "seen_size": z,
              "detect_size": dz, "detectable": dd, "inside": None if dd is None else bool(dz >= dd)}
             for e, z, (dz, dd) in zip(case.effects, seen, det)]
    if kind == "datum":
        truth.append(hidden)
    return {
        "kind": kind, "family": case.family, "seed": list(entropy), "n_sensors": case.nominal.n,
        "n_poses": case.export.n_poses, "noise_mm": case.noise_mm,
        "truth": truth,
        "cause": res["cause"], "sensors": list(res.get("sensors") or []), "confidence": res["confidence"],
        "named": [[c, list(s)] for c, s in named],
        "sizes": {e.family: _size(res, e.family) for e in case.effects},
        # the evidence of each cause named: its held-out p given the others and in-sample p
        "evidence": [[c.get("label"), c.get("p_heldout_given_others"), c.get("p_insample")]
                     for c in res.get("causes") or []],
        # the datum check: the cloud's form against the readings' (p, and whether it says "disagrees")
        "datum": _datum_check(res),
        # the verdict's trail (rule numbers, in order) and the summary made from it
        "rules": [r["rule"] for r in res.get("reasons") or []],
        "summary": res.get("summary"),
        # the datum plane against its scan's covariance (issue 40; absent before it)
        "datum_plane": res.get("datum_plane"),
    }


def _datum_check(res: dict):
    """``{"p", "agree"}`` of the datum check in the JSON, or None without one."""
    ag = (res.get("datum_form") or {}).get("against_readings")
    return None if not ag else {"p": ag["p"], "agree": bool(ag["agree"])}


def _right(effect: dict, named: list) -> bool:
    """The effect's family named with its sensors (sensors not scored for all-sensor families)."""
    for cause, sensors in named:
        if cause != effect["family"]:
            continue
        if effect["family"] in ALL_SENSORS or set(sensors) == set(effect["sensors"]):
            return True
    return False


def _right_alone(r: dict) -> bool:
    """A null or single draw's verdict is right and names nothing else: ``none`` for a null, the
    truth and only it for a single draw."""
    if r["kind"] == "null":
        return r["cause"] == "none"
    return _right(r["truth"][0], [(r["cause"], r["sensors"])]) and len(r["named"]) == 1


def _truth_size(t: dict) -> float:
    return t["seen_size"] if t.get("seen_size") is not None else t["size"]


def summarize(records: list, det: dict) -> dict:
    """Every rate of the study from the records (see module doc)."""
    out = {"detectable": {f: list(r) for f, r in det.items()}}
    singles = [r for r in records if r["kind"] in ("null", "single", "ooc")]
    rows = sorted({r["family"] for r in singles}, key=lambda f: (("none",) + FAMILY_ORDER + OOC).index(f))
    conf = {f: Counter(r["cause"] for r in singles if r["family"] == f) for f in rows}
    out["confusion"] = {f: dict(c) for f, c in conf.items()}
    fam = {}
    for f in FAMILY_ORDER:
        rs = [r for r in records if r["kind"] == "single" and r["family"] == f]
        inside = [r for r in rs if det[f][0] <= r["truth"][0]["size"] <= det[f][1]]
        right = [_right(r["truth"][0], [(r["cause"], r["sensors"])]) for r in rs]
        right_in = [_right(r["truth"][0], [(r["cause"], r["sensors"])]) for r in inside]
        above = [r for r in rs if r["truth"][0].get("inside")]
        right_above = [_right(r["truth"][0], [(r["cause"], r["sensors"])]) for r in above]
        cov = [r["sizes"].get(f) for r in rs if r["sizes"].get(f) is not None]
        covered = [abs(v - _truth_size(r["truth"][0])) <= 2 * s for r in rs
                   for v, s in [r["sizes"].get(f) or (None, None)] if v is not None]
        fam[f] = {"n": len(rs), "right": int(sum(right)), "n_inside": len(inside), "right_inside": int(sum(right_in)),
                  "n_detectable": len(above), "right_detectable": int(sum(right_above)),
                  "detectable_median": float(np.median([r["truth"][0]["detectable"] for r in rs
                                                        if r["truth"][0].get("detectable") is not None] or [np.nan])),
                  "wrong_named": int(sum(bool(r["named"]) and not ok for r, ok in zip(rs, right))),
                  # the right cause named, and another beside it (a wrong cause all the same)
                  "extra_named": int(sum(ok and len(r["named"]) > 1 for r, ok in zip(rs, right))),
                  "n_size": len(cov), "covered_2sigma": int(sum(covered))}
    out["families"] = fam
    nulls = [r for r in records if r["kind"] == "null"]
    k = sum(r["cause"] != "none" for r in nulls)
    out["null"] = {"n": len(nulls), "false_cause": int(k),
                   "named_catalogued": int(sum(bool(r["named"]) for r in nulls)), "ci95": clopper_pearson(k, len(nulls))}
    ooc = [r for r in records if r["kind"] == "ooc"]
    kc = sum(bool(r["named"]) for r in ooc)
    # named with confidence high or moderate (a catalogued cause that an uncatalogued rival ties is named `ambiguous`
    # with the rival listed: tests/diagnosis/test_blind_forward.py::test_crosstalk_is_never_a_confident_gain_error)
    kconf = sum(bool(r["named"]) and r["confidence"] in ("high", "moderate") for r in ooc)
    out["ooc"] = {"n": len(ooc), "catalogued_named": int(kc), "catalogued_confident": int(kconf),
                  "ci95": clopper_pearson(kc, len(ooc)),
                  "by_family": {f: dict(Counter(r["cause"] for r in ooc if r["family"] == f)) for f in OOC}}
    high = [r for r in records if r["kind"] in ("null", "single") and r["confidence"] == "high"]
    out["high_precision"] = {"n": len(high), "right": int(sum(map(_right_alone, high)))}
    # a cause named on weak held-out evidence (metrology.diagnosis.select.weakly_supported)
    mod = [r for r in records if r["kind"] in ("null", "single") and r["confidence"] == "moderate" and r["named"]]
    out["moderate_named"] = {"n": len(mod), "right": int(sum(map(_right_alone, mod)))}
    # the datum check on flat datums (every case without plane_form): "disagrees" is a false alarm
    flat = [r for r in records if r.get("datum") and all(e["family"] != "plane_form" for e in r["truth"])]
    flat_nulls = [r for r in flat if r["kind"] == "null"]
    out["datum_flat"] = {"n": len(flat), "disagrees": int(sum(not r["datum"]["agree"] for r in flat)),
                         "n_nulls": len(flat_nulls), "disagrees_nulls": int(sum(not r["datum"]["agree"] for r in flat_nulls)),
                         "ci95_nulls": clopper_pearson(sum(not r["datum"]["agree"] for r in flat_nulls), len(flat_nulls)),
                         "p_below_0.05_nulls": int(sum(r["datum"]["p"] < 0.05 for r in flat_nulls))}
    # a knocked sensor named where no sensor was knocked (any kind of case)
    no_shift = [r for r in records if all(e["family"] != "shift" for e in r["truth"])]
    out["false_shift"] = {"n": len(no_shift), "named": int(sum(any(c == "shift" for c, _ in r["named"]) for r in no_shift)),
                          "nulls": int(sum(any(c == "shift" for c, _ in r["named"]) for r in no_shift
                                           if r["kind"] == "null")), "n_nulls": len(nulls)}
    # nulls whose datum scan is tilted beyond its uncertainty: to be named datum_tilt, and nothing else
    dt = [r for r in records if r["kind"] == "datum"]
    out["datum_tilt"] = {"n": len(dt), "right": int(sum(_right(r["truth"][0], [tuple(x) for x in r["named"]]) for r in dt)),
                         "right_alone": int(sum(r["cause"] == "datum_tilt" and len(r["named"]) == 1 for r in dt)),
                         "pose_error": int(sum(any(c == "pose_error" for c, _ in r["named"]) for r in dt)),
                         "by_cause": dict(Counter(str(getattr(r["cause"], "value", r["cause"])) for r in dt))}
    pairs = [r for r in records if r["kind"] == "pair"]
    both = [all(_right(e, [tuple(x) for x in r["named"]]) for e in r["truth"]) for r in pairs]
    added = [any(c not in {e["family"] for e in r["truth"]} for c, _ in r["named"]) for r in pairs]
    inside = [all(det[e["family"]][0] <= e["size"] <= det[e["family"]][1] for e in r["truth"]) for r in pairs]
    above = [all(bool(e.get("inside")) for e in r["truth"]) for r in pairs]
    out["pairs"] = {"n": len(pairs), "both_right": int(sum(both)), "wrong_added": int(sum(added)),
                    "n_inside": int(sum(inside)), "both_right_inside": int(sum(b for b, i in zip(both, inside) if i)),
                    "n_detectable": int(sum(above)), "both_right_detectable": int(sum(b for b, i in zip(both, above) if i)),
                    "by_pair": {p: dict(Counter(r["cause"] for r in pairs if r["family"] == p))
                                for p in sorted({r["family"] for r in pairs})}}
    return out


def _pct(k, n):
    return f"{k}/{n} ({100.0 * k / n:.0f} %)" if n else "-"


def report(s: dict) -> str:
    """The study's tables as text."""
    lines = ["confusion matrix (rows: true family; columns: named cause)"]
    cols = sorted({c for row in s["confusion"].values() for c in row})
    lines.append(f"{'':14s}" + "".join(f"{c[:11]:>12s}" for c in cols))
    for f, row in s["confusion"].items():
        lines.append(f"{f:14s}" + "".join(f"{row.get(c, 0):12d}" for c in cols))
    lines += ["", "right cause and sensor per family (sensors not scored for pose_error, plane_form)",
              f"{'family':14s}{'all draws':>16s}{'detectable':>16s}{'wrong cause':>13s}{'upper 2/3':>16s}  "
              f"{'range':>12s}{'size 2-sigma':>16s}{'median det.':>13s}"]
    for f, r in s["families"].items():
        lo, hi = s["detectable"][f]
        cov = _pct(r["covered_2sigma"], r["n_size"]) if r["n_size"] else "n/a"
        lines.append(f"{f:14s}{_pct(r['right'], r['n']):>16s}{_pct(r['right_detectable'], r['n_detectable']):>16s}"
                     f"{r['wrong_named']:>13d}{_pct(r['right_inside'], r['n_inside']):>16s}  "
                     f"{f'{lo:.3g}-{hi:.3g}':>12s}{cov:>16s}{r.get('detectable_median', float('nan')):13.3g}")
    extra = [f"{f} {r['extra_named']}" for f, r in s["families"].items() if r.get("extra_named")]
    lines.append(f"a wrong cause named beside the right one: {', '.join(extra) if extra else 'none'}")
    n = s["null"]
    lines += ["", f"null false-cause rate: {_pct(n['false_cause'], n['n'])}, 95 % CP "
                  f"[{100 * n['ci95'][0]:.2f}, {100 * n['ci95'][1]:.2f}] % (catalogued named {n['named_catalogued']})"]
    o = s["ooc"]
    lines.append(f"out-of-catalogue named as a catalogued cause: {_pct(o['catalogued_named'], o['n'])} "
                 f"(high or moderate: {o.get('catalogued_confident', 0)}), 95 % CP "
                 f"[{100 * o['ci95'][0]:.1f}, {100 * o['ci95'][1]:.1f}] %; {o['by_family']}")
    df = s.get("datum_flat")
    if df and df["n"]:
        lines.append(f"datum check 'disagrees' on flat datums: {_pct(df['disagrees'], df['n'])} of the cases; nulls "
                     f"{_pct(df['disagrees_nulls'], df['n_nulls'])}, 95 % CP [{100 * df['ci95_nulls'][0]:.2f}, "
                     f"{100 * df['ci95_nulls'][1]:.2f}] % (p < 0.05: {df['p_below_0.05_nulls']})")
    fs = s.get("false_shift")
    if fs:
        lines.append(f"shift named where no sensor was knocked: {_pct(fs['named'], fs['n'])} of the cases "
                     f"({fs['nulls']} of {fs['n_nulls']} nulls)")
    h = s["high_precision"]
    lines.append(f"confidence high precision (nulls and singles): {_pct(h['right'], h['n'])}")
    m = s.get("moderate_named", {"n": 0, "right": 0})
    lines.append(f"a cause named with confidence moderate (weak held-out evidence), right: {_pct(m['right'], m['n'])}")
    dt = s.get("datum_tilt")
    if dt and dt["n"]:
        lines.append(f"datum tilted beyond its uncertainty: datum_tilt named {_pct(dt['right'], dt['n'])}, alone "
                     f"{_pct(dt['right_alone'], dt['n'])}, pose_error named {dt['pose_error']}; {dt['by_cause']}")
    p = s["pairs"]
    lines.append(f"pairs: both right {_pct(p['both_right'], p['n'])} (both above the case's detectable size: "
                 f"{_pct(p.get('both_right_detectable', 0), p.get('n_detectable', 0))}; both in the upper 2/3 of the "
                 f"range: {_pct(p.get('both_right_inside', 0), p.get('n_inside', 0))}), "
                 f"wrong cause added {_pct(p['wrong_added'], p['n'])}")
    for k, v in p["by_pair"].items():
        lines.append(f"  {k:24s} {v}")
    return "\n".join(lines)


def run_study(draws=20, nulls=200, pairs=20, seed=0, jobs=1, progress=True, families=None, tilt_max_deg=None,
              tilts=0) -> tuple:
    """Run every case (``families``: only those single draws, :func:`jobs_for`; ``tilt_max_deg``:
    the poses' largest tilt, default the simulator's 14 deg; ``tilts`` datum-tilt cases); (records, summary)."""
    todo = jobs_for(draws, nulls, pairs, seed, families, tilts)
    if tilt_max_deg is not None:
        todo = [j + (float(tilt_max_deg),) for j in todo]
    try:
        from rich.progress import track
    except ImportError:
        track = None

    def _iter(it):
        if not progress:
            return it
        if track is not None:
            return track(it, total=len(todo), description="blind study")
        return _plain(it, len(todo))

    if jobs > 1:
        from multiprocessing import Pool

        with Pool(jobs) as pool:
            records = list(_iter(pool.imap(run_case, todo)))
    else:
        records = list(_iter(map(run_case, todo)))
    return records, summarize(records, detectable_ranges())


def _plain(it, total):
    t0 = time.time()
    for i, x in enumerate(it, 1):
        if i % 10 == 0 or i == total:
            print(f"  {i}/{total} cases, {time.time() - t0:.0f} s", file=sys.stderr, flush=True)
        yield x


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=20, help="draws per family (catalogued and out-of-catalogue)")
    ap.add_argument("--nulls", type=int, default=200)
    ap.add_argument("--pairs", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--json", default=None, help="save records and summary here")
    ap.add_argument("--families", default="", help="comma-separated: draw only these families (e.g. incidence)")
    ap.add_argument("--tilt-max-deg", type=float, default=None, help="largest tilt of the poses (default 14)")
    ap.add_argument("--size-range", default=None,
                    help="LO,HI: draw the --families' sizes in this range instead of the family's own (the same "
                         "draws of everything else; e.g. shift near its detectable size: 0.005,0.03)")
    ap.add_argument("--scan", choices=("tracker", "hand"), default="tracker",
                    help="the datum scan: the simulator's tracker cloud (2000 points, 10 um) or a hand-held probe's "
                         "(40-80 um noise, 400-1500 points, 1-3 %% strays)")
    ap.add_argument("--datum-tilts", type=int, default=0,
                    help="nulls whose datum scan is tilted 5-10 of its own sigmas (to be named datum_tilt)")
    ap.add_argument("--poses", default=None, help="LO,HI: draw each case's pose count in this range (default 40-150)")
    a = ap.parse_args(argv)
    CASE_OPTIONS["scan"] = a.scan
    if a.poses:
        CASE_OPTIONS["poses"] = tuple(int(v) for v in a.poses.split(","))
    fams = tuple(filter(None, a.families.split(",")))
    if a.size_range:
        from dataclasses import replace

        from metrology.sim.forward import FAMILIES

        lo, hi = (float(v) for v in a.size_range.split(","))
        for f in fams:  # in this process, inherited by the pool's (forked) workers
            FAMILIES[f] = replace(FAMILIES[f], size_range=(lo, hi))
    unknown = [f for f in fams if f not in FAMILY_ORDER + OOC]
    if unknown:
        ap.error(f"--families {','.join(unknown)}: expected some of {','.join(FAMILY_ORDER + OOC)}")
    t0 = time.time()
    records, summary = run_study(a.draws, a.nulls, a.pairs, a.seed, a.jobs, families=fams or None,
                                 tilt_max_deg=a.tilt_max_deg, tilts=a.datum_tilts)
    wall = time.time() - t0
    print(report(summary))
    print(f"\nwall time {wall:.0f} s for {len(records)} cases ({a.jobs} job(s))")
    if a.json:
        from metrology.io.atomic import write_text

        write_text(a.json, json.dumps({"args": vars(a), "wall_s": wall, "summary": summary, "records": records},
                                      indent=1) + "\n")


if __name__ == "__main__":
    main()
