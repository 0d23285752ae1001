"""The words of ``metro simulate-log``."""

from __future__ import annotations

__all__ = ["simulate_log_text"]


def simulate_log_text(summary: dict) -> str:
    """What was written, in two lines, from the job's summary."""
    spec = summary["spec"]
    panel = spec["panel"]
    shape = panel["kind"] + (f" R {panel['radius_mm']:g} mm" if "radius_mm" in panel else "")
    faults = [f"drift {d['sensor']} {d['rate_mm']:g} mm/{d['per']}" for d in spec["drifts"]]
    faults += [f"shift {s['sensor']} {s['size_mm']:+g} mm at hole {s['hole'] + 1}" for s in spec["shifts"]]
    rate = summary["holes_per_s"]
    return (f"wrote {summary['out']}: {summary['holes']} holes, {summary['cells']} cell(s), {shape} panel, "
            f"true angle {spec['angle_deg'][0]:g}-{spec['angle_deg'][1]:g} deg"
            + (f", {', '.join(faults)}" if faults else "") + f" ({summary['files']} file(s))\n"
            f"truth: {summary['truth'] or 'not written'}; {summary['seconds']:.2f} s"
            + (f" ({rate:,.0f} holes/s written)" if rate else ""))
