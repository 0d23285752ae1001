"""Live results over OPC UA (issue 52): latency and sustained rate of ``metro measure --follow --opcua``.

    python benchmarks/bench_plant.py [--latency-holes 200] [--trickle 20] [--rate 1000] [--seconds 5]

Three processes: ``metro measure - --follow --opcua opc.tcp://127.0.0.1:PORT``; a real asyncua
client subscribed to the Server object's events (``--period-ms`` publishing, 5 ms); this one,
which writes the log's lines to metro's stdin, paced (every line due written at once), and reads
metro's stdout. Each line's write, its answer on stdout and its result-ready event's arrival at
the client are taken on one clock (``time.perf_counter``: CLOCK_MONOTONIC, shared by processes).

1. Trickle: ``--latency-holes`` lines at ``--trickle`` a second (each line alone: metro measures it
   on its own). The median line -> event latency against the goal (20 ms).
2. Sustained: ``--rate`` lines a second for ``--seconds`` (metro measures what has come as one
   batch): every result received, in order (the ``Sequence`` numbers 1..N), the rate delivered,
   and the latency under that load.
3. ``--server-only``: a :class:`metrology.plant.server.PlantServer` in this process fed per-hole
   results at ``--rate`` (no metro measuring), the same client counting.

The machine's load is printed with the figures (the 2 cores are shared).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.plant.opcua_client import Metro, free_port  # noqa: E402

TABLE6 = ROOT / "metrology" / "data" / "measured" / "nominal.toml"


def _log(tmp: Path, holes: int) -> Path:
    log = tmp / "log.csv"
    subprocess.run([sys.executable, "-m", "cli.main", "simulate-log", "--out", str(log), "--holes", str(holes),
                    "--layout", str(TABLE6), "--true-layout", str(TABLE6), "--seed", "7", "--no-truth"],
                   cwd=ROOT, check=True, capture_output=True)
    return log


#: the start both client scripts share: connected, subscribed, said so (the feeder waits for the word)
_SUBSCRIBED = """
import asyncio, sys, time, json
sys.path.insert(0, {root!r})
from tests.plant.opcua_client import connect, subscribe
async def main():
    c = await connect({url!r})
    _, col = await subscribe(c, period_ms={period})
    print("subscribed", flush=True)
"""
CLIENT = _SUBSCRIBED + """    n, last, seen = {n}, time.monotonic(), 0
    while len(col.results) < n and time.monotonic() - last < {idle}:  # until all came, or none for a while
        await asyncio.sleep(0.05)
        if len(col.results) != seen:
            seen, last = len(col.results), time.monotonic()
    print(json.dumps({{"status_changes": col.status, "results": [[r["Sequence"], r["Line"], r["_arrived"]] for r in col.results]}}), flush=True)
    await c.disconnect()
asyncio.run(main())
"""


#: the first lines, written before the timing starts (metro loads its measuring modules on the first)
WARM = 5


def live(tmp: Path, holes: int, per_s: float, period_ms: float = 5.0) -> dict:
    """``metro measure - --follow --opcua`` fed ``holes`` lines at ``per_s`` a second; a client in its
    own process subscribed with ``period_ms`` publishing. Each line's write, its answer on metro's
    stdout and its event's arrival at the client on one clock (CLOCK_MONOTONIC)."""
    lines = _log(tmp, holes + WARM).read_text().splitlines(keepends=True)
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    t0 = time.perf_counter()
    metro = Metro(["measure", "-", "--layout", str(TABLE6), "--follow", "--opcua", url], tmp, ROOT)
    try:
        client = subprocess.Popen([sys.executable, "-c", CLIENT.format(root=str(ROOT), url=url, n=holes + WARM, period=period_ms,
                                                                       idle=20.0)],
                                  stdout=subprocess.PIPE, text=True)
        assert client.stdout.readline().strip() == "subscribed"
        started = time.perf_counter() - t0
        written, answered = {}, {}

        def read():  # each hole's answer on stdout, in the same run
            for text in metro.proc.stdout:
                if '"line"' in text:
                    answered[json.loads(text)["line"]] = time.perf_counter()

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        metro.proc.stdin.write("".join(lines[:1 + WARM]))  # metro's first lines load its modules: not timed
        metro.proc.stdin.flush()
        while len(answered) < WARM and metro.proc.poll() is None:
            time.sleep(0.01)
        f0 = time.perf_counter()
        k = 1 + WARM
        while k < len(lines):  # paced: line k is due at f0 + (k - WARM) / per_s; every line due is written at once
            now = time.perf_counter()
            due = min(len(lines), 1 + WARM + int((now - f0) * per_s))
            if due > k:
                metro.proc.stdin.write("".join(lines[k:due]))
                metro.proc.stdin.flush()
                t = time.perf_counter()
                for j in range(k, due):
                    written[j + 1] = t  # line numbers from 1 (the header)
                k = due
            else:
                time.sleep(max(0.0, min(0.001, f0 + (k - WARM) / per_s - now)))
        fed_s = time.perf_counter() - f0
        metro.proc.stdin.close()
        reader.join()
        rc = metro.proc.wait()
        got = json.loads(client.stdout.readline())
        client.wait()
    finally:
        metro.kill()

    def stats(ms):
        ms = np.asarray(ms)
        return {"median_ms": round(float(np.median(ms)), 2), "p95_ms": round(float(np.percentile(ms, 95)), 2)} \
            if ms.size else None

    res = got["results"]
    seq = [r[0] for r in res]
    arrived = {r[1]: r[2] for r in res}
    both = [k for k in arrived if k in written and k in answered]
    span = (res[-1][2] - res[0][2]) if len(res) > 1 else None
    return {"holes": holes, "rate_asked": per_s, "fed_s": round(fed_s, 2), "received": len(res) - WARM,
            "in_order": seq == list(range(1, len(seq) + 1)), "answered_on_stdout": len(answered), "exit": rc,
            "status_changes": got["status_changes"], "server_start_s": round(started, 2),
            "delivered_per_s": round(len(res) / span, 1) if span else None,
            "line_to_event": stats([(arrived[k] - written[k]) * 1e3 for k in both]),
            "line_to_stdout_answer": stats([(answered[k] - written[k]) * 1e3 for k in both]),
            "stdout_answer_to_event": stats([(arrived[k] - answered[k]) * 1e3 for k in both])}


