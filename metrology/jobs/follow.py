"""``metro calibrate --follow``: read poses as the cell appends them, update the filter, say when to stop.

The source is a file that grows (read to its end, then polled until ``idle_s`` seconds pass
with no new line) or ``-`` (standard input, read to its end). Each complete line is one pose;
the header line comes first. The result at the end is the batch iterated EKF on every pose
read (``metro calibrate --method iekf`` on the same file), with the standard errors ``calibrate``
reports (scaled by the residuals' scatter, :func:`metrology.calibration.uncertainty.residual_scaled_cov`),
the same ones the live stopping rule uses.
"""

from __future__ import annotations

import csv
import sys
import time
from dataclasses import dataclass

import numpy as np

from metrology.calibration.calibrate import CalibrationReport, calibrate_dataset
from metrology.calibration.follow import Follower, Targets

__all__ = ["FollowResult", "follow_export"]


@dataclass(frozen=True)
class FollowResult:
    """What ``--follow`` did: the final report, the steps, where the targets were met and why it stopped.

    Attributes
    ----------
    report : CalibrationReport, the batch iterated EKF on every pose read
    steps : list of FollowStep
    met_at : (int, str) or None, poses taken and pose_id when every target was first met
    stopped : str, "targets met", "end of input" or "idle"
    live_minus_final_sigma : (n, 5) float, the live filter's last estimate minus the final
        one, in units of the final standard errors
    """

    report: CalibrationReport
    steps: list
    met_at: tuple | None
    stopped: str
    targets: Targets
    live_minus_final_sigma: np.ndarray

    def to_dict(self) -> dict:
        return {**self.report.to_dict(), "follow": {
            "targets": self.targets.to_dict(), "poses_read": len(self.steps), "stopped": self.stopped,
            "met_at_pose": None if self.met_at is None else self.met_at[1],
            "met_after_poses": None if self.met_at is None else self.met_at[0],
            "live_minus_final_max_sigma": float(np.max(np.abs(self.live_minus_final_sigma))),
            "steps": [{"k": s.k, "pose_id": s.pose_id, "normal_sigma_deg": float(np.rad2deg(s.normal_sigma_rad)),
                       "zero_sigma_max_mm": float(s.stderr[:, :3].max()),
                       "tilt_sigma_max_deg": float(np.rad2deg(s.stderr[:, 3:].max())), "met": s.met}
                      for s in self.steps]}}


def _lines(source, idle_s: float, poll_s: float, stream=None):
    """Complete lines of ``source`` as they arrive: (line number, text); a file is polled at its end
    until ``idle_s`` passes with nothing new. Yields ("idle" | "end of input") last."""
    if str(source) == "-":
        fh = stream if stream is not None else sys.stdin
        for k, line in enumerate(fh, start=1):
            yield k, line
        yield None, "end of input"
        return
    try:
        fh = open(source, newline="", encoding="utf-8-sig")
    except OSError as exc:
        raise ValueError(f"{source}: cannot read export ({exc.strerror})") from None
    with fh:
        buf, k, last = "", 0, time.monotonic()
        while True:
            chunk = fh.readline()
            if chunk:
                buf += chunk
                if buf.endswith("\n"):
                    k += 1
                    yield k, buf
                    buf, last = "", time.monotonic()
                continue
            if time.monotonic() - last >= idle_s:
                if buf.strip():
                    yield k + 1, buf
                yield None, "idle"
                return
            time.sleep(poll_s)


def _working_standoff(layout, first_d):
    if np.all(np.isfinite(layout.range_mm)):
        return float(np.mean(layout.range_mm))
    return float(np.nanmean(first_d))


