"""``metro measure --opcua opc.tcp://HOST:PORT``: an OPC UA server (asyncua, in a thread of its
own) that announces each hole's result as soon as it is measured, and each drift alarm.

The address space is :mod:`metrology.plant.gms`'s. Every hole fires a ``HoleResultReadyEventType``
event (Machinery Result's result-ready event, with GMS's characteristic fields) and updates its
cell's ``LastResult``/``LastCorrection``; every drift alarm fires a ``DriftAlarmEventType`` with
its severity. Events are emitted by the Server object (so a client subscribed to the Server's
events receives every one) and by the cell's object (reached from Server by HasNotifier). The
Server object's events are kept (the last :data:`metrology.plant.history.HISTORY_EVENTS`) for
OPC UA HistoryRead: a client back after a disconnect reads the results it missed.

Security (OPC UA's own modes): the endpoint binds 127.0.0.1 unless the URL names another host; a
host that is not loopback needs ``cert`` and ``key`` (PEM) and ``users`` (a file of ``user:SHA-256 of
the password`` lines), and with them (on any host) the server serves Basic256Sha256 SignAndEncrypt
only, with user names only (no anonymous). Nothing in the address space is writable and no client may add or delete nodes or
references, whoever it is.

A client that stops reading (its queued notifications reach :data:`SLOW_CLIENT_RESULTS`) has its
subscription deleted, with a warning; measuring goes on.
"""

from __future__ import annotations

import asyncio
import hashlib
import hmac
import ipaddress
import threading
import time
from urllib.parse import urlparse

__all__ = ["PlantServer", "parse_endpoint", "SLOW_CLIENT_RESULTS", "read_users"]

#: a subscription with this many notifications queued for it is a client that does not read: deleted
SLOW_CLIENT_RESULTS = 20_000
#: how long closing waits at most for clients to be sent (and acknowledge) what was queued for them (s),
#: and how long without progress
DRAIN_S, DRAIN_IDLE_S = 120.0, 15.0
#: a cell's LastResult and LastCorrection are written at most this often (s; and once the results stop
#: coming): each write costs as much as an event, and the events carry every result
LAST_EVERY_S = 0.05
#: s of announcing at most before the server's loop answers its sessions (a client's keepalive Read, its Publish
#: requests): results are handed over a batch at once (``measure --follow``: up to 256 holes; a whole log's
#: table), and firing a batch's events in one pass held the loop for all of them (1150 holes in 5 batches, one
#: client, load 10-11 on 2 cores: the loop's longest pause 0.28-0.47 s, 0.07-0.09 s sliced; the client's Read
#: 0.45-0.58 s, 0.14-0.20 s), where a client's keepalive waits 1 s (asyncua's default)
SLICE_S = 0.01
#: severity (1-1000) of a drift alarm as first raised, and once sized on its new baseline
SEVERITY_RAISED, SEVERITY_SIZED = 700, 800


def parse_endpoint(url: str) -> tuple[str, int, bool]:
    """``opc.tcp://HOST:PORT`` -> (host, port, loopback), HOST 127.0.0.1 where none is given
    (``opc.tcp://:4840``); ValueError (one line) otherwise."""
    p = urlparse(url)
    try:
        port = p.port
    except ValueError:
        port = None
    if p.scheme != "opc.tcp" or port is None:
        raise ValueError(f"--opcua {url}: expected opc.tcp://HOST:PORT (e.g. opc.tcp://127.0.0.1:4840)")
    host = p.hostname or "127.0.0.1"
    try:
        loopback = host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = False
    return host, port, loopback


