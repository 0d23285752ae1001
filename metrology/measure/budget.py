"""A hole's uncertainty budget: its tilt and the tilt's covariance split by named sources, and the one
function that turns it into the angle, its U95 and each source's share.

Both fitters (:func:`metrology.measure.normals.hole_normals`, the micro-plane, and
:func:`metrology.measure.surface.surface_hole_normals`, the panel's local surface known) return a
:class:`Budget`; :func:`combine` is the only place where the rules that make an angle's U95 live:

- far from ``alpha = 0``: the angle's standard uncertainty ``u = sqrt(sum_j u_j^2)``, ``u_j^2 = c^T C_j c``
  for a normal source (``c = d alpha / d g``), ``a_j^2 / 3`` for a bounded one (half-width ``a_j`` along
  the angle, rectangular: GUM 4.3.7); ``U95 = K95 u`` (the linear rule), or, with a spread within ``+-a``
  (:attr:`Kind.UNIFORM`: the head's spin read; :attr:`Kind.ARCSINE`; :attr:`Kind.EDGE`: any distribution, the
  head's spin on the convention's bound), the 95 % half-width of a normal plus that spread (its variance
  ``a^2 / 3``, ``a^2 / 2``, ``a^2``: :func:`metrology.measure.magnitude.normal_spread_u95`);
- near ``alpha = 0`` (below :data:`SMALL_ANGLE_SIGMAS` standard deviations) the angle is the length of
  the 2-D tilt, not normal: ``u`` is the tilt's major-axis standard deviation and U95 the half-width
  holding 95 % of its length (Rice and its anisotropic generalisation,
  :func:`metrology.measure.magnitude.magnitude_u95`), up to ``X_MAX`` major-axis standard deviations; a
  hole whose budget holds a :attr:`Kind.BOUND` (a worst case over panels, not a distribution) takes the
  half-width only where ``u`` was the 2-D spread's (beyond, the bound's exact worst case along the angle
  stays in ``u``).

**Adding a source** is one :class:`Source` in the tuple a fitter (or a later model: the layout's
effect terms, a tight radius' truncation) builds, ``budget.with_source(Source("name", cov))``: the
combiner reads every entry; nothing in it names a source.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from enum import StrEnum

import numpy as np

from metrology.core.sym2 import eig2
from metrology.measure.magnitude import K95, SPREAD_VARIANCE, X_MAX, magnitude_u95, normal_spread_u95

__all__ = ["Kind", "Source", "Budget", "Uncertainty", "combine", "angle_gradient", "SMALL_ANGLE_SIGMAS", "READING_NOISE",
           "CALIBRATION", "DATUM", "PANEL_SHAPE", "SPIN", "SPIN_READ", "CURVATURE",
           "SURFACE_MODEL"]

#: below this many standard uncertainties the angle's distribution is not close to normal (it is the
#: length of a 2-D vector): u is the 2-D spread's major axis (and with a bound, U95 the length's half-width)
SMALL_ANGLE_SIGMAS = 4.0

#: the sources metro's fitters name (a source's name is free: these are the ones the report knows)
READING_NOISE = "reading noise"
CALIBRATION = "calibration"
DATUM = "datum"
PANEL_SHAPE = "panel shape"
SPIN = "spin"
#: the head's spin where it was read from the redundant reading (its estimate's doubt: uniform, not the bound's shape)
SPIN_READ = "spin read"
CURVATURE = "curvature"
#: what the panel's local surface model leaves over a footprint large against the radius (truncation, faceting,
#: the drill point's position error: :mod:`metrology.measure.remainder`)
SURFACE_MODEL = "surface model"


class Kind(StrEnum):
    """How a source's error is distributed."""

    NORMAL = "normal"  # Gaussian, of covariance ``cov``
    UNIFORM = "uniform"  # uniform within +-half_width along the angle (the head's spin read): normal-plus-uniform U95
    ARCSINE = "arcsine"  # a sine between +-half_width (U-shaped: JCGM 101 6.4.6): normal-plus-arcsine U95
    EDGE = "edge"  # within +-half_width, any distribution: its worst case (at a bound), variance half_width^2
    BOUND = "bound"  # a worst case over what is not known (the micro-plane's panel curvature): rectangular in u


