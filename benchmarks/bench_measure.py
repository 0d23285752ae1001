"""Speed and memory of ``metro measure``, against baselines measured in the same run.

    python benchmarks/bench_measure.py [--holes 1e6] [--repeat 3] [--workdir DIR] [--big 1e8] [--json F]
                                       [--sections in-process,process,qif,dask,cluster,panel,controller] [--cluster-holes 4e6]
                                       [--panel-holes 1e6] [--controller-holes 2e5]

On a hole log drawn by the independent forward simulator (Table 6 head, flat panel, after-readings,
``--holes`` holes written as one Parquet file and as a partitioned folder of 8 files):

1. **in process**: :func:`metrology.measure.holes.measure_batch` on batches already in memory, with
   and without after-readings (holes/s; the issue's goal: >= 1e6 holes/s);
2. **whole process**: ``metro measure LOG.parquet --layout L --out holes.parquet`` against a plain
   script that reads the same file with pyarrow, fits the 4-point planes before and after the
   adjustment with batched numpy (the same closed-form least squares, normals only: no
   uncertainty, verdict, drift watch or summary) and writes the normals (where pandas is installed, pyarrow
   imports it for the script's first numpy conversion, ~0.5 s of its CPU, which metro's buffer conversions in
   ``metrology/io/arrays.py`` do not pay: a ratio depends on the environment; say which,
   benchmarks/results/measure_speed_issue49_r8_merged.md) (best wall time of
   ``--repeat``, run in turn; its CPU time, which the other jobs on a shared machine disturb
   less; peak RSS). Goal: <= 1.5x;
3. **Dask**: a partitioned log of ``--dask-holes`` holes (40 partitions) with ``--workers 1`` and
   ``--workers 2`` (holes/s, the cluster's start included), against the single process on the
   same folder, ``--repeat`` rounds run in turn: the best of each, and 2 workers against 1 in each
   round (its spread, and their median); and the CPU a cluster of 2 idle workers takes (cores,
   client and workers), with Dask's defaults and with the settings ``--workers`` starts it with
   (``QUIET_CLUSTER``);
4. **QIF**: the whole-process run of 2. with ``--qif results.qif`` added (a QIF 3.0 Results
   document of every hole, streamed): wall time, CPU and peak RSS against the run without it
   (goal: <= 3x the time; RSS bounded, not growing with the holes);
5. **cluster** (``--sections cluster``): a log of ``--cluster-holes`` holes, 4 cells in 40 partitions
   (``cell=C<k>/part=<n>``), measured by one process and on a localhost cluster (``dask scheduler``
   and W = 1, 2 ``dask worker --nthreads 1``, ``--scheduler``): wall time, the speedup, and the
   client's own CPU time as a share of the one-process run's CPU (the serial share ``f``), with
   Amdahl's speedup ``1 / (f + (1 - f) / N)`` for N = 4 to 64 workers as the scaling model;
6. **panel** (``--sections panel``): a log of ``--panel-holes`` holes forward-simulated on a bundled
   panel (``metro simulate-log --panel metrology/data/panels/wing.stl --points wing.holes.csv``,
   the bundled Table 6 head, ``--true-layout`` the same file: the nominal states no calibration
   error, and a head drawn 15-30 um off it is rightly refused with the panel known on most seeds),
   and ``metro measure LOG --layout L --panel P --points H`` against the same command without
   ``--panel --points``, run in turn in the same run: wall time, CPU time and peak RSS and their
   ratios (goal: <= 2x);
7. **controller** (``--sections controller``): :func:`metrology.measure.surface_normal`, the call a
   cell's controller makes per hole, in process, on the readings of a wing log of 2000 holes
   (as 6., with the CAD's shape operator under the commanded pose) tiled to ``--controller-holes``
   holes: batched (holes/s, best of ``--repeat``; goal: >= 2e5) and one hole a call (ms, the
   median and the mean of 2000 calls, best of ``--repeat``; goal: <= 1 ms);
8. **verdicts** (``--sections verdicts``): the log of 2. without its after-readings, measured with every
   hole failing (``--tolerance-deg 0.1``) and with every hole conforming (``--tolerance-deg 10``),
   against the plain script of 2. on the same file, ``--repeat`` rounds in turn: each round's CPU
   ratios (each process's CPU from ``os.wait4``; the order reversed every other round), their median with its 95 %
   bootstrap interval, and the rounds <= 1.2 (goal: <= 1.2x; ``interleaved``);
9. ``--big N``: a partitioned log of N holes, 1e6 a partition (generated in ``--workdir``, never
   committed), measured in one process: wall time, and peak RSS against that of its first
   partition alone (1e6 holes, the same row groups; goal: within 1.2x).

Results go to stdout (a markdown table) and ``--json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

RUN = ("import resource, subprocess, sys, time\n"
       "t = time.perf_counter()\n"
       "r = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)\n"
       "dt = time.perf_counter() - t\n"
       "u = resource.getrusage(resource.RUSAGE_CHILDREN)\n"
       "print(dt, u.ru_maxrss, r.returncode, u.ru_utime + u.ru_stime)\n")

BASELINE = '''
import sys, tomllib
import numpy as np, pyarrow as pa, pyarrow.parquet as pq
log, layout, out = sys.argv[1:4]
with open(layout, "rb") as fh:
    sensors = tomllib.load(fh)["sensors"]
E = np.array([s["zero"] for s in sensors]); u = np.array([s["direction"] for s in sensors])
u /= np.linalg.norm(u, axis=1, keepdims=True)
names = [s["name"] for s in sensors]
pf = pq.ParquetFile(log)
after = all(f"d_{n}_after" in pf.schema_arrow.names for n in names)
sets = [[f"d_{n}" for n in names]] + ([[f"d_{n}_after" for n in names]] if after else [])
writer = None


def normals(d):
    x, y, z = (E[None, :, k] + d * u[None, :, k] for k in range(3))
    xc, yc, zc = (v - v.mean(1, keepdims=True) for v in (x, y, z))
    sxx, syy, sxy, sxz, syz = ((a * c).sum(1) for a, c in ((xc, xc), (yc, yc), (xc, yc), (xc, zc), (yc, zc)))
    det = sxx * syy - sxy * sxy
    gx, gy = (syy * sxz - sxy * syz) / det, (sxx * syz - sxy * sxz) / det
    r = np.sqrt(1 + gx * gx + gy * gy)
    return -gx / r, -gy / r, 1 / r


for b in pf.iter_batches(batch_size=1 << 18, columns=["hole_id", *sum(sets, [])]):
    cols = {"hole_id": b.column("hole_id")}
    for k, cs in enumerate(sets):
        d = np.stack([b.column(c).to_numpy(zero_copy_only=False) for c in cs], axis=1)
        for axis, v in zip("xyz", normals(d)):
            cols[f"normal{'_after' * k}_{axis}"] = v
    t = pa.table(cols)
    if writer is None:
        writer = pq.ParquetWriter(out, t.schema)
    writer.write_table(t)
writer.close()
'''


def make_log(workdir: Path, holes: int, parts: int, seed: int = 1, single: bool = True, cells: int = 1):
    """A log of ``holes`` holes (forward simulator) as one file and as ``parts`` partitions (with
    ``cells`` > 1: ``cell=C<k>/part=<n>``, the key in the folder names only); the layout."""
    import pyarrow.parquet as pq

    from metrology.core.paper import TABLE6_NOMINAL, layout_from_table
    from metrology.io.layout import save_layout
    from metrology.sim.forward import perturb_layout
    from metrology.sim.forward.log import simulate_log
    from metrology.sim.forward.log_spec import LogSpec
    from metrology.sim.forward.log_write import log_table
    from metrology.sim.forward.panels import make_panel

    rng = np.random.default_rng(seed)
    nominal = layout_from_table(TABLE6_NOMINAL, noise_mm=0.003)
    nominal = nominal.with_params(nominal.zero, nominal.direction, range_mm=np.tile([30.0, 70.0], (4, 1)))
    true = perturb_layout(rng, nominal, zero_error_mm=(0.001, 0.005), direction_error_deg=(0.001, 0.005))
    C = np.diag(np.tile([0.005 ** 2] * 3 + [np.radians(0.01) ** 2] * 2, 4))
    cal = nominal.with_params(nominal.zero, nominal.direction, covariance=C)
    save_layout(cal, workdir / "calibrated.toml")
    spec = LogSpec(true_layout=true, cell_layout=cal, panel=make_panel("flat"))
    single = pq.ParquetWriter(workdir / "log.parquet", log_table(next(simulate_log(spec, seed, 1))).schema) \
        if single else None
    per = -(-holes // parts)
    folder = workdir / "log"
    k = 0
    for chunk in simulate_log(spec, seed, holes, cells, chunk_holes=per):
        t = log_table(chunk)
        if single is not None:
            single.write_table(t)
        d = folder / f"part={k:04d}" if cells == 1 else folder / f"cell={chunk.cell}" / f"part={k:04d}"
        d.mkdir(parents=True, exist_ok=True)
        pq.write_table(t if cells == 1 else t.drop_columns(["cell"]), d / "part-0.parquet")
        k += 1
    if single is not None:
        single.close()
    return workdir / "log.parquet", folder, workdir / "calibrated.toml"


def in_process(log, layout, repeat, cpu=False):
    import pyarrow.parquet as pq

    from metrology.io.layout import load_layout
    from metrology.measure.holes import Settings, measure_batch

    lay = load_layout(layout)
    clock = time.process_time if cpu else time.perf_counter
    table = pq.read_table(log)
    before_only = table.drop_columns([c for c in table.column_names if c.endswith("_after")])
    out = {}
    for name, t in (("before", before_only), ("before+after", table)):
        best = np.inf
        for _ in range(repeat):
            t0 = clock()
            for b in t.to_batches(max_chunksize=1 << 18):
                import pyarrow as pa

                measure_batch(lay, pa.Table.from_batches([b]), Settings())
            best = min(best, clock() - t0)
        out[name] = t.num_rows / best
    return out


#: the runs' environment: bytecode written and read (a shell with PYTHONDONTWRITEBYTECODE=1 compiles every module
#: of every run again: 5 s of CPU per ``metro measure``, against less for the plain script, which imports less)
_ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def process(cmd, repeat, cpu=None):
    """Best wall time (s) and peak RSS (MB) of ``cmd`` over ``repeat`` runs; its best CPU time into ``cpu``."""
    best, rss, best_cpu = np.inf, 0, np.inf
    for _ in range(repeat):
        r = subprocess.run([sys.executable, "-c", RUN, *cmd], capture_output=True, text=True, check=True, env=_ENV)
        dt, kb, rc, c = r.stdout.split()
        if int(rc) not in (0, 1):
            raise RuntimeError(f"{cmd} exited {rc}")
        best, rss, best_cpu = min(best, float(dt)), max(rss, int(kb)), min(best_cpu, float(c))
    if cpu is not None:
        cpu.append(best_cpu)
    return best, rss / 1024.0


def child_cpu(cmd, codes=(0, 1)) -> float:
    """CPU seconds (user + system) of the process ``cmd`` alone, from ``os.wait4``'s rusage of that child (no
    wrapper interpreter between: ``RUN`` timed the command from a second Python process)."""
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=_ENV)
    _, status, ru = os.wait4(p.pid, 0)
    p.returncode = os.waitstatus_to_exitcode(status)
    if p.returncode not in codes:
        raise RuntimeError(f"{cmd} exited {p.returncode}")
    return ru.ru_utime + ru.ru_stime


#: the bootstrap of a median ratio: resamples, and its generator's seed (the interval is the same on a re-run)
BOOT_RESAMPLES, BOOT_SEED = 4000, 49


def median_interval(x, level: float = 0.95) -> tuple:
    """The median of ``x`` (one ratio a round) and its percentile-bootstrap ``level`` interval (rounds resampled)."""
    x = np.asarray(x, float)
    rng = np.random.default_rng(BOOT_SEED)
    m = np.median(x[rng.integers(0, len(x), (BOOT_RESAMPLES, len(x)))], axis=1)
    lo, hi = np.quantile(m, [(1 - level) / 2, (1 + level) / 2])
    return float(np.median(x)), float(lo), float(hi)


def interleaved(cmds: dict, repeat: int, ratios: dict, goal: float = 1.2, codes=(0, 1)) -> dict:
    """``repeat`` rounds of every command of ``cmds`` (name -> argv), run in turn, the order reversed every other
    round (a slow spell of the shared machine then falls on each command's position alike); each round's CPU
    seconds (:func:`child_cpu`), its load average before and after, and ``ratios`` (name -> (numerator,
    denominator)) per round (a process must exit with one of ``codes``); then each ratio's median, range, 95 % bootstrap interval of the median and the rounds
    at or below ``goal``."""
    for cmd in cmds.values():  # a warm-up: the bytecode written, the files in the page cache
        child_cpu(cmd, codes)
    rounds, names = [], list(cmds)
    for k in range(repeat):
        load0 = os.getloadavg()[0]
        cpu = {name: child_cpu(cmds[name], codes) for name in (names if k % 2 == 0 else names[::-1])}
        rounds.append({**cpu, **{r: cpu[a] / cpu[b] for r, (a, b) in ratios.items()},
                       "load": [load0, os.getloadavg()[0]]})
        print(" ".join(f"{n} {v:.3f}" for n, v in rounds[-1].items() if n != "load"), "| load %.1f-%.1f"
              % tuple(rounds[-1]["load"]), file=sys.stderr, flush=True)
    out = {"rounds": rounds}
    for r in ratios:
        x = [d[r] for d in rounds]
        med, lo, hi = median_interval(x)
        out[f"median_{r}"] = med
        out[f"{r}_range"] = [min(x), max(x)]
        out[f"{r}_median_ci95"] = [lo, hi]
        out[f"{r}_rounds_at_or_below_{goal}"] = sum(v <= goal for v in x)
    for n in cmds:
        out[f"median_{n}_cpu_s"] = float(np.median([d[n] for d in rounds]))
    out["load_range"] = [min(min(d["load"]) for d in rounds), max(max(d["load"]) for d in rounds)]
    return out


def verdicts(log, layout, repeat, metro) -> dict:
    """``metro measure`` on the log without its after-readings, every hole failing (``--tolerance-deg 0.1``:
    the angles are 0.5-5 deg) and every hole conforming (``--tolerance-deg 10``), against the plain
    pyarrow+numpy micro-plane script on the same file; ``repeat`` rounds run in turn (the machine is
    shared: each round's ratios of CPU times, their median and its bootstrap interval: :func:`interleaved`)."""
    import pyarrow.parquet as pq

    t = pq.read_table(log)
    before = log.with_name("log_before.parquet")
    pq.write_table(t.drop_columns([c for c in t.column_names if c.endswith("_after")]), before,
                   row_group_size=1 << 18)
    out = log.with_name("holes_before.parquet")
    cmds = {"baseline": [sys.executable, "-c", BASELINE, str(before), str(layout), str(out)],
            "all_fail": [*metro, "-q", "measure", str(before), "--layout", str(layout), "--out", str(out),
                         "--tolerance-deg", "0.1"],
            "all_conform": [*metro, "-q", "measure", str(before), "--layout", str(layout), "--out", str(out),
                            "--tolerance-deg", "10"]}
    return interleaved(cmds, repeat, {"ratio_all_fail": ("all_fail", "baseline"),
                                      "ratio_all_conform": ("all_conform", "baseline")})


def _free_port():
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cluster(work: Path, holes: int, metro) -> dict:
    """Section 5: one process against a localhost scheduler with 1 and 2 workers (module docstring)."""
    from distributed import Client

    d = work / "cluster"
    shutil.rmtree(d, ignore_errors=True)
    d.mkdir()
    _, folder, layout = make_log(d, holes, 40, seed=5, single=False, cells=4)
    out = {"holes": holes, "partitions": 40, "cells": 4}
    cpu = []
    target = d / "out-one"
    out["one_process_s"], _ = process([*metro, "-q", "measure", str(folder), "--layout", str(layout), "--out",
                                       str(target)], 1, cpu)
    out["one_process_cpu_s"] = cpu[0]
    shutil.rmtree(target)
    dask = shutil.which("dask", path=os.path.dirname(sys.executable)) or "dask"
    env = {**os.environ, "DASK_DISTRIBUTED__WORKER__DAEMON": "False",
           "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    for w in (1, 2):
        port = _free_port()
        address = f"tcp://127.0.0.1:{port}"
        procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)]
        try:
            time.sleep(2)
            for _ in range(w):
                procs.append(subprocess.Popen([dask, "worker", address, "--nworkers", "1", "--nthreads", "1",
                                               "--no-dashboard"], stdout=subprocess.DEVNULL,
                                              stderr=subprocess.DEVNULL, env=env))
            with Client(address, timeout="60s") as c:
                c.wait_for_workers(w, timeout=120)
            cpu = []
            target = d / f"out-{w}"
            t, _ = process([*metro, "-q", "measure", str(folder), "--layout", str(layout), "--out", str(target),
                            "--scheduler", address], 1, cpu)
            shutil.rmtree(target)
        finally:
            for p in procs[::-1]:
                p.terminate()
            for p in procs:
                try:
                    p.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    p.kill()
        out[f"workers_{w}"] = {"s": t, "client_cpu_s": cpu[0], "speedup_vs_one_process": out["one_process_s"] / t,
                               "client_cpu_share": cpu[0] / out["one_process_cpu_s"]}
    out["workers_2_vs_1"] = out["workers_1"]["s"] / out["workers_2"]["s"]
    f = out["workers_2"]["client_cpu_share"]
    out["amdahl_from_client_share"] = {n: 1.0 / (f + (1.0 - f) / n) for n in (4, 8, 16, 32, 64)}
    shutil.rmtree(d, ignore_errors=True)
    return out


def panel(work: Path, holes: int, repeat: int, metro, name: str = "wing") -> dict:
    """Section 6: ``measure --panel --points`` against the same run without (module docstring)."""
    data = ROOT / "metrology" / "data"
    mesh, points = data / "panels" / f"{name}.stl", data / "panels" / f"{name}.holes.csv"
    layout = data / "measured" / "nominal.toml"
    log = work / f"panel-{name}.parquet"
    t0 = time.perf_counter()
    subprocess.run([*metro, "-q", "simulate-log", "--layout", str(layout), "--true-layout", str(layout),
                    "--panel", str(mesh), "--points", str(points),
                    "--holes", str(holes), "--seed", "1", "--no-truth", "--out", str(log)], check=True,
                   stdout=subprocess.DEVNULL)
    out = {"holes": holes, "panel": f"{name}.stl", "table": f"{name}.holes.csv", "generate_s": time.perf_counter() - t0}
    base = [*metro, "-q", "measure", str(log), "--layout", str(layout), "--out", str(work / "panel-out.parquet")]
    cpu_p, cpu_b, best, rounds = [], [], {}, []
    for _ in range(repeat):  # in turn: the machine's load falls on both alike
        rounds.append({})
        for key, cmd, cpu in (("plain", base, cpu_b), ("panel", [*base, "--panel", str(mesh), "--points", str(points)],
                                                       cpu_p)):
            t, rss = process(cmd, 1, cpu)
            b = best.setdefault(key, [np.inf, 0.0])
            b[0], b[1] = min(b[0], t), max(b[1], rss)
            rounds[-1].update({f"{key}_s": t, f"{key}_cpu_s": cpu[-1], f"{key}_rss_mb": rss})
        r = rounds[-1]
        r.update(ratio_time=r["panel_s"] / r["plain_s"], ratio_cpu=r["panel_cpu_s"] / r["plain_cpu_s"],
                 ratio_rss=r["panel_rss_mb"] / r["plain_rss_mb"])
    out.update(plain_s=best["plain"][0], plain_cpu_s=min(cpu_b), plain_rss_mb=best["plain"][1],
               panel_s=best["panel"][0], panel_cpu_s=min(cpu_p), panel_rss_mb=best["panel"][1])
    out.update(ratio_time=out["panel_s"] / out["plain_s"], ratio_cpu=out["panel_cpu_s"] / out["plain_cpu_s"],
               ratio_rss=out["panel_rss_mb"] / out["plain_rss_mb"], rounds=rounds)
    log.unlink()
    return out


def controller(work: Path, holes: int, repeat: int, metro) -> dict:
    """Section 7: ``surface_normal`` batched and one hole a call (module docstring)."""
    import pyarrow.parquet as pq

    from metrology.io.layout import load_layout
    from metrology.jobs.measure_panel import hole_surfaces
    from metrology.measure import surface_normal
    from metrology.measure.holes import _readings
    from metrology.measure.pose import read_pose as _pose
    from metrology.measure.normals import drill_axis

    data = ROOT / "metrology" / "data"
    mesh, points = data / "panels" / "wing.stl", data / "panels" / "wing.holes.csv"
    layout = data / "measured" / "nominal.toml"
    log = work / "controller-wing.parquet"
    subprocess.run([*metro, "-q", "simulate-log", "--layout", str(layout), "--true-layout", str(layout),
                    "--panel", str(mesh), "--points", str(points),
                    "--holes", "2000", "--seed", "1", "--no-truth", "--out", str(log)], check=True,
                   stdout=subprocess.DEVNULL)
    lay = load_layout(layout)
    surf = hole_surfaces(lay, str(mesh), str(points), 0.5, 0.0, 0.0)
    table = pq.read_table(log)
    d = _readings(table, lay.names)
    shape = surf.shape_pose(surf.rows(table.column("point_id")), _pose(table)[0], drill_axis(lay)[2])
    keep = np.all(np.isfinite(d), axis=1)
    d, shape = d[keep], shape[keep]
    reps = -(-holes // len(d))
    db, kb = np.tile(d, (reps, 1))[:holes], np.tile(shape, (reps, 1, 1))[:holes]
    best_batch, best_median, best_mean = np.inf, np.inf, np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        normal, ok = surface_normal(lay, db, kb)
        best_batch = min(best_batch, time.perf_counter() - t0)
        times = np.empty(2000)
        for i in range(len(times)):
            t0 = time.perf_counter()
            surface_normal(lay, d[i % len(d)], shape[i % len(d)])
            times[i] = time.perf_counter() - t0
        best_median, best_mean = min(best_median, float(np.median(times))), min(best_mean, float(times.mean()))
    log.unlink()
    return {"holes": holes, "measured": int(ok.sum()), "batched_holes_per_s": holes / best_batch,
            "one_hole_median_ms": best_median * 1e3, "one_hole_mean_ms": best_mean * 1e3}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--holes", type=float, default=1e6)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--workdir", type=Path, default=None)
    ap.add_argument("--dask-holes", type=float, default=1e7, help="holes of the Dask comparison's log")
    ap.add_argument("--big", type=float, default=0.0, help="holes of the big run (e.g. 1e8); 0: none")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--sections", default="in-process,process,qif,dask",
                    help="which of in-process, process, qif, dask, cluster, panel, controller")
    ap.add_argument("--panel-holes", type=float, default=1e6, help="holes of the panel section's log")
    ap.add_argument("--cluster-holes", type=float, default=4e6, help="holes of the cluster section's log")
    ap.add_argument("--controller-holes", type=float, default=2e5, help="holes of the controller section's batch")
    args = ap.parse_args(argv)
    sections = set(args.sections.split(","))
    work = Path(tempfile.mkdtemp(prefix="bench-measure-")) if args.workdir is None else args.workdir
    work.mkdir(parents=True, exist_ok=True)
    metro = shutil.which("metro", path=os.path.dirname(sys.executable))
    metro = [metro] if metro else [sys.executable, "-m", "cli.main"]  # from a source tree: run from ROOT
    os.chdir(ROOT)
    res = {"machine": {"cores": os.cpu_count(), "python": platform.python_version()}, "holes": int(args.holes)}
    if "panel" in sections:
        res["panel"] = panel(work, int(args.panel_holes), args.repeat, metro)
    if "controller" in sections:
        res["controller"] = controller(work, int(args.controller_holes), args.repeat, metro)
    if sections <= {"cluster", "panel", "controller"}:
        if "cluster" in sections:
            res["cluster"] = cluster(work, int(args.cluster_holes), metro)
        return _done(res, args, work)
    if sections == {"dask"}:
        _dask(res, args, work, metro)
        return _done(res, args, work)
    t0 = time.perf_counter()
    log, folder, layout = make_log(work, int(args.holes), 8)
    res["generate_s"] = time.perf_counter() - t0
    if "in-process" in sections:
        res["in_process_holes_per_s"] = in_process(log, layout, args.repeat)
        res["in_process_holes_per_cpu_s"] = in_process(log, layout, args.repeat, cpu=True)
    out = work / "holes.parquet"
    cpu_m, cpu_b = [], []
    res["metro_s"], res["metro_rss_mb"] = process([*metro, "-q", "measure", str(log), "--layout", str(layout),
                                                   "--out", str(out)], args.repeat, cpu_m)
    if "verdicts" in sections:
        res["verdicts"] = verdicts(log, layout, args.repeat, metro)
        if sections == {"verdicts"}:
            return _done(res, args, work)
    if "qif" in sections:
        cpu_q = []
        qif = work / "results.qif"
        res["qif_s"], res["qif_rss_mb"] = process([*metro, "-q", "measure", str(log), "--layout", str(layout),
                                                   "--out", str(out), "--qif", str(qif)], args.repeat, cpu_q)
        res.update(qif_cpu_s=cpu_q[0], qif_mb=qif.stat().st_size / 2**20, qif_ratio_time=res["qif_s"] / res["metro_s"],
                   qif_ratio_cpu=cpu_q[0] / cpu_m[0], qif_ratio_rss=res["qif_rss_mb"] / res["metro_rss_mb"])
        qif.unlink()
    if "cluster" in sections:
        res["cluster"] = cluster(work, int(args.cluster_holes), metro)
    if "process" not in sections and "dask" not in sections:
        return _done(res, args, work)
    res["baseline_s"], res["baseline_rss_mb"] = process([sys.executable, "-c", BASELINE, str(log), str(layout),
                                                         str(work / "normals.parquet")], args.repeat, cpu_b)
    res["metro_cpu_s"], res["baseline_cpu_s"] = cpu_m[0], cpu_b[0]
    res["ratio_cpu"] = cpu_m[0] / cpu_b[0]
    res["ratio_time"] = res["metro_s"] / res["baseline_s"]
    res["ratio_rss"] = res["metro_rss_mb"] / res["baseline_rss_mb"]
    if "dask" not in sections:
        return _done(res, args, work)
    _dask(res, args, work, metro)
    _done(res, args, work)


