"""Live results over OPC UA (issue 52): latency and throughput of ``metro measure --opcua``.

    python benchmarks/bench_plant.py [--latency-holes 200] [--rate 1000] [--seconds 10]

1. Latency: ``metro measure - --follow --opcua opc.tcp://127.0.0.1:PORT`` as its own process; a
   real asyncua client (this process) subscribed to the Server object's events with a 5 ms
   publishing interval; the log's lines written to metro's stdin one at a time, 20 a second. The
   latency of a hole is from the write of its line to the arrival of its result-ready event at the
   client (``time.perf_counter``: CLOCK_MONOTONIC, one clock for both processes). It includes
   metro's measurement of the hole (one row at a time, its drift watch) and the publishing
   interval's wait. The median against the goal (20 ms).
2. Throughput: a :class:`metrology.plant.server.PlantServer` in this process, fed per-hole results
   (dicts as ``--follow`` makes them) at ``--rate`` holes a second for ``--seconds``; the same client
   in a subprocess counts what arrives: none lost, none reordered (the ``Sequence`` numbers
   1..N in order), and the rate the server kept up.

The machine's load is printed with the figures (the 2 cores are shared).
"""

from __future__ import annotations

import argparse
import asyncio
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

from tests.plant.opcua_client import Metro, connect, free_port, subscribe  # noqa: E402

TABLE6 = ROOT / "metrology" / "data" / "measured" / "nominal.toml"


def _log(tmp: Path, holes: int) -> Path:
    log = tmp / "log.csv"
    subprocess.run([sys.executable, "-m", "cli.main", "simulate-log", "--out", str(log), "--holes", str(holes),
                    "--layout", str(TABLE6), "--true-layout", str(TABLE6), "--seed", "7", "--no-truth"],
                   cwd=ROOT, check=True, capture_output=True)
    return log


async def latency(tmp: Path, holes: int, per_s: float = 20.0) -> dict:
    lines = _log(tmp, holes).read_text().splitlines(keepends=True)
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    metro = Metro(["measure", "-", "--layout", str(TABLE6), "--follow", "--opcua", url], tmp, ROOT)
    try:
        t0 = time.perf_counter()
        client = await connect(url, proc=metro.proc)
        started = time.perf_counter() - t0
        _, col = await subscribe(client, period_ms=5.0)
        written = {}

        def feed():
            metro.proc.stdin.write(lines[0])
            for k, line in enumerate(lines[1:], start=2):
                time.sleep(1.0 / per_s)
                written[k] = time.perf_counter()
                metro.proc.stdin.write(line)
                metro.proc.stdin.flush()
            metro.proc.stdin.close()

        answered = {}

        def read():  # the baseline: each hole's answer on stdout, in the same run
            for text in metro.proc.stdout:
                if '"line"' in text:
                    answered[json.loads(text)["line"]] = time.perf_counter()

        threading.Thread(target=feed, daemon=True).start()
        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        await asyncio.get_running_loop().run_in_executor(None, reader.join)
        rc = metro.proc.wait()
        await asyncio.sleep(0.5)
        await client.disconnect()
    finally:
        metro.kill()

    def stats(ms):
        ms = np.asarray(ms)
        return {"median_ms": round(float(np.median(ms)), 2), "p95_ms": round(float(np.percentile(ms, 95)), 2)}

    got = [r for r in col.results if r["Line"] in written and r["Line"] in answered]
    return {"holes": holes, "received": len(col.results), "answered_on_stdout": len(answered), "exit": rc,
            "server_start_s": round(started, 2),
            "line_to_event": stats([(r["_arrived"] - written[r["Line"]]) * 1e3 for r in got]),
            "line_to_stdout_answer": stats([(answered[r["Line"]] - written[r["Line"]]) * 1e3 for r in got]),
            "stdout_answer_to_event": stats([(r["_arrived"] - answered[r["Line"]]) * 1e3 for r in got])}


COUNTER = """
import asyncio, sys, time, json
sys.path.insert(0, {root!r})
from tests.plant.opcua_client import connect, subscribe
async def main():
    c = await connect({url!r})
    _, col = await subscribe(c, period_ms={period})
    print("subscribed", flush=True)
    n = {n}
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
    ap.add_argument("--latency-holes", type=int, default=200)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--period-ms", type=float, default=10.0, help="the throughput client's publishing interval")
    a = ap.parse_args(argv)
    print(f"load average before: {os.getloadavg()}")
    if a.latency_holes > 0:
        with tempfile.TemporaryDirectory() as tmp:
            lat = asyncio.run(latency(Path(tmp), a.latency_holes))
        print("latency, line on stdin -> result-ready event at the client:", json.dumps(lat))
        m = lat["line_to_event"]["median_ms"]
        print(f"  median {m} ms against the goal 20 ms: {'met' if m <= 20 else 'NOT met'}; of it, the hole's measurement "
              f"(line -> its answer on stdout, no server involved) {lat['line_to_stdout_answer']['median_ms']} ms")
    thr = throughput(a.rate, a.seconds, a.period_ms)
    print("throughput through the server:", json.dumps(thr))
    ok = thr["received"] == thr["sent"] and thr["in_order"]
    print(f"  {thr['sent']} results at {a.rate:g}/s: {'none lost or reordered' if ok else 'LOST OR REORDERED'}")
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