@dataclass(frozen=True)
class Source:
    """One named source of the tilt's error, over ``N`` holes.

    Attributes
    ----------
    name : str, what the report names it by (unique within a budget)
    cov : (N, 3) float, (slope)^2, the covariance it adds to the tilt ``g`` as its entries ``(00, 01, 11)``
        (for a :attr:`Kind.BOUND` or :attr:`Kind.UNIFORM` source the 2-D spread of the same variance)
    kind : Kind
    half_width : (N,) float, rad, or None: a :attr:`Kind.UNIFORM` or :attr:`Kind.BOUND` source's half-width
        along the angle (its variance ``half_width^2 / 3``); None for a normal one
    """

    name: str
    cov: np.ndarray
    kind: Kind = Kind.NORMAL
    half_width: np.ndarray | None = None

    def rows(self, r) -> "Source":
        return replace(self, cov=self.cov[r], half_width=None if self.half_width is None else self.half_width[r])


@dataclass(frozen=True)
class Budget:
    """The tilts of ``N`` holes and their covariance split by source.

    Attributes
    ----------
    tilt : (N, 2) float, the slopes ``g = (g_x, g_y)`` of the normal in the TCS (``alpha = atan |g|``)
    sources : tuple of :class:`Source`, in the order they were added (the combiner sums in that order)
    combined : Uncertainty or None, what :func:`combine` made of this budget, kept by the fitter that made both
        (:func:`combine` returns it rather than combine again; a budget with another source is a new one, without)
    """

    tilt: np.ndarray
    sources: tuple
    combined: "Uncertainty | None" = field(default=None, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.tilt)

    @property
    def names(self) -> tuple:
        return tuple(s.name for s in self.sources)

    def source(self, name: str) -> Source:
        for s in self.sources:
            if s.name == name:
                return s
        raise KeyError(f"no source {name!r} in the budget (it has {', '.join(self.names)})")

    def with_source(self, source: Source) -> "Budget":
        """A copy with ``source`` added (a name already there raises: two sources, two names)."""
        if source.name in self.names:
            raise ValueError(f"the budget already has a source {source.name!r}")
        if source.cov.shape != (len(self), 3):
            raise ValueError(f"source {source.name!r}: cov of shape {source.cov.shape}, the budget needs {(len(self), 3)}")
        return Budget(self.tilt, self.sources + (source,))

    @staticmethod
    def concat(budgets) -> "Budget":
        """The holes of ``budgets`` (of the same sources, in order) one after the other."""
        first = budgets[0]
        if len(budgets) == 1:
            return first
        combined = None if any(b.combined is None for b in budgets) else Uncertainty.concat([b.combined for b in budgets])
        return Budget(np.concatenate([b.tilt for b in budgets]),
                      tuple(Source(s.name, np.concatenate([b.sources[j].cov for b in budgets]), s.kind,
                                   None if s.half_width is None else np.concatenate([b.sources[j].half_width for b in budgets]))
                            for j, s in enumerate(first.sources)), combined)

    def rows(self, r) -> "Budget":
        """The holes ``r`` (an index)."""
        return Budget(self.tilt[r], tuple(s.rows(r) for s in self.sources),
                      None if self.combined is None else self.combined.rows(r))

    @property
    def cov(self) -> np.ndarray:
        """(N, 3) float, (slope)^2: the tilt's whole covariance, ``(00, 01, 11)``."""
        out = self.sources[0].cov.copy()
        for s in self.sources[1:]:
            out += s.cov
        return out


@dataclass(frozen=True)
class Uncertainty:
    """What :func:`combine` makes of a :class:`Budget`.

    Attributes
    ----------
    angle : (N,) float, rad, ``atan |g|``
    u : (N,) float, rad, the angle's standard uncertainty (near 0: the tilt's major-axis one)
    U95 : (N,) float, rad, the expanded uncertainty (95 %)
    names : tuple of str, the budget's sources
    share : (N, k) float, rad, each source's standard uncertainty along the angle (``u_j``, column j the
        source ``names[j]``: ``sum_j u_j^2`` is ``u^2`` away from 0)
    """

    angle: np.ndarray
    u: np.ndarray
    U95: np.ndarray
    names: tuple
    share: np.ndarray

    def of(self, name: str) -> np.ndarray:
        """(N,) float, rad: the share of the source ``name``."""
        return self.share[:, self.names.index(name)]

    @staticmethod
    def concat(parts) -> "Uncertainty":
        """The holes of ``parts`` (of the same sources) one after the other (each hole's combination is its own)."""
        return Uncertainty(*(np.concatenate([getattr(p, f) for p in parts]) for f in ("angle", "u", "U95")),
                           parts[0].names, np.concatenate([p.share for p in parts]))

    def rows(self, r) -> "Uncertainty":
        """The holes ``r`` (an index)."""
        return Uncertainty(self.angle[r], self.u[r], self.U95[r], self.names, self.share[r])


