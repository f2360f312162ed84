"""RTS smoothing under closed-loop feedback against filterpy's smoother on the open-loop problem."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter as FilterpyKF

from fusion.config import load_config
from fusion.earth import LocalFrame
from fusion.engine import Engine, RunResult
from fusion.fault_detection import ISOLATE
from fusion.kalman import KalmanFilter
from fusion.metrics import compute_metrics
from fusion.smoother import (
    SmoothingGain,
    StepStore,
    WindowedSmoother,
    plausible_correction,
    rts,
)
from fusion.strapdown import HGT, LAT, LON, NAV_SIZE
from tests.fault_support import clean_and_faulty, without_nlos_test

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def _system() -> tuple[np.ndarray, ...]:
    dt = 0.1
    f = np.array([[1, dt, 0, 0], [0, 1, 0, dt], [0, 0, 1, dt], [0, 0, 0, 0.999]], dtype=float)
    q = np.diag([1e-4, 1e-3, 1e-4, 1e-6])
    h = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
    r = np.diag([0.04, 0.09])
    return f, q, h, r


@pytest.mark.parametrize(("budget_mb", "output_every"), [(512.0, 1), (0.0, 1), (512.0, 7)])
@pytest.mark.parametrize("fed_back", [(1, 1, 1, 1), (1, 1, 1, 0), (0, 0, 0, 0)])
def test_closed_loop_smoother_equals_open_loop_rts(
    fed_back: tuple[int, ...], budget_mb: float, output_every: int
) -> None:
    """Feed back some or all states after every update; the smoothed total state equals
    filterpy.rts_smoother on the equivalent open-loop problem — at every step, or at every 7th
    (the steps between output epochs folded into one map), and spilling to disk changes
    nothing."""
    f, q, h, r = _system()
    rng = np.random.default_rng(3)
    n_steps = 3000
    p0 = np.diag([1.0, 0.1, 1.0, 0.01])
    truth = rng.multivariate_normal(np.zeros(4), p0)
    zs = []
    for _ in range(n_steps):
        zs.append(h @ truth + rng.multivariate_normal(np.zeros(2), r))
        truth = f @ truth + rng.multivariate_normal(np.zeros(4), q)

    mask = np.array(fed_back, dtype=float)
    nominal = np.zeros(4)
    kf = KalmanFilter(np.zeros(4), p0)
    store = StepStore(4, memory_budget_mb=budget_mb)
    nominal_after = []
    for k, z in enumerate(zs):
        if k > 0:
            nominal = f @ nominal
            kf.predict(f, q)
        prior = (kf.x.copy(), kf.P.copy())
        kf.update(h @ nominal - z, h, r)  # error = nominal − truth
        posterior = (kf.x.copy(), kf.P.copy())
        u = kf.x * mask
        nominal = nominal - u
        kf.x = kf.x - u
        output = k % output_every == 0
        store.append(0.1 * k, f, prior, posterior, u, output=output)
        if output:
            nominal_after.append(nominal.copy())
    rows = sorted(rts(store), key=lambda row: row[0])
    d, p_s = np.array([row[1] for row in rows]), np.array([row[2] for row in rows])
    assert store.spilled == (budget_mb == 0.0)
    store.close()
    smoothed = np.array(nominal_after) - d

    ref = FilterpyKF(dim_x=4, dim_z=2)
    ref.x, ref.P, ref.F, ref.Q, ref.H, ref.R = np.zeros(4), p0.copy(), f, q, h, r
    xs, ps = [], []
    for k, z in enumerate(zs):
        if k > 0:
            ref.predict()
        ref.update(z)
        xs.append(ref.x.copy())
        ps.append(ref.P.copy())
    fs = np.repeat(f[None], n_steps, axis=0)
    qs = np.repeat(q[None], n_steps, axis=0)
    x_ref, p_ref, _, _ = ref.rts_smoother(np.array(xs), np.array(ps), fs, qs)
    np.testing.assert_allclose(smoothed, x_ref[::output_every], atol=1e-8)
    np.testing.assert_allclose(p_s, p_ref[::output_every], atol=1e-10)


def test_engine_smoothing_with_sparse_fixes_is_better_and_consistent() -> None:
    """Fixes every 20 s on a MEMS SINS, 10 seeds: the whole-recording smoother beats the forward
    filter between fixes, and its own σ (from P^s) describes its errors."""
    from test_engine import make_recording

    from fusion.config import parse_config
    from fusion.engine import Engine
    from fusion.metrics import interpolate_truth

    config = parse_config(
        {
            "name": "rts-fixes",
            "plugins": [{"type": "position"}],
            "smoother": {"mode": "whole", "memory_budget_mb": 2.0},
        }
    )
    forward_rms, smoothed_rms, normalized = [], [], []
    for seed in range(10):
        rec = make_recording(seed, duration=200.0)
        assert rec.position is not None
        keep = np.arange(rec.position.t.size) % 20 == 0
        fixes = rec.position
        rec = replace(
            rec,
            position=replace(fixes, t=fixes.t[keep], enu=fixes.enu[keep], sigma=fixes.sigma[keep]),
        )
        result = Engine(config, rec).run()
        assert result.smoothed is not None
        assert rec.truth is not None
        for sol, sink in ((result.solution, forward_rms), (result.smoothed, smoothed_rms)):
            inside, position, *_ = interpolate_truth(rec.truth, sol.t)
            err = sol.position[inside] - position
            sink.append(np.sqrt(np.mean(np.sum(err[:, :2] ** 2, axis=1))))
            if sol is result.smoothed:
                normalized.append(err / sol.sigma_position[inside])
    ratio = np.mean(smoothed_rms) / np.mean(forward_rms)
    nees_rms = np.sqrt(np.mean(np.concatenate(normalized) ** 2))
    print(f"smoothed/forward horizontal RMS {ratio:.2f}, smoothed RMS(err/σ) {nees_rms:.2f}")
    assert ratio < 0.7
    assert 0.7 < nees_rms < 1.3


def test_a_window_kept_forward_is_the_forward_track_and_is_reported(tmp_path: Path) -> None:
    """Fixes every 20 s give the smoother a gain of about 100σ: the window is smoothed. One fix
    at the start gives it 0.4σ: the window keeps its forward track (σ included), the summary
    and metrics.json say so, and ``significance_sigma: 0`` smooths it all the same."""
    import json

    from test_engine import make_recording

    from fusion.config import parse_config
    from fusion.outputs import summary, write_outputs

    def run(every: int, sigmas: float) -> RunResult:
        rec = make_recording(0, duration=200.0)
        assert rec.position is not None
        keep = np.arange(rec.position.t.size) % every == 0
        f = rec.position
        rec = replace(rec, position=replace(f, t=f.t[keep], enu=f.enu[keep], sigma=f.sigma[keep]))
        config = parse_config(
            {
                "name": "rts",
                "plugins": [{"type": "position"}],
                "smoother": {"mode": "whole", "significance_sigma": sigmas},
            }
        )
        return Engine(config, rec).run()

    for result, smoothed in ((run(20, 1.0), True), (run(200, 0.0), True), (run(200, 1.0), False)):
        assert result.smoothed is not None
        kept = result.smoother_unresolved_windows
        assert (result.smoother_windows, kept) == (1, int(not smoothed))
        same = np.array_equal(result.smoothed.position, result.solution.position) and (
            np.array_equal(result.smoothed.sigma_position, result.solution.sigma_position)
        )
        assert same != smoothed
    rec = make_recording(0, duration=200.0)
    assert "smoother   1 windows, smoothed: horizontal in 0, vertical in 0" in summary(result, rec)
    write_outputs(result, rec, tmp_path, plots=False)
    reported = json.loads((tmp_path / "metrics.json").read_text())["smoother"]
    assert reported == {
        "windows": 1,
        "windows_kept_forward": 1,
        "kept_forward": {"horizontal": 1, "vertical": 1},
        "epochs_rejected": 0,
    }


def test_online_smoothing_without_a_face_end_smooths_the_recording_as_one_window(
    tmp_path: Path,
) -> None:
    """Online smoothing closes its windows at the face ends the CPOEM plugin reports; a slice
    that never reaches one is smoothed as a single window, not refused."""
    from fusion.config import load_config
    from fusion.engine import Engine
    from fusion.recording import read_recording
    from fusion.sim.simulate import simulate

    simulate("longwall-200m", tmp_path / "rec", seed=1, overrides=["duration_s=90"])
    rec = read_recording(tmp_path / "rec")
    config = load_config(CONFIGS / "sins_od_cpoem_rts.yaml")
    assert config.smoother.mode == "online"
    result = Engine(config, rec).run()
    assert result.smoothed is not None
    np.testing.assert_array_equal(result.smoothed.t, result.solution.t)


def test_online_smoothing_needs_a_plugin_that_reports_window_ends() -> None:
    from test_engine import make_recording

    from fusion.config import ConfigError, parse_config
    from fusion.engine import Engine

    config = parse_config(
        {"name": "online-fixes", "plugins": [{"type": "position"}], "smoother": {"mode": "online"}}
    )
    with pytest.raises(ConfigError, match=r"smoother\.mode"):
        Engine(config, make_recording(0, duration=20.0)).run()


def _drift_system(dt: float = 1.0) -> tuple[np.ndarray, ...]:
    """Three axes of velocity (0–2), an acceleration bias (3–5) and position (6–8): the
    smoothed layout's velocity and position slots, a velocity sensor on every step."""
    f = np.eye(9)
    f[6:9, 0:3] = dt * np.eye(3)
    f[0:3, 3:6] = dt * np.eye(3)
    q = np.diag([1e-6] * 3 + [1e-8] * 3 + [1e-6] * 3)
    h = np.hstack([np.eye(3), np.zeros((3, 6))])
    p0 = np.diag([1e-4] * 3 + [1e-6] * 3 + [1e-2] * 3)
    return f, q, h, p0


