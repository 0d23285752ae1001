"""A real OPC UA client (asyncua) for the tests and the benchmark: subscribes to the Server object's
events of metro's two event types and keeps every notification with its arrival time."""

from __future__ import annotations

import asyncio
import socket
import subprocess
import sys
import time


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def _subtype(node, name):
    from asyncua import ua

    for ch in await node.get_children(refs=ua.ObjectIds.HasSubtype):
        if (await ch.read_browse_name()).Name == name:
            return ch
        found = await _subtype(ch, name)
        if found is not None:
            return found
    return None


class Collector:
    """``event_notification`` handler: results and alarms, each with ``time.perf_counter()`` at arrival."""

    def __init__(self):
        self.results, self.alarms, self.status = [], [], []

    def status_change_notification(self, status):
        self.status.append(str(status.Status))

    def event_notification(self, event):
        f = {k: v for k, v in event.get_event_props_as_fields_dict().items()}
        f = {k: (v.Value if hasattr(v, "Value") else v) for k, v in f.items()}
        f["_arrived"] = time.perf_counter()
        (self.results if f.get("Sequence") is not None else self.alarms).append(f)


#: s between the client's checks that the server is alive, and how long each waits for its answer (a Read of
#: the server's state): asyncua's default, 1 s, is a deadline on the server's answer, and on a loaded test machine
#: (load 10-14 on 2 cores) the server's process or the client's own, busy decoding a publish of hundreds of events,
#: missed it: the client took the server for dead, disconnected, and the test lost the rest of the log ("client is
#: disconnected", 5 or 773 of 1150 results). The tests here check what arrives, not how soon
#: (``benchmarks/bench_plant.py`` times that); a server that does not answer still fails them, 30 s later.
WATCHDOG_S = 30.0


async def connect(url: str, timeout_s: float = 120.0, proc=None):
    """A connected client, retrying while the server starts (the server process ``proc`` still alive)."""
    from asyncua import Client

    end = time.monotonic() + timeout_s
    while True:
        c = Client(url, timeout=30, watchdog_intervall=WATCHDOG_S)
        try:
            await c.connect()
            return c
        except (OSError, asyncio.TimeoutError, ConnectionError):
            if time.monotonic() > end or (proc is not None and proc.poll() is not None):
                raise
            await asyncio.sleep(0.2)


#: the event fields a controller asks for (not the ~60 of both types: Machinery Result's empty
#: ``Result`` structure and its parts, BaseEventType's local time, ...)
FIELDS = ("EventType", "SourceName", "Message", "Severity", "CharacteristicIdentifier", "IsValid",
          "LowerToleranceLimit", "Nominal", "ResultEvaluation", "ResultValue", "UpperToleranceLimit", "U95", "Status",
          "CorrectionValueAbsolute", "Cell", "Sequence", "Line", "Sensor", "HoleId", "Alarm")


async def subscribe(client, period_ms: float = 50.0, queue: int = 200_000):
    """Subscribe to the Server object's hole results and drift alarms (the fields :data:`FIELDS`);
    (subscription, collector).

    ``period_ms`` 50: asyncua's server deletes a subscription after the client's lifetime count
    (10,000) of publishing cycles without a publish request, and a late server runs its missed cycles
    back to back; at 5 ms a loaded test machine could reach that in seconds and lose the rest of the
    log. A test here checks what arrives, not how soon (``benchmarks/bench_plant.py`` times that)."""
    from asyncua import ua
    from asyncua.common.events import get_filter_from_event_type

    base = client.get_node(ua.ObjectIds.BaseEventType)
    hole_t = await _subtype(base, "HoleResultReadyEventType")
    alarm_t = await _subtype(base, "DriftAlarmEventType")
    evfilter = await get_filter_from_event_type([hole_t, alarm_t])
    evfilter.SelectClauses = [c for c in evfilter.SelectClauses
                              if len(c.BrowsePath) == 1 and c.BrowsePath[0].Name in FIELDS]
    col = Collector()
    sub = await client.create_subscription(period_ms, col)
    await sub.subscribe_events(client.nodes.server, [hole_t, alarm_t], evfilter=evfilter, queuesize=queue)
    return sub, col


class Metro:
    """``metro measure ...`` as a process reading its log from a pipe; stderr to a file."""

    def __init__(self, args, tmp, cwd):
        import threading

        self.err_path = tmp / "metro.err"
        self._err = open(self.err_path, "w")
        self.proc = subprocess.Popen([sys.executable, "-m", "cli.main", *args], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=self._err, text=True, cwd=cwd)
        self._threading = threading

    def feed(self, text: str):
        """Write ``text`` to stdin and close it, in a thread (stdout is read meanwhile)."""
        def run():
            try:
                self.proc.stdin.write(text)
                self.proc.stdin.close()
            except (BrokenPipeError, ValueError):
                pass  # the process ended early: its exit code and stderr say why

        t = self._threading.Thread(target=run, daemon=True)
        t.start()
        return t

    def finish(self, timeout: float = 600.0):
        """(exit code, stdout, stderr) once it ends."""
        out = self.proc.stdout.read()
        self.proc.wait(timeout)
        self._err.close()
        return self.proc.returncode, out, self.err_path.read_text()

    def kill(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self._err.close()
