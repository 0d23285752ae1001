"""What ``metro measure`` gives the plant besides its files: the per-hole results as a Q-DAS DFQ file
(``--dfq``, :mod:`metrology.io.dfq`) and, live, on an OPC UA server (``--opcua``,
:mod:`metrology.plant`). The measure jobs call these; the formats live in their modules."""

from __future__ import annotations

from pathlib import Path

__all__ = ["dfq_sink", "docs_from_output"]


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


def docs_from_output(docs, output, log) -> None:
    """Write each of ``docs`` (QIF, DFQ: context managers with ``write(table)``) from a partitioned
    output's files, row group by row group, in the log's order (whoever wrote them)."""
    import contextlib

    import pyarrow.parquet as pq

    docs = [d for d in docs if d is not None]
    if not docs:
        return
    with contextlib.ExitStack() as stack:
        for d in docs:
            stack.enter_context(d)
        for part in log.partitions:
            pf = pq.ParquetFile(output.target(part.relative), pre_buffer=False)
            cols = [c for c in (*DOC_COLUMNS, "cell", "point_id") if c in pf.schema_arrow.names]
            for g in range(pf.num_row_groups):
                table = pf.read_row_group(g, columns=cols, use_threads=False)
                if "cell" not in cols and "cell" in part.keys:
                    import pyarrow as pa

                    table = table.append_column("cell", pa.array([str(part.keys["cell"])] * table.num_rows))
                for d in docs:
                    d.write(table)

