"""A plugin defined outside the package is found through the entry-point group and runs from
YAML: the mechanism a third party uses, exercised with a throw-away distribution on sys.path."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from fusion.config import load_config
from fusion.engine import Engine
from fusion.kalman import CorrelatedNoise
from fusion.plugin import Measurement, PluginError, create_plugin, plugin_names

EXAMPLES = Path(__file__).resolve().parent / "example_plugins"


@pytest.fixture
def registered(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A fake installed distribution whose entry points name the example plugin (and a broken
    one)."""
    dist = tmp_path / "site" / "example_fusion_plugins-0.1.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: example-fusion-plugins\nVersion: 0.1\n"
    )
    (dist / "entry_points.txt").write_text(
        "[fusion.plugins]\n"
        "height_fix = height_fix:HeightFix\n"
        "broken_example = no_such_module:Nothing\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    monkeypatch.syspath_prepend(str(EXAMPLES))
    return tmp_path


def test_third_party_plugin_runs_from_yaml(registered: Path) -> None:
    from test_engine import LEVER_ARM, make_recording

    assert "height_fix" in plugin_names()
    config_file = registered / "height.yaml"
    config_file.write_text(
        yaml.safe_dump(
            {
                "name": "sins_height",
                "plugins": [{"type": "height_fix", "sigma_m": 0.05, "offset_sigma_m": 0.2}],
            }
        )
    )
    rec = make_recording(2, duration=120.0)
    result = Engine(load_config(config_file), rec).run()
    log = result.innovations["height_fix"]
    assert len(log.t) > 100
    assert 0.7 < log.whitened_rms() < 1.3
    offset, sigma = result.state_estimate("height_fix.datum_offset")
    # The recording's fixes are of an antenna 0.8 m above the IMU (the shearer stays nearly
    # level): that is the datum offset this plugin does not know about.
    assert abs(offset[0] - LEVER_ARM[2]) < 3 * sigma[0] + 0.02
    assert sigma[0] < 0.2


def test_broken_third_party_plugin_is_named_and_does_not_block_others(registered: Path) -> None:
    from test_engine import make_recording

    rec = make_recording(2, duration=10.0)
    with pytest.raises(PluginError, match=r"broken_example.*cannot be imported"):
        create_plugin("broken_example", "b", {}, rec, ("plugins", 0))
    assert create_plugin("height_fix", "h", {}, rec, ("plugins", 1)).name == "h"


def test_stacking_keeps_the_stored_errors_of_one_measurement_on_its_rows() -> None:
    """A measurement carrying stored errors stacked under a plain one: its B moves to its rows.
    Two that both carry some are refused (R's off-diagonal block would need their covariance)."""
    plain = Measurement(np.zeros(2), np.zeros((2, 4)), np.eye(2))
    carrying = Measurement(
        np.zeros(3),
        np.zeros((3, 4)),
        np.eye(3),
        correlated=CorrelatedNoise(np.array([3, 4, 5]), -np.eye(3)),
    )
    stacked = plain.stacked_with(carrying)
    assert stacked.correlated is not None
    np.testing.assert_array_equal(stacked.correlated.columns, [3, 4, 5])
    np.testing.assert_array_equal(
        stacked.correlated.mixing, np.vstack([np.zeros((2, 3)), -np.eye(3)])
    )
    assert plain.stacked_with(plain).correlated is None
    with pytest.raises(ValueError, match="both carry stored errors"):
        carrying.stacked_with(carrying)