def _filter_drift(
    seed: int,
    n_steps: int,
    fix_sigma: float | tuple[float, float, float],
    output_every: int = 1,
    smoother: WindowedSmoother | None = None,
) -> tuple[StepStore, np.ndarray, np.ndarray, np.ndarray]:
    """Open-loop filter of :func:`_drift_system` (velocity σ 1 cm/s on every step, one position
    fix of σ ``fix_sigma`` per axis at the last step): its store, the truth and the filtered
    estimates at the output epochs, and P0. With ``smoother`` the filter runs closed-loop (its
    estimate fed back at every step) and the steps go to the smoother instead, with a nominal
    navigation state at rest at every output epoch."""
    f, q, h, p0 = _drift_system()
    rng = np.random.default_rng(seed)
    truth = rng.multivariate_normal(np.zeros(9), p0)
    kf = KalmanFilter(np.zeros(9), p0)
    store = StepStore(9, memory_budget_mb=512.0)
    truths, filtered = [], []
    nav = np.zeros(NAV_SIZE)
    nav[0], nav[7] = 1.0, 0.5
    nominal = np.zeros(9)
    for k in range(n_steps):
        if k > 0:
            truth = f @ truth + rng.multivariate_normal(np.zeros(9), q)
            nominal = f @ nominal
            kf.predict(f, q)
        prior = (kf.x.copy(), kf.P.copy())
        rows, r = h, np.eye(3) * 1e-4
        if k == n_steps - 1:
            rows = np.vstack([h, np.hstack([np.zeros((3, 6)), np.eye(3)])])
            r = np.diag([1e-4] * 3 + list(np.broadcast_to(fix_sigma, 3) ** 2))
        z = rows @ (truth - nominal) + rng.multivariate_normal(np.zeros(len(r)), r)
        kf.update(-z, rows, r)  # the nominal's error: nominal − truth
        output = k % output_every == 0 or k == n_steps - 1
        posterior = (kf.x.copy(), kf.P.copy())
        if smoother is not None:
            feedback = kf.x.copy()
            smoother.step(float(k), f, prior, posterior, feedback, nav if output else None)
            nominal = nominal - feedback
            kf.x = np.zeros(9)
        else:
            store.append(float(k), f, prior, posterior, np.zeros(9), output=output)
        if output:
            truths.append(truth.copy())
            filtered.append(kf.x.copy())
    return store, np.array(truths), np.array(filtered), p0