def follow_export(source, plane_path, layout_path, targets: Targets, on_step=None, idle_s: float = 5.0,
                  poll_s: float = 0.2, stop_when_met: bool = False, sigma_mm=None, quaternion_order="wxyz",
                  position_units="mm", no_reading=None, stream=None, name=None, target_set=False) -> FollowResult:
    """Follow a growing export (or ``-``): one filter update per pose, ``on_step(step)`` after each.

    Errors are ValueError naming the source and line (the header is checked against the layout
    before any pose is read). ``sigma_mm`` (mm) replaces the layout's ``noise_mm``. ``name`` is
    the source as messages and the report name it (default ``source``; the CLI gives ``<stdin>``
    for ``-``). ``target_set``: the user set ``targets`` (they gate the verdict).
    """
    from metrology.calibration.dataset import Dataset, check, drop_no_reading, load_plane
    from metrology.calibration.sanity import check_dataset
    from metrology.io.export import export_from_rows
    from metrology.io.layout import load_layout

    label = str(source) if name is None else str(name)
    layout = load_layout(layout_path)
    from metrology.core.effects.terms import refuse_terms

    refuse_terms(layout, layout_path, "calibrate --follow", "the live filter's state does not carry them")
    plane, points = load_plane(plane_path)
    sigma = layout.noise_mm if sigma_mm is None else np.full(layout.n, float(sigma_mm))
    if not np.all(np.isfinite(sigma) & (sigma > 0)):
        raise ValueError(f"{layout_path}: --follow needs the reading noise: noise_mm in the layout")
    header, rows, steps, follower, stopped = None, [], [], None, "end of input"
    for k, line in _lines(source, idle_s, poll_s, stream):
        if k is None:
            stopped = line
            break
        row = next(csv.reader([line]), [])
        if not any(c.strip() for c in row):
            continue
        if header is None:
            header = [h.strip() for h in row]
            names = sorted(h[2:] for h in header if h.startswith("d_"))
            if names != sorted(layout.names):
                raise ValueError(f"{label}: line {k}: reading columns {', '.join('d_' + n for n in names) or 'none'} "
                                 f"do not match the layout's sensors {', '.join(layout.names)}")
            continue
        one = export_from_rows([header, row], label, quaternion_order, position_units, first_line=k)
        one, _ = drop_no_reading(one.reordered(layout.names), layout, no_reading)
        lo, hi = layout.range_mm[:, 0], layout.range_mm[:, 1]
        bad = np.isfinite(one.d[0]) & ((one.d[0] < lo) | (one.d[0] > hi))
        if np.any(bad):
            i = int(np.argmax(bad))
            raise ValueError(f"{label}: line {k}: d_{layout.names[i]} = {one.d[0, i]:g} mm outside the sensor's range "
                             f"[{lo[i]:g}, {hi[i]:g}] mm")
        rows.append(row)
        if follower is None:
            follower = Follower(layout, plane.normal, plane.offset, sigma, targets, _working_standoff(layout, one.d[0]))
        step = follower.add(one.pose_id[0], one.tcs2tracker_rot[0], one.tcs2tracker_trans[0], one.d[0])
        steps.append(step)
        if on_step is not None:
            on_step(step)
        if step.met and stop_when_met:
            stopped = "targets met"
            break
    if header is None or not rows:
        raise ValueError(f"{label}: no pose rows (a header line, then one line per pose)")
    export = export_from_rows([header, *rows], label, quaternion_order, position_units)
    export, dropped = drop_no_reading(export.reordered(layout.names), layout, no_reading)
    if not np.any(np.isfinite(export.d)):
        raise ValueError(f"{label}: {len(rows)} pose(s) read, none with a reading yet (the d_ columns are empty: "
                         "a planned file waiting for readings?); nothing to calibrate")
    export = check(export, layout, label)
    dataset = Dataset(export, layout, plane, points, dropped)
    check_dataset(dataset, label, quaternion_order, position_units)
    report = calibrate_dataset(dataset, "iekf", sources={"export": label, "plane": str(plane_path),
                                                         "layout": str(layout_path)},
                                target=(targets.zero_mm, targets.tilt_rad), target_set=target_set, sigma_mm=sigma,
                                stderr="residual")
    cal = report.calibration
    diff = (follower.x - cal.theta) / np.where(cal.stderr > 0, cal.stderr, np.inf)
    return FollowResult(report, steps, follower.met_at, stopped, targets, diff)
