"""One normals run over a panel's drilling points: micro-plane against micro-sphere, per point and in summary."""

from __future__ import annotations

import math
from dataclasses import dataclass
import numpy as np
from metrology.core.layout import SensorLayout
from metrology.core.normals import angle_between
from metrology.core.progress import ProgressFn, notify
from metrology.core.sphere import SPHERE_PRIOR_RADIUS_MM
from metrology.panel.attitude import MotionError, _beam_detail, _normal_from, _readings, attitude_loop
from metrology.panel.edges import footprint_radius, straddle
from metrology.panel.head import MAX_TILT, cast_beams, default_standoff, orientation_from_feed, place_head, tilted_feed, tool_axis_tcs
from metrology.panel.mesh import CREASE_ANGLE_DEG, ON_PANEL_MM, Panel
from metrology.panel.points import DrillPoints, snap_points
from metrology.panel.rays import RayCaster


@dataclass
class NormalsRun:
    """Per-point results of :func:`run_normals`; arrays of length m unless stated.

    Attributes
    ----------
    labels : tuple of str
    points : (m, 3) float, mm, panel frame, drilling points on the panel
    status : (m,) str, a key of :data:`STATUS`
    off_mm : (m,) float, mm, distance of the given point from the panel
    n_true : (m, 3) float, unit, panel frame, the mesh's reference normal (the face hit,
        smoothed within :data:`CREASE_ANGLE_DEG`), out
    n_analytic : (m, 3) float or None, unit, panel frame, for generated panels (analytic) and
        STEP panels when OCP is installed (the B-rep's face normal)
    n_plane, n_sphere : (m, 3) float, unit, panel frame, out; NaN unless status ok
    err_plane, err_sphere : (m,) float, rad, angle to the reference normal (:attr:`n_ref`)
    sphere_radius : (m,) float, mm, inf where the sphere degraded to the plane
    readings : (m, n) float, mm
    initial_tilt : (m,) float, rad, true deviation of the initial tool axis
    loop : dict method -> dict of arrays (see :func:`attitude_loop`), or empty
    engine : str; info : dict of run settings
    detail : (m,) str, why a point was not measured (which beams, how far off), '' if ok
    """

    labels: tuple
    points: np.ndarray
    status: np.ndarray
    off_mm: np.ndarray
    n_true: np.ndarray
    n_analytic: np.ndarray | None
    n_plane: np.ndarray
    n_sphere: np.ndarray
    err_plane: np.ndarray
    err_sphere: np.ndarray
    sphere_radius: np.ndarray
    readings: np.ndarray
    initial_tilt: np.ndarray
    loop: dict
    engine: str
    info: dict
    detail: np.ndarray

    @property
    def n_ref(self):
        """The reference normal: analytic where known, else the mesh's (crease-limited) one."""
        return self.n_analytic if self.n_analytic is not None else self.n_true


