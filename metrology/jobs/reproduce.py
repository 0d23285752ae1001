"""``metro reproduce`` as a job: the paper's simulation run, summarized, its figures written."""

from __future__ import annotations

__all__ = ["reproduce"]


def reproduce(cfg, seed: int, trials: int, figures=None, progress=None) -> dict:
    """Run ``trials`` seeded trials of :mod:`metrology.sim.reproduce` and summarize them.

    Parameters
    ----------
    cfg : metrology.sim.reproduce.ReproduceConfig
    seed : int
        Seed of the first trial's random stream.
    trials : int
    figures : str or os.PathLike or None
        Directory for Figures 7 and 8 (PNG, of the first trial); None for none.
    progress : callable or None
        ``progress(done, total, what)`` before each trial (:mod:`metrology.core.progress`).

    Returns
    -------
    dict
        :func:`metrology.sim.reproduce.summarize`, plus ``figures`` (the paths written)
        when ``figures`` is given.
    """
    from metrology.sim.reproduce import run_trials, summarize

    results = run_trials(cfg, seed, trials, progress=progress)
    summary = summarize(cfg, results, seed)
    if figures is not None:
        from metrology.report.reproduce import write_reproduce_figures

        summary["figures"] = write_reproduce_figures(cfg, results, figures)
    return summary
