"""What ``metro measure`` gives the plant besides its files: the per-hole results as a Q-DAS DFQ file
(``--dfq``, :mod:`metrology.io.dfq`) and, live, on an OPC UA server (``--opcua``,
:mod:`metrology.plant`). The measure jobs call these; the formats live in their modules."""

from __future__ import annotations

from pathlib import Path

__all__ = ["dfq_sink", "docs_from_output", "opcua_server"]


def dfq_sink(dfq, tolerance_deg: float, layout_path, points, surfaces, log_display: str):
    """The ``--dfq`` writer (None without it): one characteristic per hole of the hole table
    (``surfaces.ids``, in its order) where one is known, else one for the log."""
    if dfq is None:
        return None
    from metrology.io.dfq import DfqHoles

    features = None if surfaces is None else tuple(surfaces.ids)
    part = Path(points).stem if points is not None else "holes"
    return DfqHoles(dfq, tolerance_deg=tolerance_deg, layout_path=layout_path, features=features, part=part,
                    log=log_display)


#: the per-hole result columns the documents are made from (``cell`` where the log has one)
DOC_COLUMNS = ("hole_id", "angle_deg", "U95_angle_deg", "angle_after_deg", "U95_after_deg", "status", "time")


def docs_from_output(docs, output, log, sinks=()) -> None:
    """Write each of ``docs`` (QIF, DFQ: context managers with ``write(table)``) and ``sinks`` (open
    already: the OPC UA server) from a partitioned output's files, row group by row group, in the
    log's order (whoever wrote them)."""
    import contextlib

    import pyarrow.parquet as pq

    docs = [d for d in docs if d is not None]
    sinks = [s for s in sinks if s is not None]
    if not docs and not sinks:
        return
    with contextlib.ExitStack() as stack:
        for d in docs:
            stack.enter_context(d)
        for part in log.partitions:
            pf = pq.ParquetFile(output.target(part.relative), pre_buffer=False)
            cols = [c for c in (*DOC_COLUMNS, "cell", "point_id", "correction_deg") if c in pf.schema_arrow.names]
            for g in range(pf.num_row_groups):
                table = pf.read_row_group(g, columns=cols, use_threads=False)
                if "cell" not in cols and "cell" in part.keys:
                    import pyarrow as pa

                    table = table.append_column("cell", pa.array([str(part.keys["cell"])] * table.num_rows))
                for d in (*docs, *sinks):
                    d.write(table)



def opcua_server(url: str, tolerance_deg: float, layout_path, cert=None, key=None, users=None, warn=None,
                 slow_results: int | None = None):
    """The ``--opcua`` server (:class:`metrology.plant.server.PlantServer`, not started: enter it),
    serving the calibration in use: the layout's SHA-256, file name and ``[certificate]`` fields.
    ValueError (one line) for an endpoint it must refuse, or without asyncua (the ``plant`` extra)."""
    from metrology.io.layout import load_layout
    from metrology.io.names import display_name, sha256_file

    try:
        import asyncua  # noqa: F401 - the plant extra
    except ImportError:
        raise ValueError("--opcua needs the plant extra: pip install 'metro[plant]' (asyncua)") from None
    from metrology.plant.server import PlantServer

    layout = load_layout(layout_path)
    calibration = {"sha256": sha256_file(layout_path), "file": display_name(layout_path),
                   "certificate": dict(layout.certificate or {})}
    kw = {} if slow_results is None else {"slow_results": slow_results}
    if slow_results is not None and slow_results < 1:
        raise ValueError(f"--opcua-queue must be 1 or more, got {slow_results}")
    return PlantServer(url, tolerance_deg=tolerance_deg, calibration=calibration, cert=cert, key=key, users=users,
                       warn=warn, **kw)
