"""metrology.io.names: the name outputs give an input path, scoped to a with-block."""

from pathlib import Path

from metrology.io.names import display_name, named_inputs


def test_a_named_path_is_shown_by_its_name_only_inside_the_block(tmp_path):
    f = tmp_path / "stdin.csv"
    f.write_text("x")
    assert display_name(f) == str(f)
    with named_inputs({f: "<stdin>"}):
        assert display_name(f) == "<stdin>"
        assert display_name(str(f)) == "<stdin>"
        assert display_name(f.resolve()) == "<stdin>"
        assert display_name(tmp_path / "other.csv") == str(tmp_path / "other.csv")
        with named_inputs({tmp_path / "b.toml": "<b>"}):  # nested: both names hold
            assert display_name(f) == "<stdin>" and display_name(tmp_path / "b.toml") == "<b>"
        assert display_name(tmp_path / "b.toml") == str(tmp_path / "b.toml")
    assert display_name(f) == str(f)
    assert display_name(None) is None
    assert display_name(Path("rel/x.ply")) == "rel/x.ply"
