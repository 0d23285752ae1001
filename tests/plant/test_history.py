"""metro measure --opcua keeps its events' history: a real asyncua client that disconnects while
metro goes on measuring, and reconnects, reads exactly the results it missed, in order, by
HistoryRead of the Server object's events; the history's bound names the older ones missing."""

import asyncio
import json
import os
import threading
import time
import tracemalloc
from datetime import datetime, timedelta, timezone
from types import SimpleNamespace

import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.data import data_path
from tests.plant.opcua_client import Metro, connect, free_port, subscribe

asyncua = pytest.importorskip("asyncua")
runner = CliRunner()
TABLE6 = data_path("measured", "nominal.toml")
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _wait(cond, what, timeout_s=120.0):
    end = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < end, what
        time.sleep(0.02)


async def _until(cond, what, timeout_s=120.0):
    end = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < end, what
        await asyncio.sleep(0.02)


async def _reconnect(lines, tmp):
    from asyncua import ua

    from tests.plant.opcua_client import _subtype

    url = f"opc.tcp://127.0.0.1:{free_port()}"
    metro = Metro(["measure", "-", "--layout", str(TABLE6), "--follow", "--opcua", url], tmp, ROOT)
    answers = []
    reader = threading.Thread(target=lambda: answers.extend(json.loads(x) for x in metro.proc.stdout), daemon=True)
    try:
        client = await connect(url, proc=metro.proc)
        _, col = await subscribe(client)
        reader.start()
        metro.proc.stdin.write("".join(lines[:31]))  # the header and 30 holes
        metro.proc.stdin.flush()
        await _until(lambda: len(col.results) >= 30, "the first 30 results")
        await client.disconnect()
        metro.proc.stdin.write("".join(lines[31:71]))  # 40 more while no client is connected
        metro.proc.stdin.flush()
        await _until(lambda: len(answers) >= 70, "metro measuring on")
        again = await connect(url, proc=metro.proc)
        try:
            hole_t = await _subtype(again.get_node(ua.ObjectIds.BaseEventType), "HoleResultReadyEventType")
            history = await again.nodes.server.read_event_history(None, datetime.now(timezone.utc), 0, [hole_t])
        finally:
            await again.disconnect()
        metro.proc.stdin.close()
        await asyncio.get_running_loop().run_in_executor(None, reader.join)
        rc = metro.proc.wait()
        return rc, col.results, history, answers
    finally:
        metro.kill()


def test_a_client_back_reads_the_results_it_missed(tmp_path):
    log = tmp_path / "log.csv"
    r = runner.invoke(app, ["simulate-log", "--out", str(log), "--holes", "70", "--seed", "52", "--layout", str(TABLE6),
                            "--true-layout", str(TABLE6), "--no-truth"])
    assert r.exit_code == 0, r.output
    rc, live, history, answers = asyncio.run(_reconnect(log.read_text().splitlines(keepends=True), tmp_path))
    assert rc in (0, 1)
    last = live[-1]["Sequence"]
    assert [e["Sequence"] for e in live] == list(range(1, last + 1))
    # newest first (no start time: read backwards from now); the client keeps what follows its last
    seq = [e.Sequence for e in history]
    assert seq == sorted(seq, reverse=True) and seq[0] == 70 and seq[-1] == 1
    missed = [e for e in reversed(history) if e.Sequence > last]
    assert [e.Sequence for e in missed] == list(range(last + 1, 71))
    holes = [a for a in answers if "hole_id" in a]
    for e in missed:  # each equal to metro's answer for that hole on stdout
        h = holes[e.Sequence - 1]
        assert e.CharacteristicIdentifier == h["hole_id"] and e.Line == h["line"] and e.Status == h["status"]
        after = h["angle_after_deg"]
        assert e.ResultValue == (after if after is not None and after == after else h["angle_deg"])


def test_the_history_is_bounded_and_names_what_it_lost():
    """The oldest events go first; what a client reads back then starts past its last Sequence (the
    gap names the results missing); each event kept costs about 1 kB (the bound of docs/plant.md)."""
    from asyncua import ua

    from metrology.plant.gms import HOLE_FIELDS
    from metrology.plant.history import EventHistory

    history = EventHistory(limit=1000)
    ev = SimpleNamespace(SourceNode=ua.NodeId(1, 2), SourceName="C1", Severity=100)
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    t0 = datetime.now(timezone.utc)
    for k in range(1, 3001):
        ev.EventId, ev.Time = os.urandom(16), t0 + timedelta(milliseconds=k)
        ev.ReceiveTime, ev.Message = ev.Time, ua.LocalizedText(f"C1 C1-{k:08d}: conforms")
        for name, vt in HOLE_FIELDS.items():
            setattr(ev, name, {"String": f"C1-{k:08d}", "Boolean": True, "Double": 0.1 * k, "Int32": 1}.get(vt, k))
        history.keep(ev, tuple(HOLE_FIELDS))
    per_event = (tracemalloc.get_traced_memory()[0] - before) / 1000
    tracemalloc.stop()
    kept = history.events()
    assert [e.Sequence for e in kept] == list(range(2001, 3001))
    assert kept[0].CharacteristicIdentifier == "C1-00002001" and kept[0].ResultValue == pytest.approx(200.1)
    assert len(history.events(kept[10].Time, kept[19].Time)) == 10
    assert per_event < 1500, per_event