COUNTER = _SUBSCRIBED + """    n = {n}
    end = time.monotonic() + {wait}
    while len(col.results) < n and time.monotonic() < end:
        await asyncio.sleep(0.05)
    seq = [r["Sequence"] for r in col.results]
    print(json.dumps({{"status_changes": col.status, "received": len(seq), "in_order": seq == sorted(seq), "first_last": [seq[0], seq[-1]] if seq else None,
                      "span_s": (col.results[-1]["_arrived"] - col.results[0]["_arrived"]) if seq else None}}), flush=True)
    await c.disconnect()
asyncio.run(main())
"""


def throughput(rate: float, seconds: float, period_ms: float = 10.0) -> dict:
    from metrology.plant.server import PlantServer

    n = int(rate * seconds)
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    warnings = []
    with PlantServer(url, tolerance_deg=0.5, calibration={"sha256": "0" * 64}, warn=warnings.append) as server:
        counter = subprocess.Popen([sys.executable, "-c", COUNTER.format(root=str(ROOT), url=url, n=n, period=period_ms,
                                                                       wait=seconds * 3 + 30)],
                                   stdout=subprocess.PIPE, text=True)
        assert counter.stdout.readline().strip() == "subscribed"
        rng = np.random.default_rng(0)
        angles = rng.uniform(0, 0.4, n)
        t0 = time.perf_counter()
        for k in range(n):  # paced: hole k is due at t0 + k / rate
            due = t0 + k / rate
            while time.perf_counter() < due:
                time.sleep(max(0.0, min(0.001, due - time.perf_counter())))
            server.result({"hole_id": f"H{k + 1}", "status": "conforms", "angle_deg": float(angles[k]),
                           "U95_angle_deg": 0.01, "angle_after_deg": None, "U95_after_deg": None, "cell": "C1",
                           "line": k + 2})
        fed_s = time.perf_counter() - t0
        got = json.loads(counter.stdout.readline())
        counter.wait()
    return {"sent": n, "rate_asked": rate, "fed_s": round(fed_s, 2), **got,
            "delivered_per_s": round(got["received"] / got["span_s"], 1) if got["span_s"] else None,
            "warnings": warnings}


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--latency-holes", type=int, default=200, help="holes of the trickle leg (0: none)")
    ap.add_argument("--trickle", type=float, default=20.0, help="the trickle leg's lines a second")
    ap.add_argument("--rate", type=float, default=1000.0, help="the sustained leg's lines a second")
    ap.add_argument("--seconds", type=float, default=5.0, help="the sustained leg's length (0: none)")
    ap.add_argument("--period-ms", type=float, default=5.0, help="the client's publishing interval")
    ap.add_argument("--server-only", action="store_true", help="also the server alone fed at --rate (no metro)")
    a = ap.parse_args(argv)
    print(f"load average before: {os.getloadavg()}")
    legs = []
    if a.latency_holes > 0:
        legs.append(("trickle", a.latency_holes, a.trickle))
    if a.seconds > 0:
        legs.append(("sustained", int(a.rate * a.seconds), a.rate))
    for name, holes, per_s in legs:
        with tempfile.TemporaryDirectory() as tmp:
            r = live(Path(tmp), holes, per_s, a.period_ms)
        print(f"{name}: metro measure - --follow --opcua, {holes} lines at {per_s:g}/s:", json.dumps(r))
        m = r["line_to_event"]["median_ms"] if r["line_to_event"] else float("nan")
        ok = r["received"] == holes and r["in_order"]
        print(f"  line on stdin -> result-ready event at the client: median {m} ms against the goal 20 ms "
              f"({'met' if m <= 20 else 'NOT met'}); {r['received']} of {holes} results, "
              f"{'none lost or reordered' if ok else 'LOST OR REORDERED'}")
    if a.server_only:
        thr = throughput(a.rate, max(a.seconds, 1.0), a.period_ms)
        print("the server alone:", json.dumps(thr))
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
