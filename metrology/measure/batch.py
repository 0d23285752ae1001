"""What a measured batch of holes is: the typed contract between :mod:`metrology.measure.holes`
(which makes it), the summary, the drift watch and the writers (:class:`HoleBatch`,
:class:`ChartRows`), and the one mapping between a hole's status and its code."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import pyarrow as pa

__all__ = ["Status", "STATUSES", "CODE", "ChartRows", "Labels", "HoleBatch", "blanked"]


class Status(StrEnum):
    CONFORMS = "conforms"
    FAILS = "fails"
    UNDECIDED = "undecided"
    NOT_MEASURED = "not_measured"


#: the one mapping between a hole's status and its code (``HoleBatch.status``): code ``i`` is ``STATUSES[i]``
STATUSES = tuple(Status)
#: each status's code
CODE = {s: i for i, s in enumerate(STATUSES)}


def blanked(mask, *arrays) -> tuple:
    """``arrays`` (N,) float with NaN where ``mask`` (N,) bool: a hole not measured carries no judged
    figure in any output (its angle and U95 blank; issue 51), whatever its reason."""
    return tuple(np.where(mask, np.nan, a) if mask.any() else a for a in arrays)


@dataclass(frozen=True)
class ChartRows:
    """What the drift chart takes of a batch: its holes measured on all 4 sensors of a 4-sensor head.

    Attributes
    ----------
    index : (m,) int, their rows in the batch
    rho_mm : (m,) float, mm, the redundant reading's misfit
    noise_sd_mm : (m,) float, mm, its sigma from the reading noise
    signature : (m, 4) float, mm per mm, ``d rho / d delta_k`` of each sensor's zero
    """

    index: np.ndarray
    rho_mm: np.ndarray
    noise_sd_mm: np.ndarray
    signature: np.ndarray


@dataclass(frozen=True)
class Labels:
    """A text column with few values (the cell, the panel) by its dictionary: made once per batch, read
    by the summary and the drift watch alike (encoding it costs a hash of every row's text).

    Attributes
    ----------
    codes : (N,) int64, each row's value as its index in ``values``
    values : list of str
    """

    codes: np.ndarray
    values: list

    @staticmethod
    def concat(parts) -> Labels:
        """The labels of ``parts`` one after the other, on one dictionary (each part's codes mapped into it)."""
        at, codes = {}, []
        for p in parts:
            to = np.array([at.setdefault(v, len(at)) for v in p.values], np.int64)
            codes.append(to[p.codes] if len(to) else p.codes.astype(np.int64))
        return Labels(np.concatenate(codes), list(at))


@dataclass(frozen=True)
class HoleBatch:
    """A batch measured.

    Attributes
    ----------
    columns : pyarrow.Table: :data:`OUTPUT_COLUMNS` (angles in deg, the residual in µm: the
        file's units) then the log's other columns (not the readings), in the log's row order
    status : (N,) int8, each hole's :class:`Status` as its code (:data:`CODE`, :data:`STATUSES`)
    judged : (N,) float, rad, the angle the verdict judged (NaN where not measured)
    judged_u95 : (N,) float, rad
    angle_before, angle_after : (N,) float, rad (NaN where not measured / no after-readings)
    disagree : (N,) bool, holes whose readings disagree (rule 2), before or after the adjustment
    unknown_after : (N,) bool, holes not measured after the adjustment whose before-readings do not rule
        out a wrong turn of the cell (rule 3's; before-readings gross or too few): their drilled angle is not
        known, and may be out of tolerance
    chart : ChartRows, what the drift chart takes of the batch
    spin_free : (N,) bool or None, with the panel known: judged with a U95 over every spin of the head (its
        spin not known: :mod:`metrology.measure.spin`)
    on_convention : (N,) bool or None, with the panel known: judged with the head's spin taken from the cell's
        convention (no pose in the log)
    cell, panel : Labels, each hole's cell and panel
    spin_bound : (N,) bool or None, with the panel known: holes whose readings (before the adjustment, or the
        judged after) rest on the spin's bound, the spin not read and its bound over
        :data:`metrology.measure.spin.SPIN_BOUND_SHARE` of U95^2 (as their reason says)
    one_sensor : (N,) bool or None, without the panel: judged with rule 2b's U95, which covers one sensor's offset
        (:data:`metrology.measure.rules.EDGE_SIGMAS`)
    spin_alias : (N,) bool or None, with the panel known: holes whose readings (before the adjustment, or the
        after-readings judged) the convention's alias spin sent to every spin, their reason says so (the convention
        not stated: :data:`metrology.measure.spin.SPIN_ALIAS_SHARE`)
    """

    columns: "pa.Table"
    status: np.ndarray
    judged: np.ndarray
    judged_u95: np.ndarray
    angle_before: np.ndarray
    angle_after: np.ndarray
    chart: "ChartRows"
    disagree: np.ndarray | None = None
    unknown_after: np.ndarray | None = None
    spin_free: np.ndarray | None = None
    on_convention: np.ndarray | None = None
    cell: Labels | None = None
    panel: Labels | None = None
    spin_bound: np.ndarray | None = None
    one_sensor: np.ndarray | None = None
    spin_alias: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.status)