def run_normals(panel: Panel, layout: SensorLayout, drill: DrillPoints, rng, *, tilt=math.radians(1.0),
                standoff=None, noise=None, tolerance=math.radians(0.5), engine="auto",
                motion: MotionError = MotionError(), layout_true: SensorLayout | None = None,
                loop=True, caster: RayCaster | None = None,
                prior_radius_mm=SPHERE_PRIOR_RADIUS_MM, footprint_mm=None, progress: ProgressFn | None = None,
                beams: str = "facets", reading_offsets=None) -> NormalsRun:
    """Measure the normal at each drilling point by both methods, and run the attitude loop.

    Parameters
    ----------
    panel : Panel
    layout : SensorLayout, used to compute the normals (nominal or calibrated)
    drill : DrillPoints
    rng : numpy.random.Generator, the only source of randomness
    tilt : float, rad, attitude error of the initial tool axis (random azimuth)
    standoff : float, mm, or None for :func:`default_standoff`
    noise : (n,) or scalar float, mm, reading noise 1 sigma; None: the layout's ``noise_mm``
        (0 where not stated)
    tolerance : float, rad, of the attitude loop
    engine : {"auto", "trimesh", "embree", "open3d"}
    motion : MotionError
    layout_true : SensorLayout, the head as it really is (default ``layout``)
    loop : bool, run the attitude loop
    caster : RayCaster, to reuse a built scene (its mesh must be ``panel.mesh``)
    prior_radius_mm : float, mm, the micro-sphere's curvature prior (see
        :func:`fit_algebraic_sphere`); inf for the exact interpolating sphere
    footprint_mm : float, mm, radius of the head's footprint (the pressure foot); None: the
        spots' (:func:`metrology.panel.edges.footprint_radius`). A point whose footprint, or
        the disc out to its farthest spot, holds a crease, a hole or the panel's outline is
        not measured (:func:`metrology.panel.edges.straddle`)
    progress : callable or None, ``progress(done, total, what)`` at each of the 4 stages
        (:mod:`metrology.core.progress`)
    beams : str, what the simulated beams hit: ``"facets"``, the mesh as it is, or
        ``"smooth"``, the smooth surface it tessellates (:class:`metrology.panel.smooth.SmoothCaster`)
    reading_offsets : callable or None, the true head's terms: ``(d_true (m, n) mm, incidence (m, n)
        rad) -> (m, n) mm`` added to the distances (:mod:`metrology.panel.head_terms`); needed when
        ``layout_true`` carries terms. ``layout``'s terms are removed before each normal

    Returns
    -------
    NormalsRun
    """
    layout_true = layout if layout_true is None else layout_true
    if layout_true.effects is not None and reading_offsets is None:
        raise ValueError("the true head has effect terms: give reading_offsets, their physics (metro normals takes "
                         "them from the forward simulator)")
    if layout_true.n != layout.n:
        raise ValueError(f"true and estimating layouts differ in sensor count ({layout_true.n} vs {layout.n})")
    if layout.n < 3:
        raise ValueError(f"a layout needs at least 3 sensors, got {layout.n}")
    if not (0 <= tilt < MAX_TILT):
        raise ValueError(f"tilt must be in [0, {math.degrees(MAX_TILT):g}) deg, got {math.degrees(tilt):g} deg")
    if not (tolerance > 0 and math.isfinite(tolerance)):
        raise ValueError(f"tolerance must be a positive angle, got {tolerance}")
    if not prior_radius_mm > 0:
        raise ValueError(f"the micro-sphere's prior radius must be > 0 mm (inf: no prior), got {prior_radius_mm}")
    a_tcs = tool_axis_tcs(layout)
    if not np.array_equal(tool_axis_tcs(layout_true), a_tcs):
        raise ValueError(f"the true layout's beams point {tool_axis_tcs(layout_true)[2]:+.0f}z, the layout's "
                         f"{a_tcs[2]:+.0f}z: they are not the same head")
    standoff = default_standoff(layout) if standoff is None else float(standoff)
    if not (math.isfinite(standoff) and standoff > 0):
        raise ValueError(f"stand-off must be a positive number of mm, got {standoff}")
    if noise is None:
        noise = np.nan_to_num(layout_true.noise_mm, nan=0.0)
    noise = np.broadcast_to(np.asarray(noise, float), (layout.n,)).copy()
    if np.any(~np.isfinite(noise)) or np.any(noise < 0):
        raise ValueError(f"reading noise must be finite and >= 0 mm, got {noise.tolist()}")
    foot = footprint_radius(layout, standoff) if footprint_mm is None else float(footprint_mm)
    if not (math.isfinite(foot) and foot >= 0):
        raise ValueError(f"footprint radius must be a finite number of mm >= 0, got {footprint_mm}")
    caster = RayCaster(panel.mesh, engine) if caster is None else caster
    if beams not in ("facets", "smooth"):
        raise ValueError(f"beams must be facets or smooth, got {beams!r}")
    if beams == "smooth":
        from metrology.panel.smooth import SmoothCaster

        caster = SmoothCaster(caster, panel)
    m = len(drill.points)
    notify(progress, 0, 4, f"snapping {m} points to the panel")
    pts, off, n_true, faceting, chord = snap_points(panel, caster, drill.points)
    status = np.full(m, "ok", dtype=object)
    status[off > ON_PANEL_MM] = "off_panel"
    has_app = np.all(np.isfinite(drill.approach), axis=1)
    behind_app = has_app & (np.sum(drill.approach * n_true, axis=1) >= 0)
    status[(status == "ok") & behind_app] = "approach_behind"
    n_an = panel.surface.normal(pts) if panel.surface is not None else None
    if n_an is not None:  # a B-rep face's orientation is its own: the outside is the mesh's
        n_an *= np.where(np.sum(n_an * n_true, axis=1) < 0, -1.0, 1.0)[:, None]
    n_ref = n_an if n_an is not None else n_true
    # initial feed: the approach direction where given, else the inward normal; tilted
    base = np.where(has_app[:, None], -drill.approach, n_ref)
    feed = tilted_feed(base, tilt, rng)
    R0 = orientation_from_feed(feed, a_tcs)
    T0 = place_head(pts, R0, a_tcs, layout, standoff)
    rng_read, rng_loop_p, rng_loop_s = rng.spawn(3)
    notify(progress, 1, 4, f"readings and both normals at {m} points")
    # both methods see the same noisy readings at the first pose
    d, miss_b, beh_b, oor_b, tri_b = _readings(caster, layout_true, R0, T0, noise, rng_read, reading_offsets)
    miss, beh, oor = np.any(miss_b, axis=1), np.any(beh_b, axis=1), np.any(oor_b, axis=1)
    n_plane, _ = _normal_from(layout, a_tcs, R0, d, "plane")
    n_sphere, rad = _normal_from(layout, a_tcs, R0, d, "sphere", float(np.mean(noise)), prior_radius_mm)
    edge_status, edge_detail = _edge_check(panel, caster, layout_true, R0, T0, pts, n_true, foot, status == "ok",
                                           np.where(beh_b, -1, tri_b))
    status[edge_status != ""] = edge_status[edge_status != ""]
    for flag, name in ((oor, "out_of_range"), (beh, "beam_behind"), (miss, "beam_miss")):
        status[(status == "ok") & flag] = name
    good = status == "ok"
    detail = np.array(_beam_detail(layout_true.names, miss_b, beh_b, oor_b), dtype=object)
    on_edge = edge_status != ""
    detail[on_edge] = [e + ("; " + b if b else "") for e, b in zip(edge_detail[on_edge], detail[on_edge])]
    detail[status == "off_panel"] = np.char.mod("%.3f mm from the panel", off[status == "off_panel"]).astype(object)
    detail[status == "approach_behind"] = "approach direction points out of the panel"
    detail[good] = ""
    n_plane[~good] = np.nan
    n_sphere[~good] = np.nan
    rad[~good] = np.nan
    err_p = np.where(good, angle_between(n_plane, n_ref, oriented=True), np.nan)
    err_s = np.where(good, angle_between(n_sphere, n_ref, oriented=True), np.nan)
    init_tilt = angle_between(R0 @ a_tcs, -n_ref, oriented=True)
    loops = {}
    if loop and np.any(good):
        for k, (method, r) in enumerate((("plane", rng_loop_p), ("sphere", rng_loop_s))):
            notify(progress, 2 + k, 4, f"attitude loop, micro-{method}, {int(np.sum(good))} points")
            res = attitude_loop(caster, panel, layout_true, layout, pts[good], R0[good], standoff, noise, r,
                                method, tolerance, motion, prior_radius_mm=prior_radius_mm, offsets=reading_offsets)
            full = {}
            for k, v in res.items():
                arr = np.full(m, np.nan) if v.dtype.kind == "f" else np.zeros(m, v.dtype)
                if v.dtype.kind == "i":
                    arr = np.full(m, -1, int)
                arr[good] = v
                full[k] = arr
            loops[method] = full
    info = {"engine": caster.engine, "beams": getattr(caster, "beams", "facets: the mesh as it is"), "standoff_mm": standoff, "tilt_deg": math.degrees(tilt),
            "noise_mm": noise.tolist(), "tolerance_deg": math.degrees(tolerance),
            "motion": {"repeat_deg": math.degrees(motion.repeat), "scale": motion.scale, "position_mm": motion.position_mm},
            "tool_axis_tcs": a_tcs.tolist(), "reference_normal": getattr(panel.surface, "reference_name", "analytic") if n_an is not None else
            f"mesh: face hit, smoothed within {CREASE_ANGLE_DEG:g} deg",
            "reference_faceting": _faceting_info(faceting, chord, status == "ok", n_an is not None),
            "sensors": layout.n, "sphere_prior_radius_mm": prior_radius_mm,
            "footprint_mm": foot, "units": panel.units}
    notify(progress, 4, 4, "done")
    return NormalsRun(drill.labels, pts, status.astype(str), off, n_true, n_an, n_plane, n_sphere, err_p, err_s,
                      rad, d, init_tilt, loops, caster.engine, info, detail.astype(str))