def read_users(path) -> dict:
    """``user:sha256hex`` lines (``#`` comments) -> {user: digest}; ValueError naming the line."""
    users = {}
    try:
        lines = open(path, encoding="utf-8").read().splitlines()
    except OSError as exc:
        raise ValueError(f"--opcua-users {path}: cannot read ({exc.strerror})") from None
    for n, line in enumerate(lines, start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        user, _, digest = line.partition(":")
        if not user or len(digest) != 64 or any(c not in "0123456789abcdef" for c in digest.lower()):
            raise ValueError(f"--opcua-users {path}: line {n}: expected user:SHA-256 of the password (64 hex digits)")
        users[user] = digest.lower()
    if not users:
        raise ValueError(f"--opcua-users {path}: no user")
    return users


def _ruleset(base):
    """Read-only for every session: no Write, no node management (AddNodes, DeleteNodes, references)."""
    from asyncua import ua
    from asyncua.crypto.permission_rules import ADMIN_TYPES

    denied = {*ADMIN_TYPES, ua.ObjectIds.WriteRequest_Encoding_DefaultBinary,
              ua.ObjectIds.HistoryUpdateRequest_Encoding_DefaultBinary}

    class ReadOnly(base):
        def __init__(self):
            pass

        def check_validity(self, user, action_type_id, body):
            return action_type_id not in denied

    return ReadOnly()


def _user_manager(users: dict | None):
    from asyncua.crypto.permission_rules import User, UserRole

    class Users:
        def get_user(self, iserver, username=None, password=None, certificate=None):
            if users is None:  # loopback: anonymous sessions, read-only
                return User(role=UserRole.User)
            if not username or password is None or username not in users:
                return None
            pw = password.decode() if isinstance(password, bytes) else str(password)
            ok = hmac.compare_digest(hashlib.sha256(pw.encode()).hexdigest(), users[username])
            return User(role=UserRole.User, name=username) if ok else None

    return Users()


class PlantServer:
    """The OPC UA server of a ``metro measure`` run (module docstring); a context manager.

    Parameters
    ----------
    url : str, ``opc.tcp://HOST:PORT``
    tolerance_deg : float, deg, the characteristic's upper tolerance limit
    calibration : dict, {"sha256", "file", "certificate": {...}}: the calibration in use
    cert, key, users : paths or None, required for a host that is not loopback
    warn : callable(str) or None, where warnings go (a slow client dropped)
    history_events : int or None, events kept for HistoryRead (None: :data:`metrology.plant.history.HISTORY_EVENTS`)
    """

    def __init__(self, url: str, *, tolerance_deg: float, calibration: dict, cert=None, key=None, users=None,
                 warn=None, slow_results: int = SLOW_CLIENT_RESULTS, history_events: int | None = None):
        self.url = url
        self.host, self.port, loopback = parse_endpoint(url)
        self.users = None
        secure = cert is not None or key is not None or users is not None
        if not loopback or secure:
            if cert is None or key is None or users is None:
                raise ValueError(f"--opcua {url}: " + ("a host that is not loopback" if not loopback else "a secured "
                                 "endpoint") + " needs --opcua-cert, --opcua-key and --opcua-users (signed and "
                                 "encrypted, user and password): refused")
            self.users = read_users(users)
        self.cert, self.key = cert, key
        self.tolerance_deg = float(tolerance_deg)
        self.calibration = dict(calibration)
        self.warn = warn
        self.slow_results = int(slow_results)
        from metrology.plant.history import HISTORY_EVENTS

        self.history_events = HISTORY_EVENTS if history_events is None else int(history_events)
        self.sequence = 0
        self.dropped = []
        self._loop = None
        self._thread = None
        self._queue = None
        self._ready = threading.Event()
        self._error = None
        self._closing = None

    # ----- the caller's thread -----
    def __enter__(self):
        self._check_bind()
        self._thread = threading.Thread(target=self._run, name="metro-opcua", daemon=True)
        self._thread.start()
        self._ready.wait()
        if self._error is not None:
            self._thread.join()
            raise self._error
        return self

    def _check_bind(self) -> None:
        """Refuse at once an address that cannot be bound (in use, not this machine's), before the
        NodeSets load (seconds); the server's own bind reports the same if it loses a race."""
        import socket

        try:
            infos = socket.getaddrinfo(self.host, self.port, type=socket.SOCK_STREAM)
        except OSError as exc:
            raise ValueError(f"--opcua {self.url}: cannot resolve {self.host} ({exc.strerror or exc})") from None
        family, _, _, _, addr = infos[0]
        with socket.socket(family, socket.SOCK_STREAM) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as asyncio's server does
            try:
                s.bind(addr)
            except OSError as exc:
                raise ValueError(f"--opcua {self.url}: cannot listen on {self.host}:{self.port} "
                                 f"({exc.strerror or exc})") from None

    def wait_for_client(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for a client's subscription with a monitored item (before a whole
        log is measured: the results go out as they are measured); whether one came."""
        async def wait():
            subs = self.space.server.iserver.subscription_service
            end = time.monotonic() + timeout_s
            while time.monotonic() < end:
                if any(sub.monitored_item_srv._monitored_items for sub in subs.subscriptions.values()):
                    return True
                await asyncio.sleep(0.05)
            return False

        return asyncio.run_coroutine_threadsafe(wait(), self._loop).result()

    def result(self, hole: dict) -> None:
        """Announce a hole's result (the dict of ``measure --follow``: hole_id, status, angle_deg,
        U95_angle_deg, angle_after_deg, U95_after_deg, correction_deg, cell, line)."""
        self._loop.call_soon_threadsafe(self._queue.put_nowait, ("hole", hole, time.perf_counter()))

    def results(self, holes: list) -> None:
        """Announce the results of holes measured together (one hand-over to the server's thread)."""
        if holes:
            self._loop.call_soon_threadsafe(self._queue.put_nowait, ("holes", list(holes), time.perf_counter()))

    def alarm(self, alarm: dict) -> None:
        """Announce a drift alarm (the dict of ``measure --follow``'s ``{"alarm": ...}`` lines)."""
        self._loop.call_soon_threadsafe(self._queue.put_nowait, ("alarm", alarm, time.perf_counter()))

    def write(self, table) -> None:
        """Announce the holes of a per-hole results table (``measure`` on a whole log: a results sink)."""
        cols = [c for c in ("hole_id", "status", "angle_deg", "U95_angle_deg", "angle_after_deg", "U95_after_deg",
                            "correction_deg", "cell") if c in table.column_names]
        self.results(table.select(cols).to_pylist())

    def __exit__(self, exc_type, exc, tb):
        if self._loop is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._queue.put_nowait, ("close", None, None))
            self._thread.join()
        return False

    # ----- the server's thread -----
    def _run(self) -> None:
        self._loop = asyncio.new_event_loop()
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(self._serve())
            tasks = asyncio.all_tasks(self._loop)  # the sessions' own loops, ended with the server
            for t in tasks:
                t.cancel()
            if tasks:
                self._loop.run_until_complete(asyncio.gather(*tasks, return_exceptions=True))
        finally:
            self._loop.close()

    async def _start(self):
        import logging

        from asyncua import Server, ua
        from asyncua.crypto.permission_rules import PermissionRuleset

        from metrology.plant.gms import build

        for name in ("asyncua", "asyncua.server", "asyncua.common"):
            logging.getLogger(name).setLevel(logging.ERROR)
        server = Server(user_manager=_user_manager(self.users))
        await server.init()
        server.iserver.allow_remote_admin = False
        server.set_endpoint(f"opc.tcp://{self.host}:{self.port}/")
        server.set_server_name("metro measure")
        await server.set_application_uri("urn:metro:measure")
        if self.users is None:
            server.set_security_policy([ua.SecurityPolicyType.NoSecurity], permission_ruleset=_ruleset(PermissionRuleset))
            server.set_identity_tokens([ua.AnonymousIdentityToken])
        else:
            try:
                await server.load_certificate(str(self.cert))
                await server.load_private_key(str(self.key))
            except Exception as exc:  # noqa: BLE001 - any unreadable or mismatched PEM: one line
                raise ValueError(f"--opcua-cert/--opcua-key: cannot load ({exc.__class__.__name__}: {exc})") from None
            server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt],
                                       permission_ruleset=_ruleset(PermissionRuleset))
            server.set_identity_tokens([ua.UserNameIdentityToken])
        self.space = await build(server, self.calibration)
        from metrology.plant.history import EventHistory, history_storage

        self.history = EventHistory(self.history_events)  # HistoryRead of the Server object's events
        server.iserver.history_manager.set_storage(history_storage(self.history, ua.NodeId(ua.ObjectIds.Server)))
        notifier = (1 << ua.EventNotifier.SubscribeToEvents) | (1 << ua.EventNotifier.HistoryRead)  # bit numbers
        await server.nodes.server.write_attribute(ua.AttributeIds.EventNotifier,
                                                  ua.DataValue(ua.Variant(notifier, ua.VariantType.Byte)))
        try:
            await server.start()
        except OSError as exc:
            raise ValueError(f"--opcua {self.url}: cannot listen on {self.host}:{self.port} ({exc.strerror or exc})") \
                from None
        return server

    async def _serve(self) -> None:
        self._queue = asyncio.Queue()
        try:
            server = await self._start()
        except Exception as exc:  # noqa: BLE001 - reported to the caller's thread, which raises it
            self._error = exc if isinstance(exc, ValueError) else ValueError(f"--opcua {self.url}: {exc}")
            self._ready.set()
            return
        self._ready.set()
        checked = wrote = sliced = time.monotonic()
        last = {}  # each cell's last result not yet written to its LastResult / LastCorrection
        try:
            closing, getter = False, None
            while not closing:
                # a getter kept across timeouts (wait_for on Queue.get can drop an item it got as it times out)
                getter = getter or asyncio.ensure_future(self._queue.get())
                done, _ = await asyncio.wait({getter}, timeout=LAST_EVERY_S if last else None)
                first, getter = (getter.result(), None) if done else (None, getter)
                items = [first] if first is not None else []
                while not self._queue.empty():  # all that came meanwhile: one pass for them
                    items.append(self._queue.get_nowait())
                for kind, item, _ in items:
                    if kind == "close":
                        closing = True
                        break
                    for hole in ((item,) if kind == "hole" else item if kind == "holes" else ()):
                        cell, fields = await self._hole(hole)
                        last[cell] = fields
                        if time.monotonic() - sliced > SLICE_S:  # the sessions' requests answered meanwhile
                            await asyncio.sleep(0)
                            sliced = time.monotonic()
                    if kind == "alarm":
                        await self._alarm(item)
                if last and (closing or first is None or time.monotonic() - wrote >= LAST_EVERY_S):
                    for cell, fields in last.items():
                        await self._write_last(cell, fields)
                    last, wrote = {}, time.monotonic()
                if closing:
                    await self._drain()
                elif time.monotonic() - checked > 0.2:
                    checked = time.monotonic()
                    await self._drop_slow()
        finally:
            await server.stop()

    async def _hole(self, hole: dict) -> tuple:
        """Fire the hole's result-ready event; (cell, its fields) for :meth:`_write_last`."""

        from metrology.plant.gms import EVALUATION, HOLE_FIELDS, cell_node

        self.sequence += 1
        cell = str(hole.get("cell") or "cell")
        await cell_node(self.space, cell)
        after = hole.get("angle_after_deg")
        use_after = after is not None and after == after
        angle = after if use_after else hole.get("angle_deg")
        u95 = hole.get("U95_after_deg") if use_after else hole.get("U95_angle_deg")
        status = str(hole.get("status"))
        valid = status != "not_measured" and angle is not None and angle == angle
        nan = float("nan")
        corr = hole.get("correction_deg")
        fields = {"CharacteristicIdentifier": str(hole.get("hole_id")), "IsValid": valid,
                  "LowerToleranceLimit": 0.0, "Nominal": 0.0, "ResultEvaluation": EVALUATION.get(status, 0),
                  "ResultValue": float(angle) if valid else nan, "UpperToleranceLimit": self.tolerance_deg,
                  "U95": float(u95) if valid and u95 is not None else nan, "Status": status,
                  "CorrectionValueAbsolute": float(corr) if corr is not None else nan, "Cell": cell,
                  "Sequence": self.sequence, "Line": int(hole.get("line") or 0)}
        ev = self.space.hole_event.event
        for name in HOLE_FIELDS:  # plain values (the event type gives their types): asyncua deep-copies each
            setattr(ev, name, fields[name])
        ev.SourceNode = self.space.cells[cell][0].nodeid
        ev.SourceName = cell
        ev.Severity = 100 if status == "conforms" else 500
        await self._fire(self.space.hole_event, f"{cell} {fields['CharacteristicIdentifier']}: {status}", HOLE_FIELDS)
        return cell, fields

    async def _write_last(self, cell: str, fields: dict) -> None:
        """The cell's ``LastResult`` and ``LastCorrection``: its last hole's (written straight into the
        address space, once per pass over the queue)."""
        from asyncua import ua

        from metrology.plant.gms import HOLE_FIELDS

        _, nodes = self.space.cells[cell]
        server = self.space.server
        values = [(nodes["result"][k], fields[k], HOLE_FIELDS[k]) for k in nodes["result"]]
        values += [(nodes["U95"], fields["U95"], "Double"), (nodes["Status"], fields["Status"], "String"),
                   (nodes["correction"]["CharacteristicIdentifier"], fields["CharacteristicIdentifier"], "String"),
                   (nodes["correction"]["Identifier"], f"{cell}/{fields['CharacteristicIdentifier']}/normal", "String"),
                   (nodes["correction"]["CorrectionValueAbsolute"], fields["CorrectionValueAbsolute"], "Double")]
        for node, value, vt in values:
            await server.write_attribute_value(node.nodeid, ua.DataValue(ua.Variant(value, getattr(ua.VariantType, vt))))

    async def _alarm(self, alarm: dict) -> None:

        from metrology.plant.gms import ALARM_FIELDS, cell_node

        cell = str(alarm.get("cell") or "cell")
        await cell_node(self.space, cell)
        ev = self.space.alarm_event.event
        raised = bool(alarm.get("raised"))
        sensor = alarm.get("sensor") or alarm.get("sensors") or ""
        for name, value in (("Cell", cell), ("Sensor", " ".join(sensor) if isinstance(sensor, list) else str(sensor)),
                            ("HoleId", str(alarm.get("hole_id") or "")),
                            ("Alarm", "raised" if raised else "sized")):
            setattr(ev, name, value)
        ev.SourceNode = self.space.cells[cell][0].nodeid
        ev.SourceName = cell
        ev.Severity = SEVERITY_RAISED if raised else SEVERITY_SIZED
        await self._fire(self.space.alarm_event, f"drift alarm {cell} at {alarm.get('hole_id')}: "
                                                 + ("raised" if raised else "sized on its new baseline"), ALARM_FIELDS)

    async def _fire(self, gen, message: str, names) -> None:
        """Emit from the Server object (kept in its history with the fields ``names``), then from the
        cell's object (for a client subscribed to it): asyncua's ``EventGenerator.trigger`` less its
        per-event local-time lookup."""
        import os
        from datetime import datetime, timezone

        from asyncua import ua

        ev = gen.event
        ev.EventId = os.urandom(16)
        ev.Time = ev.ReceiveTime = datetime.now(timezone.utc)
        ev.Message = ua.LocalizedText(message)
        subs = self.space.server.iserver.subscription_service
        cell_id = ev.SourceNode
        ev.emitting_node = ua.NodeId(ua.ObjectIds.Server)
        await subs.trigger_event(ev)
        self.history.keep(ev, names)
        ev.emitting_node = cell_id
        await subs.trigger_event(ev)

    async def _drop_slow(self) -> None:
        subs = self.space.server.iserver.subscription_service
        for sid, sub in list(subs.subscriptions.items()):
            queued = _queued(sub)
            if queued >= self.slow_results:
                await subs.delete_subscriptions([sid])
                self.dropped.append(sid)
                if self.warn is not None:
                    self.warn(f"--opcua: a client is not reading ({queued:,} results queued for subscription {sid}): "
                              f"its subscription is deleted; measuring goes on")

    async def _drain(self) -> None:
        """Wait until every subscription has been sent what was queued for it and its client has
        acknowledged it; at most :data:`DRAIN_S`, and no longer than :data:`DRAIN_IDLE_S` without
        progress (a client that stopped reading)."""
        subs = self.space.server.iserver.subscription_service
        end = time.monotonic() + DRAIN_S
        idle_end, before = time.monotonic() + DRAIN_IDLE_S, None
        while time.monotonic() < min(end, idle_end):
            left = sum(_queued(sub) + len(getattr(sub, "_not_acknowledged_results", ()))
                       for sub in subs.subscriptions.values())  # asyncua 2.1: queued, and sent not acknowledged
            if not left:
                return
            if left != before:
                idle_end, before = time.monotonic() + DRAIN_IDLE_S, left
            await asyncio.sleep(0.02)


def _queued(sub) -> int:
    """The events queued for a subscription and not yet sent (asyncua 2.1's private ``_triggered_events``; 0
    where a later asyncua keeps them elsewhere: the slow-client drop and the drain at close then do nothing,
    they never stop the server)."""
    return sum(len(q) for q in getattr(sub, "_triggered_events", {}).values())
