"""Where ``metro measure`` writes its per-hole results: one CSV or Parquet file, stdout (CSV),
or a folder mirroring a partitioned log, one file per partition.

Every file is written atomically (a temporary file beside it, renamed on success): a file is
complete or absent. A partitioned output is also resumable: a partition whose file exists was
written whole by an earlier run with the same settings (the folder's ``_metro_measure.json``
says which), so a re-run leaves it as it is and writes the rest; nothing is written twice and
nothing already written is lost. A folder written with other settings is refused.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

__all__ = ["OUT_SUFFIXES", "parquet_options", "TableSink", "PartitionedOutput", "check_out", "is_file_out"]

OUT_SUFFIXES = (".csv", ".parquet")
MANIFEST = "_metro_measure.json"
#: held by the run writing into a folder (created exclusively): two runs at once are refused
LOCK = "_metro_measure.lock"
#: how long a run waits for another run's lock on its output folder before it is refused, s
LOCK_WAIT_S = 5.0


def is_file_out(out) -> bool:
    """Whether ``--out`` names one results file (``.csv``/``.parquet``, not an existing folder, not
    ending in a separator); any other name is a folder, ``out.one`` too."""
    p = Path(out)
    return (p.suffix.lower() in OUT_SUFFIXES and not p.is_dir()
            and not str(out).endswith((os.sep,) + ((os.altsep,) if os.altsep else ())))


def check_out(out, partitioned_input: bool, distributed: bool = False):
    """Refuse, before any work, an output that cannot be written (ValueError, one line). One
    process or Dask alike: a log into one file (or stdout), a partitioned log into a folder."""
    if out is None:
        return None
    p = Path(out)
    if is_file_out(out):
        if not p.resolve().parent.is_dir():
            raise ValueError(f"--out {out}: folder {p.parent} does not exist")
        return p
    if not partitioned_input:
        raise ValueError(f"--out {out}: a folder output mirrors a partitioned Parquet log (a folder); for a single "
                         f"log give a file: {', '.join(OUT_SUFFIXES)}")
    if p.exists() and not p.is_dir():
        raise ValueError(f"--out {out}: exists and is not a folder")
    if not p.resolve().parent.is_dir():
        raise ValueError(f"--out {out}: folder {p.parent} does not exist")
    return p


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return True  # another user's process, or no pid: left alone
    return True


def clear_stale(path: Path) -> None:
    """Remove the temporaries of ``path`` left by a run that was killed (``kill -9``, a power
    cut) while writing it: ``.<name>.<pid>.<random><suffix>`` whose process is gone. A live run's
    temporary is left alone."""
    prefix = f".{path.name}."
    import glob

    for q in path.parent.glob(f"{glob.escape(prefix)}*{glob.escape(path.suffix)}"):
        pid = q.name[len(prefix):].split(".", 1)[0]
        if pid.isdigit() and not _alive(int(pid)):
            try:
                q.unlink()
            except OSError:
                pass


#: the columns a results file keeps Parquet's statistics (each row group's min and max) of: what a reader selects
#: row groups by (when, which cell and panel, which status); a measurement or an id has none (measured: the min and
#: max of the floats and ``hole_id`` cost 0.04-0.05 s of CPU per million holes for a filter nobody pushes down)
STATISTICS = ("time", "cell", "panel", "status")
#: text columns whose values are unique per row: no dictionary (it is built and dropped at every page)
UNIQUE_TEXT = ("hole_id",)


def parquet_options(schema) -> dict:
    """How a results file is encoded, column by column (the table read back is the same whatever the encoding):

    - a dictionary for the text columns with few values (status, reason, cell, ...), not for ``hole_id``
      (:data:`UNIQUE_TEXT`) nor for the numbers (a float of measurements has no repeats: trying a dictionary for it
      costs time for nothing);
    - the floats stored plain, uncompressed (their mantissas are noise: on a 1e6-hole results file zstd on them
      saved 57.6 -> 50.7 MB for 0.29-0.34 -> 0.36-0.49 s of the write's CPU; measure_verdicts_issue49_r3.md);
    - ``time`` (microseconds, rising) delta-encoded, uncompressed: smaller than zstd made it (2.9 against 4.0 MB
      per 1e6 holes) for a third of the CPU; every other column zstd;
    - statistics for :data:`STATISTICS` alone.

    Figures: benchmarks/results/measure_speed_issue49_r6.md."""
    import pyarrow as pa

    text = [f.name for f in schema if (pa.types.is_string(f.type) or pa.types.is_dictionary(f.type))
            and f.name not in UNIQUE_TEXT]
    delta = {f.name: "DELTA_BINARY_PACKED" for f in schema if f.name == "time" and pa.types.is_timestamp(f.type)}
    return {"use_dictionary": text,
            "compression": {f.name: "none" if pa.types.is_floating(f.type) or f.name in delta else "zstd"
                            for f in schema},
            "column_encoding": delta,
            "write_statistics": [n for n in STATISTICS if n in schema.names]}


class TableSink:
    """Batches of one table into one file (``.csv`` or ``.parquet``), or CSV on stdout (``path`` None).

    Use as a context manager: the file appears, whole, only when the block ends without error. Its
    temporary (``.<name>.<pid>.<random><suffix>`` beside it) names the writing process, so the next
    run clears the temporaries of a run that was killed (:func:`clear_stale`).
    """

    def __init__(self, path=None):
        self.path = None if path is None else Path(path)
        self._writer = None
        self._tmp = None
        self._schema = None

    def __enter__(self):
        return self

    def write(self, table) -> None:
        if self._writer is None:
            import pyarrow as pa

            self._schema = table.schema
            parquet = self.path is not None and self.path.suffix.lower() == ".parquet"
            if parquet:
                import pyarrow.parquet as pq
            else:  # pyarrow.csv loaded for a CSV alone
                import pyarrow.csv as pcsv
            if self.path is None:
                self._writer = pcsv.CSVWriter(pa.PythonFile(sys.stdout.buffer, mode="w"), table.schema)
            else:
                clear_stale(self.path)
                fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.{os.getpid()}.", suffix=self.path.suffix,
                                           dir=self.path.parent)
                os.close(fd)
                self._tmp = tmp
                self._writer = (pq.ParquetWriter(tmp, table.schema, **parquet_options(table.schema))
                                if parquet else pcsv.CSVWriter(tmp, table.schema))
        elif table.schema != self._schema:
            table = table.cast(self._schema)
        self._writer.write_table(table)

    def __exit__(self, exc_type, exc, tb):
        if self._writer is not None:
            self._writer.close()
        if self._tmp is not None:
            if exc_type is None:
                mask = os.umask(0)
                os.umask(mask)
                os.chmod(self._tmp, 0o666 & ~mask)
                os.replace(self._tmp, self.path)
            elif os.path.exists(self._tmp):
                os.unlink(self._tmp)
        elif exc_type is None and self.path is not None:
            raise ValueError(f"{self.path}: the log has no rows, nothing to write")
        if self.path is None and exc_type is None:
            sys.stdout.flush()
        return False


class PartitionedOutput:
    """A folder mirroring the log's partitions: ``folder/<partition's relative path>``.

    Parameters
    ----------
    folder : Path
    settings : dict, what the results depend on (tolerance, layout digest, ...), kept in
        ``_metro_measure.json``; a folder written with other settings is refused
    """

    def __init__(self, folder, settings: dict):
        self.folder = Path(folder).resolve()  # workers started in another folder write the same files
        self.settings = settings
        self._created = None  # what begin() made: (folder made?, manifest made?)
        self._earlier = frozenset()  # begin(): the partitions' files there before this run
        manifest = self.folder / MANIFEST
        if manifest.exists():
            old = json.loads(manifest.read_text(encoding="utf-8"))
            if old != settings:
                diff = sorted(k for k in set(old) | set(settings) if old.get(k) != settings.get(k))
                raise ValueError(f"--out {folder}: holds the results of a run with other settings ({', '.join(diff)} "
                                 f"differ): choose another folder or remove it")
        elif self.folder.exists() and any(q.name != LOCK for q in self.folder.iterdir()):  # a run starting: its lock
            raise ValueError(f"--out {folder}: folder is not empty and is not a metro measure output")

    def begin(self) -> None:
        """Create the folder and its manifest (atomically) before any partition is written."""
        from metrology.io.atomic import write_text

        made_folder = not self.folder.exists()
        self.folder.mkdir(parents=True, exist_ok=True)
        self._lock()
        manifest = self.folder / MANIFEST
        made_manifest = not manifest.exists()
        if made_manifest:
            write_text(manifest, json.dumps(self.settings, indent=1, sort_keys=True))
        self._created = (made_folder, made_manifest)
        # the partitions' files already there: written by earlier runs (a temporary is dot-named)
        self._earlier = frozenset(q.relative_to(self.folder).as_posix() for q in self.folder.rglob("*.parquet")
                                  if not q.name.startswith("."))

    def _lock(self) -> None:
        """Hold the folder's lock (created exclusively): another run's is waited for up to
        :data:`LOCK_WAIT_S`, then refused in one line; a lock left by a run killed on this host
        (its process gone) is taken over."""
        import socket
        import time

        lock = self.folder / LOCK
        me = f"pid {os.getpid()} on {socket.gethostname()}"
        start = time.monotonic()
        deadline = start + LOCK_WAIT_S
        held_by = None
        while True:
            try:
                fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
                break
            except FileExistsError:
                try:
                    who = lock.read_text(encoding="utf-8").strip()
                except OSError:
                    who = "?"
                pid, _, host = who.removeprefix("pid ").partition(" on ")
                if host == socket.gethostname() and pid.isdigit() and not _alive(int(pid)):
                    lock.unlink(missing_ok=True)  # a killed run's: nobody holds it
                    continue
                held_by = held_by or who
                if time.monotonic() >= deadline:
                    raise ValueError(f"--out {self.folder}: another run is writing into it ({who}; waited "
                                     f"{LOCK_WAIT_S:g} s; if none is, remove {lock})") from None
                time.sleep(0.2)
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(me)
        self._locked = True
        if held_by is not None:
            self.waited = (time.monotonic() - start, held_by)

    #: ``(seconds, "pid N on HOST")``: the run this one waited for (it ended within :data:`LOCK_WAIT_S`), or None
    waited = None

    def waited_line(self) -> str | None:
        """What a run that waited for another's lock says (None when it did not wait): the folder's partitions that
        run wrote are then kept, not written again."""
        if self.waited is None:
            return None
        s, who = self.waited
        return (f"--out {self.folder}: waited {s:.1f} s for another run writing into it ({who}), which ended; this "
                f"run resumes from what it wrote")

    def release(self) -> None:
        """The run has ended (well or not): let another run write into the folder."""
        if getattr(self, "_locked", False):
            (self.folder / LOCK).unlink(missing_ok=True)
            self._locked = False

    def abort(self) -> None:
        """A run failed: when no partition's file is there (this run wrote none, and no earlier run
        did), remove what :meth:`begin` made (the manifest, the folder and its empty subfolders), so
        a failed run leaves nothing; else leave all for a resume."""
        if self._created is None or not self.folder.is_dir():
            return
        made_folder, made_manifest = self._created
        if any(self.folder.rglob("*.parquet")):
            return
        if made_manifest:
            (self.folder / MANIFEST).unlink(missing_ok=True)
        for d in sorted((q for q in self.folder.rglob("*") if q.is_dir()), key=lambda q: len(q.parts), reverse=True):
            if not any(d.iterdir()):
                d.rmdir()
        if made_folder and not any(self.folder.iterdir()):
            self.folder.rmdir()

    def target(self, relative: str) -> Path:
        rel = Path(relative)
        return self.folder / rel.with_suffix(".parquet")

    def done(self, relative: str) -> bool:
        """Whether the partition's file exists (whole: it is written atomically), by an earlier run or
        by this one's worker that was lost after it (:meth:`earlier` tells which)."""
        return self.target(relative).exists()

    def earlier(self, relative: str) -> bool:
        """Whether an earlier run wrote the partition's file: it was there when :meth:`begin` ran."""
        return self.target(relative).relative_to(self.folder).as_posix() in self._earlier

    def sink(self, relative: str) -> TableSink:
        t = self.target(relative)
        t.parent.mkdir(parents=True, exist_ok=True)
        return TableSink(t)
