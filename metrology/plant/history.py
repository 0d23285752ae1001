"""The event history ``metro measure --opcua`` keeps: the last :data:`HISTORY_EVENTS` events the
Server object emitted (hole results and drift alarms), in memory, read by OPC UA HistoryRead
(``ReadEventDetails`` on the Server object: asyncua's ``Node.read_event_history``).

A client that disconnected and comes back reads the history from the time of the last result it
received (or all of it) and keeps the results whose ``Sequence`` follows its last one: those it
missed, in order. Results older than the history's bound are gone: the first ``Sequence`` the
history returns is then more than one past the client's last, and the results between are named
missing by their numbers.

Each event is kept as the tuple of the fields that change from one event to the next (845 bytes
with its values); the bound is on their number.
"""

from __future__ import annotations

import copy
from collections import deque
from datetime import timezone

__all__ = ["HISTORY_EVENTS", "EventHistory", "history_storage"]

#: events kept (results and alarms): 20 s at 1,000 holes a second, 17 min at 20; 845 bytes a hole
#: result (tracemalloc, 20,000 results: 17 MB; tests/plant/test_history.py bounds it at 1.5 kB)
HISTORY_EVENTS = 20_000
#: the per-event fields a history entry holds beyond an event type's own (BaseEventType's that change)
BASE_FIELDS = ("EventId", "Time", "ReceiveTime", "Message", "Severity", "SourceNode", "SourceName")


class EventHistory:
    """The last ``limit`` events of the Server object: :meth:`keep` each as it is fired,
    :meth:`events` to read them (Event objects, in order)."""

    def __init__(self, limit: int = HISTORY_EVENTS):
        self.limit = int(limit)
        self._kept = deque(maxlen=self.limit)
        self._templates = []  # (generator's event, names of its changing fields)

    def keep(self, gen_event, names) -> None:
        """Keep ``gen_event``'s current values of ``names`` (and :data:`BASE_FIELDS`)."""
        for k, (ev, _) in enumerate(self._templates):
            if ev is gen_event:
                break
        else:
            self._templates.append((gen_event, (*BASE_FIELDS, *names)))
            k = len(self._templates) - 1
        fields = self._templates[k][1]
        self._kept.append((k, tuple(getattr(gen_event, n) for n in fields)))

    def events(self, start=None, end=None, count: int = 0) -> list:
        """The kept events with ``start <= Time <= end`` (None or 1601-01-01: no bound), oldest first
        (newest first when ``start`` is after ``end``, as OPC UA Part 11 reads backwards), at most
        ``count`` (0: all)."""
        lo, hi = _bound(start), _bound(end)
        backwards = lo is not None and hi is not None and lo > hi
        if backwards:
            lo, hi = hi, lo
        out = []
        kept = reversed(self._kept) if backwards or (lo is None and hi is not None) else self._kept
        for k, values in kept:
            ev, names = self._templates[k]
            t = values[1]
            if (lo is not None and t < lo) or (hi is not None and t > hi):
                continue
            e = copy.copy(ev)
            for n, v in zip(names, values):
                setattr(e, n, v)
            out.append(e)
            if count and len(out) >= count:
                break
        return out


def _bound(t):
    """A HistoryRead time bound as an aware UTC datetime; None for none (1601-01-01: OPC UA's null)."""
    if t is None:
        return None
    if t.tzinfo is None:
        t = t.replace(tzinfo=timezone.utc)
    return None if t.year <= 1601 else t


def history_storage(history: EventHistory, server_id):
    """An asyncua history storage answering HistoryRead of events on the Server object from
    ``history`` (and nothing else: no node's value is historized)."""
    from asyncua.server.history import HistoryDict

    class Storage(HistoryDict):
        async def read_event_history(self, source_id, start, end, nb_values, evfilter):
            if source_id != server_id:
                return [], None
            return history.events(start, end, nb_values), None

    return Storage(max_history_data_response_size=history.limit)