@pytest.mark.parametrize("output_every", [1, 4])
@pytest.mark.parametrize("converted", [False, True])
@pytest.mark.parametrize("axes", [(0, 1, 2), (0, 1)])
def test_smoothing_gain_variance_is_the_batch_solution_s(
    output_every: int, converted: bool, axes: tuple[int, ...]
) -> None:
    """The recursion of :class:`SmoothingGain` gives Var(Σ_j D_jᵀ ε_j) over a window's smoothed
    errors: the same as the joint covariance of a batch least-squares solution of the whole
    window (its information matrix inverted), with steps folded between output epochs, with
    a conversion T_j per epoch, and on the horizontal axes alone."""
    n = 24
    f, q, h, p0 = _drift_system()
    store, _, _, _ = _filter_drift(0, n, fix_sigma=0.05, output_every=output_every)
    rng = np.random.default_rng(1)
    info = np.zeros((9 * n, 9 * n))
    block = [slice(9 * k, 9 * k + 9) for k in range(n)]
    info[block[0], block[0]] += np.linalg.inv(p0)
    qi = np.linalg.inv(q)
    for k in range(n - 1):
        a, b = block[k], block[k + 1]
        info[a, a] += f.T @ qi @ f
        info[b, b] += qi
        info[a, b] -= f.T @ qi
        info[b, a] -= qi @ f
    for k in range(n):
        rows, r = h, np.eye(3) * 1e-4
        if k == n - 1:
            rows = np.vstack([h, np.hstack([np.zeros((3, 6)), np.eye(3)])])
            r = np.diag([1e-4] * 3 + [0.05**2] * 3)
        info[block[k], block[k]] += rows.T @ np.linalg.inv(r) @ rows
    joint = np.linalg.inv(info)

    gain = SmoothingGain(9, axes)
    weights = np.zeros(9 * n)
    expected = 0.0
    outputs = [k for k in range(n) if k % output_every == 0 or k == n - 1]
    for j, _, p_s, g in rts(store):
        k = outputs[j]
        np.testing.assert_allclose(p_s, joint[block[k], block[k]], rtol=1e-6, atol=1e-12)
        correction = rng.normal(size=3)
        transform = np.eye(9) + 0.3 * rng.normal(size=(9, 9)) if converted else None
        gain.add(correction, p_s, g, None if transform is None else transform[6:9])
        w = np.zeros(9)
        w[[6 + a for a in axes]] = correction[list(axes)]
        expected += float(w @ w)
        weights[block[k]] = w if transform is None else transform.T @ w
    store.close()
    assert gain.variance == pytest.approx(float(weights @ joint @ weights), rel=1e-6)
    assert gain.expected == pytest.approx(expected, rel=1e-12)