def _edge_check(panel, caster, layout_true, R0, T0, pts, normal, foot, todo, tri_b):
    """Status and detail of the points whose footprint straddles a crease, a hole or the
    outline (:func:`metrology.panel.edges.straddle`), or one of whose spots lies where the
    surface has turned by more than the crease angle from the drilling point's normal (a
    bend tighter than the head: a leading edge); '' elsewhere. Beams are cast again only at
    points with an edge within twice the footprint (their spots can reach farther than the
    footprint when the head is tilted). ``tri_b (m, n)``: the face each beam hit, -1 for a
    miss or a hit from behind (those keep their own status)."""
    m = len(pts)
    status = np.full(m, "", dtype=object)
    detail = np.full(m, "", dtype=object)
    edges = panel.edges(CREASE_ANGLE_DEG)
    idx = np.flatnonzero(todo)
    near, _, _ = edges.near(pts[idx], 2.0 * foot + 1.0)
    idx = idx[np.unique(near)]
    if len(idx):
        d, tri, _ = cast_beams(caster, layout_true, R0[idx], T0[idx])
        o = np.einsum("mij,nj->mni", R0[idx], layout_true.zero) + T0[idx][:, None, :]
        u = np.einsum("mij,nj->mni", R0[idx], layout_true.direction)
        spots = o + d[..., None] * u
        fn = np.full(spots.shape, np.nan)
        hit = tri >= 0
        fn[hit] = np.asarray(panel.mesh.face_normals)[tri[hit]]
        status[idx], detail[idx] = straddle(edges, pts[idx], foot, normal[idx], spots, fn, layout_true.names)
    # a spot on a surface turned past the crease angle, no crease edge needed (a tight bend)
    hit = tri_b >= 0
    cos = np.full(tri_b.shape, np.nan)
    cos[hit] = np.einsum("qj,qj->q", np.asarray(panel.mesh.face_normals)[tri_b[hit]], normal[np.nonzero(hit)[0]])
    turned = np.isfinite(cos) & (cos < math.cos(math.radians(CREASE_ANGLE_DEG)))
    for i in np.flatnonzero(todo & (status == "") & np.any(turned, axis=1)):
        who = ", ".join(str(n) for n, t in zip(layout_true.names, turned[i]) if t)
        deg = math.degrees(math.acos(float(np.nanmin(np.clip(cos[i], -1, 1)))))
        status[i] = "spot_bend"
        detail[i] = f"spot of {who} where the surface has turned {deg:.0f} deg (more than the {CREASE_ANGLE_DEG:g} deg crease angle)"
    return status, detail


def _faceting_info(faceting, chord, good, analytic):
    """The mesh reference's own uncertainty over the measured points (for ``info``)."""
    if analytic:
        return {"used": False, "note": "the analytic surface is the reference; the mesh only carries the beams"}
    f = np.degrees(faceting[good]) if np.any(good) else np.array([np.nan])
    c = chord[good] if np.any(good) else np.array([np.nan])
    return {"used": True, "crease_angle_deg": CREASE_ANGLE_DEG,
            "angle_median_deg": float(np.median(f)), "angle_max_deg": float(np.max(f)),
            "chord_median_mm": float(np.median(c)), "chord_max_mm": float(np.max(c)),
            "note": "half the largest angle between the face hit and the faces smoothed with it, and its chord "
                    "error (the face's width across the bend x angle / 8); 0 on a facet bounded by creases, exact "
                    "only if the design is flat there"}
