"""The jobs report their progress through ``progress(done, total, what)``: steps in order,
within their total, ending with ``done`` (the bar the command line draws relies on it)."""

from metrology.io.data import DATA_DIR
from metrology.jobs.calibrate import calibrate_files
from metrology.jobs.demo import DEMO_STEPS, run_demo
from metrology.jobs.fit_plane import fit_plane_file

M = DATA_DIR / "measured"


def _recorder():
    calls = []
    return calls, lambda done, total, what: calls.append((done, total, what))


def _check(calls, total):
    assert calls, "no progress reported"
    dones = [d for d, _, _ in calls]
    assert dones == sorted(dones) and dones[0] == 0
    assert {t for _, t, _ in calls} == {total}
    assert calls[-1] == (total, total, "done")
    assert all(isinstance(w, str) and w for _, _, w in calls)


def test_calibrate_files_reports_each_step(tmp_path):
    calls, progress = _recorder()
    calibrate_files(M / "calibration.csv", M / "plane.json", M / "nominal.toml", out=tmp_path / "c.toml",
                    progress=progress)
    _check(calls, 3)  # read, calibrate, write (no --plot)
    assert calls[1][2].startswith("calibrating (lsq, 100 poses")


def test_fit_plane_file_reports_each_step():
    calls, progress = _recorder()
    fit_plane_file(DATA_DIR / "datum_cloud.ply", progress=progress)
    _check(calls, 3)
    assert "3300 points" in calls[1][2]


def test_run_demo_reports_each_step_before_running_it(tmp_path):
    calls, progress = _recorder()
    ran = []

    def run_step(args):
        ran.append((len(calls), args[0]))
        return 0

    assert run_demo(DATA_DIR, tmp_path, run_step, lambda title, args: None, progress=progress) == 0
    _check(calls, len(DEMO_STEPS))
    # step k is announced (call k) before it runs
    assert [n for n, _ in ran] == list(range(1, len(DEMO_STEPS) + 1))
    assert [w.split()[-1] for _, _, w in calls[:-1]] == [a for _, a in ran]
