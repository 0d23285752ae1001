"""A layout's head terms as the forward simulator's physics: ``simulate-log`` draws the head a layout describes.

The terms' parameters map onto the properties of :mod:`metrology.sim.forward.properties` one by one
(the forward simulator computes the readings from them, not from the model's terms): a gain ``k``
is the characteristic ``e = k d`` of the true distance; an incidence response ``c`` (``c2, c4``) is
the bias ``c tan^2(a)`` (``+ c4 tan^4(a)``) of the true incidence angle; a temperature coefficient
is ``rate (T - ref)``; a characteristic ``k d + sum_j c_j P_j(x)`` over the sensor's range is drawn as
a calibration table through it (Legendre polynomials written out here from their definition, 41
knots). A spline characteristic is refused (its knots are not a physical description).
"""

from __future__ import annotations

import numpy as np

__all__ = ["properties_from_terms"]

#: knots of the table a polynomial characteristic is drawn through
TABLE_KNOTS = 41

#: Legendre polynomials P2..P5 of x in [-1, 1] (Bonnet's recursion written out)
_LEGENDRE = {2: lambda x: (3 * x**2 - 1) / 2, 3: lambda x: (5 * x**3 - 3 * x) / 2,
             4: lambda x: (35 * x**4 - 30 * x**2 + 3) / 8, 5: lambda x: (63 * x**5 - 70 * x**3 + 15 * x) / 8}


def properties_from_terms(layout):
    """The :class:`~metrology.sim.forward.HeadProperties` of ``layout``'s head terms, or None without."""
    from metrology.sim.forward import Characteristic, HeadProperties, IncidenceBias, SensorProperty

    terms = layout.effects
    if terms is None:
        return None
    per = {}
    for c in terms.components:
        i = c.sensors[0]
        kw = per.setdefault(i, {})
        lo, hi = (float(v) for v in layout.range_mm[i])
        vals = dict(zip(c.param_names, (float(v) for v in c.values)))
        if c.name == "scale":
            kw["characteristic"] = Characteristic("gain", lo, hi, {"gain": vals["k"]})
        elif c.name == "incidence":
            kw["incidence"] = IncidenceBias("tan_poly", {"coeffs_mm": [vals.get("c_mm", vals.get("c2_mm", 0.0)),
                                                                       vals.get("c4_mm", 0.0)]})
        elif c.name == "drift":
            kw["tempco_mm_per_k"], kw["ref_temp_c"] = vals["rate_mm_per_K"], float(c.ref)
        elif c.name == "nonlinearity":
            if c.order == 0:
                raise ValueError(f"term {c.label}: a spline characteristic cannot be drawn by the simulator; "
                                 f"give a polynomial member (order 3 or 5)")
            if not (np.isfinite(lo) and np.isfinite(hi)):
                raise ValueError(f"term {c.label}: the sensor needs range_mm for its characteristic")
            d = np.linspace(lo, hi, TABLE_KNOTS)
            x = (2 * d - lo - hi) / (hi - lo)
            e = vals.get("k", 0.0) * d + sum(vals[f"c{j}_mm"] * _LEGENDRE[j](x) for j in range(2, c.order + 1))
            kw["characteristic"] = Characteristic("table", lo, hi, {"knots_mm": d.tolist(), "values_mm": e.tolist()})
    return HeadProperties(tuple(SensorProperty(i, **kw) for i, kw in sorted(per.items())))
