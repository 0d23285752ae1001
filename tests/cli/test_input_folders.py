"""A folder given where `metro measure` and `metro simulate-log` read a file (--layout, --panel, --points,
--true-layout): one line in the CLI's wording, "FOLDER: a folder, not a file (OPTION)", exit 2 (docs/cli.md), not
the reader's own ("cannot read mesh (ValueError: string is not a file ...)", "no such hole table": the walk,
round 7; issue 51 item 13). A log may be a folder (hive): it is read."""

import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.data import data_path

runner = CliRunner()
LAYOUT = str(data_path("measured", "nominal.toml"))
WING = str(data_path("panels", "wing.stl"))
HOLES = str(data_path("panels", "wing.holes.csv"))


@pytest.mark.parametrize("command, option", [
    ("measure", "--layout"), ("measure", "--panel"), ("measure", "--points"),
    ("simulate-log", "--layout"), ("simulate-log", "--true-layout"), ("simulate-log", "--panel"),
    ("simulate-log", "--points"),
])
def test_a_folder_where_a_file_is_read_is_one_line(tmp_path, command, option):
    folder = tmp_path / "given.stl"  # a suffix: simulate-log takes --panel NAME without one as a generated panel
    folder.mkdir()
    files = {"--layout": LAYOUT, "--panel": WING, "--points": HOLES}
    files[option] = str(folder)
    out = tmp_path / "out.csv"
    if command == "measure":
        args = ["measure", HOLES, "--layout", files["--layout"], "--out", str(out)]  # any existing file as LOG
        args += ["--panel", files["--panel"], "--points", files["--points"]] if option != "--layout" else []
    else:
        args = ["simulate-log", "--layout", files["--layout"], "--panel", files["--panel"], "--points",
                files["--points"], "--holes", "5", "--out", str(out)]
        args += ["--true-layout", str(folder)] if option == "--true-layout" else []
    r = runner.invoke(app, args)
    assert r.exit_code == 2, r.output
    assert r.output.strip() == f"error: {folder}: a folder, not a file ({option})", r.output
    assert not out.exists()
