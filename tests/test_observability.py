"""The observability report: the share of each state's prior variance the data removed."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from fusion.config import load_config, parse_config
from fusion.engine import Engine
from fusion.error_model import StateBlock, StateLayout
from fusion.kalman import KalmanFilter
from fusion.observability import ObservabilityTracker
from fusion.outputs import summary, write_outputs
from tests.test_engine import CONFIGS, make_recording


def test_a_state_nothing_measures_keeps_its_prior_share_of_zero() -> None:
    """Two random walks, only the first measured: its share tends to 1, the other's stays 0
    however long the run; the history starts at 0."""
    layout = StateLayout((StateBlock("a", ("x", "y"), (1.0, 2.0), (0.01, 0.01)),))
    kf = KalmanFilter(np.zeros(2), layout.initial_covariance())
    tracker = ObservabilityTracker(layout)
    phi, qd = np.eye(2), np.diag([0.01, 0.01])
    rng = np.random.default_rng(0)
    tracker.sample(0.0, kf.P)
    for k in range(1, 200):
        kf.predict(phi, qd)
        tracker.predict(phi, qd)
        kf.update(np.array([rng.normal()]), np.array([[1.0, 0.0]]), np.array([[0.04]]))
        tracker.sample(float(k), kf.P)
    report = tracker.report(kf.P)
    assert report.share("a.x") > 0.9
    assert report.share("a.y") == pytest.approx(0.0, abs=1e-12)
    assert report.removed_history.shape == (200, 2) and np.all(report.removed_history[0] == 0)
    assert report.by_block() == {"a": {"x": round(report.share("a.x"), 4), "y": 0.0}}
    with pytest.raises(KeyError, match=r"a\.x"):
        report.share("b.x")


def test_a_free_inertial_run_observes_nothing() -> None:
    """Without a measurement the filter's covariance is its prior: every share is 0."""
    result = Engine(load_config(CONFIGS / "sins_only.yaml"), make_recording(1, 60.0, False)).run()
    assert result.observability is not None
    assert np.max(result.observability.removed) < 1e-9
    assert np.max(result.observability.removed_history) < 1e-9


def test_position_fixes_observe_the_position_and_the_report_reaches_every_output(
    tmp_path: Path,
) -> None:
    """1-Hz position fixes over 5 min of shearer motion: the position and the tilts are
    observed (> 99 % and > 90 % of their prior variance removed), the vertical gyro bias far
    less (a slow, nearly level machine turns little); the summary, metrics.json and the figure
    carry the report, its history once per second."""
    rec = make_recording(3)
    config = parse_config({"name": "sins_position", "plugins": [{"type": "position"}]})
    result = Engine(config, rec).run()
    report = result.observability
    assert report is not None
    print("\n".join(report.describe()))
    assert min(report.share(f"position.{a}") for a in "enu") > 0.99
    assert min(report.share(f"attitude.{a}") for a in "en") > 0.9
    assert report.share("gyro_bias.z") < report.share("gyro_bias.x")
    assert np.all(np.diff(report.t) >= 1.0 - 1e-9) and report.t.size == pytest.approx(300, abs=2)
    text = summary(result, rec)
    assert "observed   share of each state's prior variance the data removed:" in text
    assert "           gyro_bias: x " in text
    assert re.search(r"estimate   gyro_bias: \[.*\] ± \[.*\] deg/h", text)  # a user's unit
    files = write_outputs(result, rec, tmp_path)
    metrics = json.loads(files["metrics"].read_text())
    assert metrics["observability"]["removed"]["position"]["e"] > 0.99
    assert files["observability"].exists()