def test_a_window_smooths_the_height_without_the_horizontal_track_it_cannot_tell() -> None:
    """A fix that knows the height to a millimetre and the horizontal position to 100 m (seed 4:
    gains of 2.3 and 0.5 of their spreads): the height is smoothed; the horizontal output
    coordinates and their covariance keep the forward ones exactly, about an origin more than a
    kilometre away (where the local vertical leans off the origin's by 2·10⁻⁴ rad)."""
    n = 40
    frame = LocalFrame(np.degrees(0.5) - 0.01, -0.01, 0.0)

    def to_output(navs: np.ndarray) -> np.ndarray:
        return frame.to_enu(navs[:, LAT], navs[:, LON], navs[:, HGT])

    smoother = WindowedSmoother(9, lambda t: t == n - 1, 512.0, to_output, significance_sigma=1.0)
    _filter_drift(4, n, (100.0, 100.0, 0.001), smoother=smoother)
    times, navs, positions, covariances = smoother.take_rows()
    forward = WindowedSmoother(9, lambda t: t == n - 1, 512.0, to_output, significance_sigma=1e9)
    _filter_drift(4, n, (100.0, 100.0, 0.001), smoother=forward)
    _, navs_f, positions_f, covariances_f = forward.take_rows()
    assert smoother.kept_forward == {"horizontal": 1, "vertical": 0}
    assert (smoother.windows, smoother.unresolved_windows) == (1, 0)
    horizontal = [0, 1, 2, 3, 4, 5, LAT, LON]  # attitude, east and north velocity, lat, lon
    np.testing.assert_array_equal(navs[:, horizontal], navs_f[:, horizontal])
    np.testing.assert_array_equal(positions[:, :2], positions_f[:, :2])
    np.testing.assert_array_equal(positions_f, to_output(navs_f))
    np.testing.assert_array_equal(positions[:, 2], to_output(navs)[:, 2])
    assert np.all(positions[:-1, 2] != positions_f[:-1, 2])  # height
    assert np.any(to_output(navs)[:, :2] != positions_f[:, :2])  # what the tilt would have done
    np.testing.assert_array_equal(covariances[:, :2, :2], covariances_f[:, :2, :2])
    assert np.all(covariances[:-1, 2, 2] < covariances_f[:-1, 2, 2])
    assert times.size == n


