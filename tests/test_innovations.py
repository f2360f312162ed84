"""The innovation log: records survive the spill to disk, and the summary needs no read-back."""

import numpy as np
import pytest

import fusion.innovations
from fusion.innovations import InnovationLog
from fusion.kalman import KalmanFilter, UpdateResult


def _updates(n: int, seed: int) -> list[tuple[float, UpdateResult, bool]]:
    """n real Kalman updates of 1- to 3-component measurements, a few gated out."""
    rng = np.random.default_rng(seed)
    kf = KalmanFilter(np.zeros(3), np.eye(3))
    out = []
    for k in range(n):
        m = 1 + k % 3
        h = rng.standard_normal((m, 3))
        z = 3.0 * rng.standard_normal(m)
        res = kf.update(z, h, 0.5 * np.eye(m), gate_probability=0.99)
        out.append((0.01 * k, res, bool(k % 7 == 0)))
    return out


@pytest.mark.parametrize("chunk", [5, 1 << 16])
def test_records_survive_the_spill_and_the_summary_matches_them(
    monkeypatch: pytest.MonkeyPatch, chunk: int
) -> None:
    monkeypatch.setattr(fusion.innovations, "CHUNK_RECORDS", chunk)
    updates = _updates(23, seed=4)
    log = InnovationLog()
    for t, res, suspect in updates:
        log.append(t, res, suspect)
    assert len(log) == len(log.t) == 23
    np.testing.assert_array_equal(log.t, [u[0] for u in updates])
    np.testing.assert_array_equal(log.accepted, [u[1].accepted for u in updates])
    np.testing.assert_array_equal(log.suspect, [u[2] for u in updates])
    np.testing.assert_array_equal(log.dof, [u[1].dof for u in updates])
    np.testing.assert_allclose(log.nis, [u[1].nis for u in updates], rtol=1e-6)
    assert 0 < log.rejected == int(np.sum(~log.accepted)) < 23
    whitened = np.concatenate([u[1].whitened for u in updates if u[1].accepted])
    assert log.whitened_rms() == pytest.approx(np.sqrt(np.mean(whitened**2)), rel=1e-12)


def test_empty_log() -> None:
    log = InnovationLog()
    assert len(log) == 0 and log.t.size == 0 and np.isnan(log.whitened_rms())
