"""Layout TOML (metrology.core.layout): round trip and one-line errors."""

import numpy as np
import pytest

from metrology.core.layout import SensorLayout
from metrology.io.layout import load_layout, save_layout
from metrology.core.paper import table6_layouts


def test_layout_round_trip(tmp_path):
    nominal, _ = table6_layouts()
    lay = SensorLayout(nominal.names, nominal.zero, nominal.direction, [0.003] * 4, [[20, 80]] * 4,
                       np.full((4, 3), 0.01), np.full((4, 2), 0.02))
    save_layout(lay, tmp_path / "l.toml", header="test")
    back = load_layout(tmp_path / "l.toml")
    assert back.names == lay.names and back.effects is None
    np.testing.assert_allclose(back.zero, lay.zero, atol=1e-6)
    np.testing.assert_allclose(back.direction, lay.direction, atol=1e-9)
    np.testing.assert_allclose(back.range_mm, lay.range_mm)
    np.testing.assert_allclose(back.direction_stderr_deg, 0.02)


@pytest.mark.parametrize("body,msg", [
    ('units = "inch"\n', "units must be"),
    ("[[sensors]]\nname='a'\nzero=[0,0,0]\ndirection=[0,0,1]\n", "at least 3 sensors"),
    ("[[sensors]]\nname='a'\nzero=[0,0]\ndirection=[0,0,1]\n" * 3, "'zero' must be 3"),
    ("[[sensors]]\nname='a'\nzero=[0,0,0]\ndirection=[0,0,2]\n" * 3, "expected a unit vector"),
    ("[[sensors]]\nname='a'\nzero=[0,0,0]\ndirection=[0,0,1]\n" * 3, "unique"),
    ("not toml [", "not valid TOML"),
])
def test_layout_errors_name_the_file(tmp_path, body, msg):
    p = tmp_path / "bad.toml"
    p.write_text(body)
    with pytest.raises(ValueError, match=msg) as exc:
        load_layout(p)
    assert "bad.toml" in str(exc.value) or "unique" in msg