def angle_gradient(gx, gy, gn=None, g2=None):
    """``(c_x, c_y)``, (N,) each: ``d alpha / d g = g / (|g| (1 + |g|^2))`` of the tilts ``g`` (0 at ``g = 0``);
    ``gn = |g|`` and ``g2 = |g|^2`` where the caller has them."""
    if g2 is None:
        g2 = gx * gx + gy * gy
        gn = np.sqrt(g2)
    with np.errstate(invalid="ignore", divide="ignore"):
        k = 1.0 / (gn * (1.0 + g2))
    k = np.where(np.isfinite(k), k, 0.0)
    return gx * k, gy * k


def _summed(sources, k):
    """(N,) the entry ``k`` of the sources' covariances summed in their order."""
    out = sources[0].cov[:, k].copy()
    for s in sources[1:]:
        out += s.cov[:, k]
    return out


def combine(budget: Budget) -> Uncertainty:
    """The angle, its standard and expanded (95 %) uncertainty and each source's share (the module docstring).

    Parameters
    ----------
    budget : Budget of N holes

    Returns
    -------
    Uncertainty (``budget.combined`` where the budget has it: the same numbers, not made twice)
    """
    if budget.combined is not None:
        return budget.combined
    g = budget.tilt
    gx, gy = np.ascontiguousarray(g[:, 0]), np.ascontiguousarray(g[:, 1])
    g2 = gx * gx + gy * gy
    gn = np.sqrt(g2)
    angle = np.arctan(gn)
    cx, cy = angle_gradient(gx, gy, gn, g2)
    cxx, cxy, cyy = cx * cx, 2 * cx * cy, cy * cy  # c^T C c = cxx C_00 + cxy C_01 + cyy C_11, for every source
    N = len(g)
    share2 = []  # (N,) each, rad^2: each source's variance along the angle
    spreads = {}  # Kind -> (N,) rad, the half-widths of the spreads within bounds
    bounded = np.zeros(N, bool)
    for s in budget.sources:
        if s.kind is Kind.NORMAL:
            C = s.cov
            share2.append(cxx * C[:, 0] + cxy * C[:, 1] + cyy * C[:, 2])
        else:
            share2.append(s.half_width ** 2 * (1.0 / 3.0 if s.kind is Kind.BOUND else SPREAD_VARIANCE[s.kind.value]))
            if s.kind is Kind.BOUND:
                bounded |= s.half_width > 0
            else:
                spreads[s.kind] = spreads.get(s.kind, 0.0) + s.half_width
    var = share2[0].copy()
    for v in share2[1:]:
        var += v
    u = np.sqrt(var)
    U95 = K95 * u
    if spreads:
        # a spread within bounds: the 95 % half-width of the normal plus the spread, the bounds of every spread added
        # and taken as the widest shape present (edge, then arcsine, then uniform: the safe side where a hole has several)
        a = sum(spreads.values(), np.zeros(N))
        rest = np.sqrt(np.maximum(var - sum(h ** 2 * SPREAD_VARIANCE[k.value] for k, h in spreads.items()), 0.0))
        done = np.zeros(N, bool)
        for kind in (Kind.EDGE, Kind.ARCSINE, Kind.UNIFORM):
            take = ~done & (spreads[kind] > 0) if kind in spreads else done & False
            if take.any():
                U95[take] = normal_spread_u95(rest[take], a[take], kind.value)
                done |= take
    # near 0 the angle is the length of the 2-D tilt (metrology.measure.magnitude): its covariance in angle (rad^2),
    # the sources summed in order entry by entry (as Budget.cov)
    scale = (1.0 + g2) ** 2
    c00, c01, c11 = (_summed(budget.sources, k) / scale for k in range(3))
    s2d = np.sqrt(eig2(c00, c01, c11)[0])  # rad: the major axis's standard deviation
    still = (angle < SMALL_ANGLE_SIGMAS * 2.0 * u) & (angle < SMALL_ANGLE_SIGMAS * s2d)
    u[still] = s2d[still]
    near = np.where(bounded, still, angle < X_MAX * s2d)
    if np.any(near):
        with np.errstate(invalid="ignore", divide="ignore"):
            tilt = g[near] * np.where(gn[near] > 0, angle[near] / gn[near], 1.0)[:, None]  # rad, length = angle
        Ca = np.empty((int(near.sum()), 2, 2))
        Ca[:, 0, 0], Ca[:, 0, 1], Ca[:, 1, 1] = c00[near], c01[near], c11[near]
        Ca[:, 1, 0] = Ca[:, 0, 1]
        U95[near] = magnitude_u95(tilt, Ca)
    share2 = np.stack(share2, axis=1)
    return Uncertainty(angle, u, U95, budget.names, np.sqrt(share2))