def test_windows_the_smoother_calls_significant_are_better_than_forward() -> None:
    """A correct smoother whose only news is a weak fix at a window's end is worse than its
    forward track on a large share of windows (a coin toss by its own statistics). The windows
    :meth:`SmoothingGain.significant` passes at 1σ are better in ≥ 84 % of cases by the model
    (Φ(1)); 400 seeded windows, fixes of σ 3 cm–1 m against a forward position σ of ~10 cm."""
    better_all, better_significant, significant = [], [], 0
    for seed in range(400):
        fix_sigma = (0.03, 0.3, 1.0)[seed % 3]
        store, truths, filtered, _ = _filter_drift(seed, 40, fix_sigma)
        gain = SmoothingGain(9)
        smoothed = np.zeros_like(filtered)
        for j, d, p_s, g in rts(store):
            smoothed[j] = d
            gain.add(filtered[j, 6:9] - d[6:9], p_s, g, None)
        store.close()
        errors = [np.sum((x[:, 6:9] + truths[:, 6:9]) ** 2) for x in (filtered, smoothed)]
        better = bool(errors[1] < errors[0])
        better_all.append(better)
        if gain.significant(1.0):
            significant += 1
            better_significant.append(better)
    worse_share = 1.0 - np.mean(better_all)
    hit = np.mean(better_significant)
    print(
        f"smoothing every window: {worse_share:.2f} worse;"
        f" {significant} significant, {hit:.2f} of them better"
    )
    assert worse_share > 0.2
    assert significant > 60
    assert hit > 0.84


def test_plausible_correction_allows_what_the_forward_statistics_allow() -> None:
    """A correction inside the χ²₃ bound of P_f − P_s passes; beyond it, with a smoothed
    covariance larger than the forward one, a correction where nothing was gained, or a NaN,
    the forward estimate is kept."""
    forward = np.diag([0.04, 0.09, 0.01])
    smoothed = 0.25 * forward
    gained = np.sqrt(np.diag(forward - smoothed))
    assert plausible_correction(2.0 * gained, smoothed, forward)
    assert not plausible_correction(4.0 * gained, smoothed, forward)
    assert not plausible_correction(np.zeros(3), 2.0 * forward, forward)
    assert not plausible_correction(np.array([0.1, 0.0, 0.0]), forward, forward)
    assert plausible_correction(np.zeros(3), forward, forward)
    assert not plausible_correction(np.array([np.nan, 0.0, 0.0]), smoothed, forward)


def test_smoothing_across_isolations_is_finite_and_no_worse(tmp_path: Path) -> None:
    """full_afkf_rts through 30 s of NLOS on every anchor, with the UWB plugin's NLOS test off
    so that the master isolates the UWB local and re-admits it, each a step whose fused prior
    and posterior are not one filter's. The windows close before them: the smoothed track is
    finite, its σ too, and it is no worse than the forward one (on an independent world the
    smoother returned a NaN σ from an isolation on)."""
    nlos = "faults=[{kind: uwb_nlos, t_start: 200, t_end: 230, bias_m: [0.3, 1.5]}]"
    _, disturbed = clean_and_faulty(tmp_path, nlos, duration_s=280.0, uwb_rate_hz=40.0)
    assert disturbed.truth is not None
    config = without_nlos_test(load_config(CONFIGS / "full_afkf_rts.yaml"))
    result = Engine(config, disturbed).run()
    assert any(e.action == ISOLATE for e in result.faults)
    assert result.smoothed is not None
    assert np.all(np.isfinite(result.smoothed.position))
    assert np.all(np.isfinite(result.smoothed.sigma_position))
    forward = compute_metrics(result.solution, disturbed.truth)["horizontal_rms"]
    smoothed = compute_metrics(result.smoothed, disturbed.truth)["horizontal_rms"]
    print(f"horizontal RMS forward {forward:.4f} m, smoothed {smoothed:.4f} m")
    assert smoothed <= forward
