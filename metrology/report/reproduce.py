"""Text and figures of ``metro reproduce`` (the paper's section 5): the tables and Figures 7, 8."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["format_reproduce", "write_reproduce_figures", "FIGURE_NAMES"]

#: file names of the paper's Figures 7 and 8 in the figures directory
FIGURE_NAMES = ("figure7_ekf_convergence.png", "figure8_angular_deviation.png")


def _table(rows, header):
    """Rows of cells under a header, first column left-aligned, the others right-aligned."""
    widths = [max(len(str(r[i])) for r in rows + [header]) for i in range(len(header))]
    line = "  ".join(h.ljust(w) if i == 0 else h.rjust(w) for i, (h, w) in enumerate(zip(header, widths)))
    out = [line, "-" * len(line)]
    for r in rows:
        out.append("  ".join(str(c).ljust(w) if i == 0 else str(c).rjust(w) for i, (c, w) in enumerate(zip(r, widths))))
    return "\n".join(out)


def format_reproduce(s: dict) -> str:
    """The readable report of :func:`metrology.sim.reproduce.summarize`."""
    cfg = s["config"]
    lines = [
        f"metro reproduce: layout {s['layout']}, {s['trials']} trial(s), seed {s['seed']}",
        f"  {cfg['n_poses']} calibration poses, reading noise {cfg['noise_mm']} mm; datum {cfg['n_datum_points']} points "
        f"at {cfg['datum_noise_mm']} mm over {cfg['datum_size_mm']:g} mm; stand-off {cfg['standoff_mm'][0]:g}-"
        f"{cfg['standoff_mm'][1]:g} mm, tilt <= {cfg['tilt_max_deg']:g} deg, spread {cfg['spread_mm']:g} mm; "
        f"{cfg['n_workpiece']} workpiece poses; paper EKF Q={cfg['ekf_paper']['Q']:g} R={cfg['ekf_paper']['R']:g} "
        f"delta={cfg['ekf_paper']['delta']:g}",
        "",
        "Table 1 analogue: datum plane (A, B, C, D), trial 1",
    ]
    t1 = s["table1"]
    rows = [["theoretical"] + [f"{v:.4f}" for v in t1["theoretical"]], ["fitted (metro)"] + [f"{v:.4f}" for v in t1["fitted_trial1"]]]
    if t1["paper_fitted"]:
        rows.append(["fitted (paper)"] + [f"{v:.4f}" for v in t1["paper_fitted"]])
    lines += [_table(rows, ["", "A", "B", "C", "D"]), ""]
    t3 = s["table3"]
    lines.append("Table 3 analogue: measurements to the paper's stopping rule (-: never met)")
    fmt = lambda v: "-" if v is None or v < 0 else f"{v:g}"  # noqa: E731
    rows = [["trial 1"] + [fmt(v) for v in t3["n_converged_trial1"]],
            ["never met (share)"] + [f"{v:.0%}" for v in t3["never_converged_fraction"]],
            ["median if met"] + [fmt(v) for v in t3["median_when_converged"]],
            ["paper"] + [str(v) for v in t3["paper"]]]
    lines += [_table(rows, [""] + t3["sensors"]), ""]
    spread = s["trials"] > 1
    lines.append("Table 4 analogue: angular deviation of the measured normal on the workpiece [deg]"
                 + (" (mean +- spread over trials)" if spread else ""))
    rows = []
    for m, r in s["table4"].items():
        cell = lambda k: f"{r[k]:.4f}" + (f" +- {r[k.replace('_deg', '_spread_deg')]:.4f}" if spread else "")  # noqa: E731
        p = s["paper_table4"].get(m)
        rows.append([m, cell("max_deg"), cell("mean_deg"), cell("std_deg"), f"{r['zero_error_mm']:.3f}",
                     f"{r['direction_error_deg']:.3f}", "" if p is None else f"{p['max_deg']:.4f}/{p['mean_deg']:.4f}/{p['std_deg']:.4f}"])
    lines.append(_table(rows, ["method", "max", "mean", "std", "max|dE| mm", "max dir err deg", "paper max/mean/std"]))
    lines.append("  before = nominal layout; true = the true parameters (the floor set by reading noise).")
    return "\n".join(lines)


def write_reproduce_figures(cfg, results, directory) -> list:
    """Write Figures 7 and 8 of the first trial into ``directory`` (created if absent).

    Parameters
    ----------
    cfg : metrology.sim.reproduce.ReproduceConfig
    results : list of metrology.sim.reproduce.Trial
    directory : str or os.PathLike

    Returns
    -------
    list of str
        The two paths written (atomically).
    """
    from metrology.report.plots import figure7, figure8

    fig_dir = Path(directory)
    fig_dir.mkdir(parents=True, exist_ok=True)
    nominal, true, _, _ = cfg.tables()
    true_err = np.concatenate([true.zero - nominal.zero, true.direction - nominal.direction], axis=1)
    figure7(results[0].ekf_history, true_err, nominal.names, fig_dir / FIGURE_NAMES[0])
    figure8(results[0].deviation_deg, fig_dir / FIGURE_NAMES[1])
    return [str(fig_dir / name) for name in FIGURE_NAMES]