def dask_idle(seconds: float = 10.0) -> dict:
    """The CPU (cores) that a LocalCluster of 2 idle workers takes, client and workers, with Dask's
    defaults and with :data:`metrology.measure.fleet.QUIET_CLUSTER` (what ``--workers`` starts): on a
    2-core machine, what the tasks of a 2-worker run lose to the cluster's own housekeeping."""
    import dask.config
    import psutil
    from distributed import Client, LocalCluster

    from metrology.measure.fleet import QUIET_CLUSTER

    def cpu(p):
        t = p.cpu_times()
        return t.user + t.system

    out = {}
    for name, cfg in (("dask defaults", {}), ("QUIET_CLUSTER", QUIET_CLUSTER)):
        with dask.config.set(cfg), LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                                dashboard_address=None) as cl, Client(cl) as c:
            c.submit(time.sleep, 0.1).result()
            procs = [psutil.Process()] + psutil.Process().children(recursive=True)
            a = [cpu(p) for p in procs]
            time.sleep(seconds)
            b = [cpu(p) for p in procs]
            out[name] = {"cores_total": (sum(b) - sum(a)) / seconds, "cores_client": (b[0] - a[0]) / seconds}
    return out


def _dask(res, args, work, metro):
    """Section 3 (module docstring), then the big run of ``--big``."""
    res["dask_idle_cores"] = dask_idle()
    daskdir = work / "dask"
    shutil.rmtree(daskdir, ignore_errors=True)
    daskdir.mkdir()
    _, dfolder, dlayout = make_log(daskdir, int(args.dask_holes), 40, seed=3, single=False)
    res["dask_holes"] = int(args.dask_holes)
    rates = {}
    for _ in range(args.repeat):  # in turn, so a load from other jobs falls on every engine alike
        for label, extra in (("one process", []), ("dask 1 worker", ["--workers", "1"]),
                             ("dask 2 workers", ["--workers", "2"])):
            target = work / f"out-{label.replace(' ', '-')}"
            shutil.rmtree(target, ignore_errors=True)
            t, rss = process([*metro, "-q", "measure", str(dfolder), "--layout", str(dlayout), "--out", str(target),
                              *extra], 1)
            rates.setdefault(label, []).append(args.dask_holes / t)
            if label == "one process":
                res["partitioned_rss_mb"] = rss
            shutil.rmtree(target, ignore_errors=True)
    res["partitioned_holes_per_s"] = {k: max(v) for k, v in rates.items()}
    res["partitioned_holes_per_s_runs"] = rates
    # 2 workers against 1 in the same round of runs: the spread over --repeat rounds
    res["workers_2_vs_1_runs"] = [b / a for a, b in zip(rates["dask 1 worker"], rates["dask 2 workers"])]
    res["workers_2_vs_1_median"] = float(np.median(res["workers_2_vs_1_runs"]))  # what the rounds agree on
    shutil.rmtree(daskdir, ignore_errors=True)
    if args.big:
        bigdir = work / "big"
        shutil.rmtree(bigdir, ignore_errors=True)
        bigdir.mkdir()
        t0 = time.perf_counter()
        _, bigfolder, biglayout = make_log(bigdir, int(args.big), max(int(args.big // 1e6), 1), seed=2, single=False)
        res["big_generate_s"] = time.perf_counter() - t0
        # the reference: the big log's first partition alone (the same partition and row-group size)
        first = sorted(p for p in bigfolder.iterdir() if p.is_dir())[0]
        one = bigdir / "one"
        shutil.copytree(first, one / first.name)
        _, rss1 = process([*metro, "-q", "measure", str(one), "--layout", str(biglayout), "--out", str(bigdir / "out1")], 1)
        t, rss = process([*metro, "-q", "measure", str(bigfolder), "--layout", str(biglayout), "--out",
                          str(bigdir / "out")], 1)
        res.update(big_holes=int(args.big), big_s=t, big_rss_mb=rss, big_reference_rss_mb=rss1,
                   big_rss_ratio=rss / rss1)
        shutil.rmtree(bigdir, ignore_errors=True)


def _done(res, args, work):
    print(json.dumps(res, indent=1))
    if args.json:
        args.json.write_text(json.dumps(res, indent=1))
    if args.workdir is None:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
