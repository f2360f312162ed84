"""Federated master: exactness against the centralized filter, sharing rules, fault isolation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fusion.config import (
    ConfigError,
    FaultDetectionOptions,
    FederatedOptions,
    load_config,
    parse_config,
)
from fusion.encoder import combine_readings
from fusion.engine import Engine
from fusion.error_model import ImuNoise, StateBlock, StateLayout, common_blocks
from fusion.fault_detection import ISOLATE, READMIT, FaultMonitor
from fusion.federated import LAST_HOLDER, FederatedFilter
from fusion.filter_bank import CentralizedFilter, FilterBank
from fusion.kalman import CorrelatedNoise, UpdateResult
from fusion.plugin import MeasurementContext, StoredEstimate
from fusion.recording import read_recording
from fusion.sim.simulate import simulate

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def _layout() -> StateLayout:
    imu = ImuNoise(1e-4, 1e-3, 1e-5, 1e-3)
    return StateLayout(common_blocks(imu, [0.1] * 3, [0.01] * 3, [1.0] * 3))


def _random_system(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    phi = np.eye(15) + 0.05 * rng.standard_normal((15, 15))
    a = 0.01 * rng.standard_normal((15, 15))
    return phi, a @ a.T + 1e-6 * np.eye(15)


def test_inflating_the_common_states_matches_the_centralized_filter() -> None:
    """A lost lock's fading factor (fusion.lock) inflates the common states in every local and
    the master: the fused filter stays equal to the centralized one inflated alike, own states
    and their cross terms included, through the rounds that follow."""
    rng = np.random.default_rng(8)
    fed, ckf = _banks_with_an_owning_local(FederatedOptions(sharing="trace", master_share=0.3))
    for step in range(40):
        _owning_round(fed, ckf, rng, step)
        if step == 20:
            before = ckf.common_covariance()
            fed.inflate_common(7.0)
            ckf.inflate_common(7.0)
            inflated = before + 6.0 * np.diag(np.diagonal(before))
            np.testing.assert_allclose(fed.common_covariance(), inflated, rtol=1e-9)


@pytest.mark.parametrize("master_share", [0.0, 0.3])
@pytest.mark.parametrize("sharing", ["equal", "trace", "inverse_trace"])
def test_fusion_reset_equals_centralized_on_common_states(
    sharing: str, master_share: float
) -> None:
    """Carlson's result: with fusion and reset after every update round and locals that hold only
    common states, the federated filter is the centralized one for any sharing factors."""
    rng = np.random.default_rng(4)
    layout = _layout()
    options = FederatedOptions(sharing=sharing, master_share=master_share)  # type: ignore[arg-type]
    fed = FederatedFilter(layout, [[], [], []], ["a", "b", "c"], options)
    ckf = CentralizedFilter(layout)
    for step in range(60):
        phi, qd = _random_system(rng)
        fed.predict(phi, qd)
        ckf.predict(phi, qd)
        plugin = step % 3
        h = rng.standard_normal((2, 15))
        r = np.diag(rng.uniform(0.01, 1.0, 2))
        z = rng.standard_normal(2)
        for bank in (fed, ckf):
            _, kf = bank.filter_of(plugin)
            kf.update(z, h, r)
        np.testing.assert_allclose(fed.feedback(step), ckf.feedback(step), rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(
            fed.estimate()[1], ckf.estimate()[1], rtol=1e-8, atol=1e-14, err_msg=f"step {step}"
        )


def _banks_with_an_owning_local(
    options: FederatedOptions, stored_errors: int = 0
) -> tuple[FederatedFilter, CentralizedFilter]:
    """Three locals, the first owning three states, and the CKF over the same layout."""
    own = StateBlock("a.bias", ("b1", "b2", "b3"), (0.2, 0.1, 0.05), (1e-4, 1e-4, 1e-4))
    layout = _layout().extended([own])
    names = ["a", "b", "c"]
    fed = FederatedFilter(layout, [["a.bias"], [], []], names, options, stored_errors=stored_errors)
    return fed, CentralizedFilter(layout, stored_errors)


def _owning_step(
    rng: np.random.Generator, step: int
) -> tuple[np.ndarray, np.ndarray, int, np.ndarray, np.ndarray, np.ndarray]:
    """Random Φ and Q_d (own states driven by the common ones) and one update (plugin, H, R, z)
    of the local ``step % 3``; only the first local's H sees the own states."""
    phi_c, qd_c = _random_system(rng)
    phi, qd = np.eye(18), np.zeros((18, 18))
    phi[:15, :15], qd[:15, :15] = phi_c, qd_c
    phi[15:, :15] = 0.05 * rng.standard_normal((3, 15))
    qd[15:, 15:] = np.diag(rng.uniform(1e-6, 1e-4, 3))
    plugin = step % 3
    h = np.zeros((2, 18))
    h[:, :15] = rng.standard_normal((2, 15))
    if plugin == 0:
        h[:, 15:] = rng.standard_normal((2, 3))
    r = np.diag(rng.uniform(0.01, 1.0, 2))
    return phi, qd, plugin, h, r, rng.standard_normal(2)


def _owning_round(
    fed: FederatedFilter, ckf: CentralizedFilter, rng: np.random.Generator, step: int
) -> None:
    """One :func:`_owning_step` through both banks, then :func:`_assert_same_round`."""
    phi, qd, plugin, h, r, z = _owning_step(rng, step)
    for bank in (fed, ckf):
        bank.predict(phi, qd)
        local_layout, kf = bank.filter_of(plugin)
        kf.update(z, h[:, : local_layout.dim], r)
    _assert_same_round(fed, ckf, step)


def _assert_same_round(fed: FederatedFilter, ckf: CentralizedFilter, step: int) -> None:
    """Feedback, estimate and covariance of the two banks agree."""
    np.testing.assert_allclose(fed.feedback(step), ckf.feedback(step), rtol=1e-8, atol=1e-12)
    x_f, p_f = fed.estimate()
    x_c, p_c = ckf.estimate()
    np.testing.assert_allclose(x_f, x_c, rtol=1e-8, atol=1e-12, err_msg=f"step {step}")
    np.testing.assert_allclose(p_f, p_c, rtol=1e-7, atol=1e-14, err_msg=f"step {step}")


@pytest.mark.parametrize("sharing", ["trace", "inverse_trace"])
def test_shares_follow_the_information_not_the_previous_shares(sharing: str) -> None:
    """Two locals holding the same information at unit share but with shares 0.9 and 0.1 (so
    their stored P_cc differ ninefold) get equal shares: the rule reads tr(β_i P_i,cc). Read
    from the stored P_cc, trace sharing would swap the shares at every fusion and let their
    ratio random-walk (BROAD trial 30: a share of 2e-10 and an overflowing covariance)."""
    layout = _layout()
    fed = FederatedFilter(layout, [[], []], ["a", "b"], FederatedOptions(sharing=sharing))
    p_unit = layout.initial_covariance()
    for f, beta in zip(fed.locals, (0.9, 0.1), strict=True):
        f.beta = beta
        f.kf.P = p_unit / beta
    fed.feedback(0.0)
    assert [f.beta for f in fed.locals] == pytest.approx([0.5, 0.5], rel=1e-12)
    np.testing.assert_allclose(fed.locals[0].kf.P, p_unit / 0.5, rtol=1e-9)  # P_g = P_unit


def test_fusion_reset_equals_centralized_with_a_local_owning_states() -> None:
    """A local with its own states (an odometer's mounting angles and scale, say) beside locals
    of common states only: propagating its own states' conditional at unit share keeps the
    federated filter equal to the centralized one, own states included."""
    rng = np.random.default_rng(5)
    fed, ckf = _banks_with_an_owning_local(FederatedOptions(sharing="trace"))
    for step in range(60):
        _owning_round(fed, ckf, rng, step)


@pytest.mark.parametrize("master_share", [0.0, 0.3])
def test_signatures_and_jumps_taken_in_match_the_centralized_filter(master_share: float) -> None:
    """Signature columns (fusion.jumps) are fused and reset like the estimates, and a jump taken
    in between rounds moves every local so that the fused result is the centralized filter's:
    columns, state and covariance equal to the CKF's to 1e-8, with a local owning states and a
    master share. (Within a round, after some locals have updated, it is as approximate as a
    second plugin's update in the same round.)"""
    rng = np.random.default_rng(11)
    options = FederatedOptions(sharing="trace", master_share=master_share)
    fed, ckf = _banks_with_an_owning_local(options)
    for step in range(60):
        phi, qd, plugin, h, r, z = _owning_step(rng, step)
        for bank in (fed, ckf):
            if step == 30:  # between rounds, where every local holds the fused estimate
                bank.accommodate(1, 0.7, 0.01)
            bank.predict(phi, qd)
            if step in (10, 20):  # a jump of the own state b2 and one of common state 4
                bank.add_signatures(np.eye(18)[:, [16, 4]])
            local_layout, kf = bank.filter_of(plugin)
            kf.update(z, h[:, : local_layout.dim], r)
            if step == 45:
                bank.keep_signatures(np.array([True, False, True, True]))
        _assert_same_round(fed, ckf, step)
        e_c = ckf.signatures_of(0)
        for f in fed.locals:  # after the reset every local holds the fused columns
            np.testing.assert_allclose(f.kf.signatures, e_c[f.index], rtol=1e-8, atol=1e-12)
    assert ckf.signatures_of(0).shape[1] == 3


@pytest.mark.parametrize("master_share", [0.0, 0.3])
def test_stored_errors_match_the_centralized_filter(master_share: float) -> None:
    """Estimates stored between rounds (as the engine's store epochs are, after the feedback)
    from a local owning states and from one that does not: every local's cross-covariances are
    the CKF's (own rows through the regression) through ordinary updates, fusion and reset.
    Updates whose noise carries a stored error (decorrelated in the local) keep the fusion
    exact when the local owning states makes them (steps 30–44). Made by a local without own
    states (from step 45), they reach the other local's own states only through its regression
    on the common states, where the CKF also uses the own states' own correlation with the
    stored error, and the estimates stay within 5 % of their σ."""
    rng = np.random.default_rng(12)
    options = FederatedOptions(sharing="trace", master_share=master_share)
    fed, ckf = _banks_with_an_owning_local(options, stored_errors=6)
    groups = (np.arange(3), np.arange(3, 6))
    for step in range(60):
        phi, qd, plugin, h, r, z = _owning_step(rng, step)
        carries = step >= 45 or (step >= 30 and plugin == 0)
        for bank in (fed, ckf):
            bank.predict(phi, qd)
            local_layout, kf = bank.filter_of(plugin)
            correlated, r_total = None, r
            if carries and plugin < 2:
                b = 0.5 * np.eye(2, 3)
                d = kf.stored_covariance[np.ix_(groups[step % 2], groups[step % 2])]
                correlated, r_total = CorrelatedNoise(groups[step % 2], b), r + b @ d @ b.T
            shared = bank.shared_covariance(plugin)  # as the engine passes it
            kf.update(z, h[:, : local_layout.dim], r_total, None, shared, correlated)
        if step < 45:
            _assert_same_round(fed, ckf, step)
        else:
            x_f, x_c = (
                np.concatenate([b.feedback(step), b.estimate()[0][15:]]) for b in (fed, ckf)
            )
            sigma = np.sqrt(np.diag(ckf.estimate()[1]))
            assert np.all(np.abs(x_f - x_c) < 0.05 * sigma)
            continue
        if step in (10, 20):  # local a (own states) stores at 10, local b at 20
            plugin = 0 if step == 10 else 1
            h_store = np.eye(18)[6:9]
            for bank in (fed, ckf):
                layout, _ = bank.filter_of(plugin)
                bank.store_error(plugin, groups[plugin], h_store[:, : layout.dim])
        c_ckf = ckf.filter_of(0)[1].cross
        for f in fed.locals:
            np.testing.assert_allclose(f.kf.cross, c_ckf[f.index], rtol=1e-7, atol=1e-12)


@pytest.fixture(scope="module")
def carrier_two_cycles(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("carrier") / "rec"
    simulate("seed000-carrier", out, seed=3, overrides=["face.cycles=2", "imu.grade=seed002-mems"])
    return out


def test_single_local_equals_centralized_end_to_end(carrier_two_cycles: Path) -> None:
    """One local holding every plugin, β = 1: the federated engine run is the CKF run, CPOEM's
    stored errors (cycle 2 measures against cycle 1) included."""
    rec = read_recording(carrier_two_cycles)
    config = load_config(CONFIGS / "sins_od_cpoem.yaml")
    data = config.model_dump()
    data["filter"]["architecture"] = "federated"
    for block in data["plugins"]:
        block["local"] = "all"
    ckf = Engine(config, rec).run()
    fed = Engine(parse_config(data), rec).run()
    assert ckf.innovations["cpoem"].dof.sum() > 30  # the stored points were measured against
    np.testing.assert_allclose(fed.solution.position, ckf.solution.position, atol=1e-7)
    np.testing.assert_allclose(fed.solution.sigma_position, ckf.solution.sigma_position, rtol=1e-9)
    np.testing.assert_allclose(fed.final_state, ckf.final_state, atol=1e-12)
    scale = np.abs(ckf.final_covariance).max()
    np.testing.assert_allclose(fed.final_covariance, ckf.final_covariance, atol=1e-11 * scale)


def test_stores_come_after_the_fusion(carrier_two_cycles: Path) -> None:
    """The engine calls a plugin's store after the instant's update round and feedback: in the
    federated filter (odometer, CPOEM and the face heading in a local each) the serving local
    then holds the fused estimate, zero in the common states, and every other local carries the
    same cross rows."""
    data = load_config(CONFIGS / "sins_od_cpoem.yaml").model_dump()
    data["filter"]["architecture"] = "federated"
    engine = Engine(parse_config(data), read_recording(carrier_two_cycles))
    plugin = engine.plugins[1]
    store = plugin.store
    calls: list[np.ndarray] = []

    def checked(index: int, ctx: MeasurementContext) -> StoredEstimate | None:
        calls.append(ctx.x[:15].copy())
        return store(index, ctx)

    plugin.store = checked  # type: ignore[method-assign]
    stored = engine.filter_bank
    banks: list[FederatedFilter] = []

    def keep_bank() -> FilterBank:
        bank = stored()
        assert isinstance(bank, FederatedFilter)
        banks.append(bank)
        return bank

    engine.filter_bank = keep_bank  # type: ignore[method-assign]
    engine.run()
    assert len(calls) == plugin.store_epochs().size > 30
    np.testing.assert_array_equal(np.array(calls), 0.0)
    first, *others = banks[0].locals
    assert len(others) == 2
    for local in others:
        np.testing.assert_allclose(local.kf.cross[:15], first.kf.cross[:15], rtol=1e-6, atol=1e-12)


@pytest.mark.parametrize("invariant_error", ["none", "heading"])
def test_five_source_partition_tracks_the_centralized_filter(
    tmp_path: Path, invariant_error: str
) -> None:
    """full_afkf without fault isolation against full_ckf: four locals (the kinematic one owns
    the odometer's states), adaptive magnetometer and UWB noise, gates. Each local's updates are
    exact in information form; what differs is second order — the second plugin of a local in
    one round is judged against a covariance that counts the first one's information 1/β_i
    times, and a local's plugins linearize without the other locals' updates of that round.
    Each range at its own epoch (no ``epoch_grid_s``), as the shipped configs' 0.1-s grid puts
    the five ranges of a round into the odometer's and magnetometer's rounds, and these second
    order terms then reach 5 mm (against 2 cm horizontal RMS for both). Each anchor at 10 Hz
    (the preset's 40 Hz: the same, at four times the work). ``filter.observable_force`` off in
    both: with it a range update considers the heading (Schmidt, :mod:`fusion.aiding.uwb`), and a
    local's Schmidt update is not its measurement's information, which is what the fusion
    adds up (with it on the two tracks differ by 2 mm). The same with the covariances in the
    invariant error of the heading (:mod:`fusion.invariant_error`), which every local takes
    over its own index set."""
    simulate(
        "longwall-200m", tmp_path / "rec", seed=1, overrides=["duration_s=150", "uwb.rate_hz=10"]
    )
    rec = read_recording(tmp_path / "rec")
    fed_data = load_config(CONFIGS / "full_afkf.yaml").model_dump()
    fed_data["filter"]["federated"]["fault_detection"]["enabled"] = False
    ckf_data = load_config(CONFIGS / "full_ckf.yaml").model_dump()
    for data in (fed_data, ckf_data):
        data["filter"]["observable_force"] = False
        data["filter"]["invariant_error"] = invariant_error
        for block in data["plugins"]:
            block.pop("epoch_grid_s", None)
    fed = Engine(parse_config(fed_data), rec).run()
    ckf = Engine(parse_config(ckf_data), rec).run()
    assert np.abs(fed.solution.position - ckf.solution.position).max() < 1e-3
    np.testing.assert_allclose(fed.solution.sigma_position, ckf.solution.sigma_position, rtol=2e-3)


@pytest.fixture(scope="module")
def longwall_60s(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("lw") / "rec"
    simulate("longwall-200m", out, seed=2, overrides=["duration_s=60"])
    return out


def _full_afkf(**federated: object) -> dict:
    data = load_config(CONFIGS / "full_afkf.yaml").model_dump()
    data["filter"]["federated"].update(federated)
    return data


def test_fusing_at_every_covariance_step_changes_nothing(longwall_60s: Path) -> None:
    """The default fuses only after steps that carried an update: after a step of prediction
    alone the fusion-reset locals fuse to the propagated global estimate, so fusing at every
    covariance step (the issue's default) gives the same run."""
    rec = read_recording(longwall_60s)
    default = Engine(parse_config(_full_afkf()), rec).run()
    every_step = Engine(parse_config(_full_afkf(fusion_period_s=1e-6)), rec).run()
    np.testing.assert_allclose(every_step.solution.position, default.solution.position, atol=1e-6)
    np.testing.assert_allclose(
        every_step.solution.sigma_position, default.solution.sigma_position, rtol=1e-6
    )


def test_no_reset_needs_equal_shares_and_runs(longwall_60s: Path) -> None:
    """Without resets the locals keep equal shares (a recomputed share would rescale a
    covariance built under the old one): the configuration refuses a sharing rule that only a
    reset can hand out, and with equal shares the fused solution stays near the reset one."""
    with pytest.raises(ConfigError, match="no_reset"):
        parse_config(_full_afkf(mode="no_reset"))
    rec = read_recording(longwall_60s)
    reset = Engine(parse_config(_full_afkf()), rec).run()
    no_reset = Engine(parse_config(_full_afkf(mode="no_reset", sharing="equal")), rec).run()
    assert np.abs(no_reset.solution.position - reset.solution.position).max() < 0.1
    assert np.all(np.isfinite(no_reset.solution.sigma_position))


def test_reset_carries_own_states_as_a_conditional() -> None:
    """Resetting the common states moves a local's own states along their regression on them,
    and leaves the covariance positive definite."""
    rng = np.random.default_rng(8)
    layout = _layout()
    fed = FederatedFilter(layout.extended([]), [[]], ["a"], FederatedOptions(sharing="equal"))
    f = fed.locals[0]
    a = rng.standard_normal((15, 15))
    f.kf.P = a @ a.T + np.eye(15)
    f.kf.x = rng.standard_normal(15)
    x_g = rng.standard_normal(15)
    f.reset(x_g, 0.5 * f.kf.P[:15, :15], np.zeros((15, 0)))
    np.testing.assert_array_equal(f.kf.x, 0.0)
    np.linalg.cholesky(f.kf.P)


def _monitor(**kw: float) -> FaultMonitor:
    return FaultMonitor("mag", FaultDetectionOptions(window_s=5.0, hold_s=10.0, **kw))


def test_monitor_quiet_on_consistent_innovations() -> None:
    """χ²(1) innovations at 10 Hz for an hour: about one false isolation per hour."""
    rng = np.random.default_rng(1)
    mon = _monitor()
    t = np.arange(0.0, 3600.0, 0.1)
    events = [mon.observe(ti, float(rng.chisquare(1)), 1, False) for ti in t]
    isolations = sum(e is not None and e.action == ISOLATE for e in events)
    assert isolations <= 3


def test_monitor_isolates_a_burst_and_readmits_after_hold() -> None:
    rng = np.random.default_rng(2)
    mon = _monitor()
    events = []
    for ti in np.arange(0.0, 120.0, 0.1):
        nis = float(rng.chisquare(1)) * (25.0 if 40.0 <= ti < 60.0 else 1.0)
        e = mon.observe(ti, nis, 1, False)
        if e is not None:
            events.append(e)
    assert [e.action for e in events] == [ISOLATE, READMIT]
    assert 40.0 <= events[0].t < 42.0
    # The burst leaves the window 5 s after it ends; then 10 s of hold.
    assert 60.0 + 10.0 <= events[1].t < 60.0 + 5.0 + 10.0 + 1.0


def test_mean_test_finds_a_bias_the_chi_square_sum_misses() -> None:
    """A 1σ bias on one of three whitened components for 10 s at 10 Hz raises the 5-s χ² sum
    by a third of its degrees of freedom, under its threshold; the windowed mean sees it. An
    hour of consistent innovations raises no more than a few isolations."""
    rng = np.random.default_rng(3)
    events = {}
    for mean_test in (False, True):
        mon = FaultMonitor("odo", FaultDetectionOptions(mean_test=mean_test))
        found = []
        for ti in np.arange(0.0, 60.0, 0.1):
            w = rng.standard_normal(3) + (1.0 if 30.0 <= ti < 40.0 else 0.0) * np.eye(3)[0]
            e = mon.observe(ti, float(w @ w), 3, False, "odometer", w)
            if e is not None:
                found.append(e)
        events[mean_test] = found
    assert events[False] == []
    assert events[True][0].action == ISOLATE and 30.0 < events[True][0].t < 36.0
    assert events[True][0].reason == "window mean of odometer"
    quiet = FaultMonitor("odo", FaultDetectionOptions())
    isolations = 0
    for ti in np.arange(0.0, 3600.0, 0.1):
        w = rng.standard_normal(3)
        e = quiet.observe(ti, float(w @ w), 3, False, "odometer", w)
        isolations += e is not None and e.action == ISOLATE
    assert isolations <= 3


def _ar1(rng: np.random.Generator, n: int, rho: float, dof: int) -> np.ndarray:
    """Unit-variance AR(1) sequences, one per column."""
    w = np.empty((n, dof))
    w[0] = rng.standard_normal(dof)
    for k in range(1, n):
        w[k] = rho * w[k - 1] + np.sqrt(1 - rho**2) * rng.standard_normal(dof)
    return w


def test_mean_test_allows_for_serially_correlated_innovations() -> None:
    """Innovations correlated like BROAD's optical fixes (lag-1 ρ = 0.95 at 10 Hz) raise no
    isolation in an hour: the monitor learns how far ‖Σw‖²/n spreads while it passes (f ≈ 28
    here) and ρ for the χ² sum. A 6σ bias on one component of the same sequence for 10 s is
    still found within the window."""
    rng = np.random.default_rng(8)
    times = np.arange(0.0, 3600.0, 0.1)
    w = _ar1(rng, times.size, 0.95, 3)
    quiet = FaultMonitor("fix", FaultDetectionOptions())
    events = [
        quiet.observe(t, float(v @ v), 3, False, "position", v)
        for t, v in zip(times, w, strict=True)
    ]
    assert [e for e in events if e is not None] == []
    biased = FaultMonitor("fix", FaultDetectionOptions())
    found = []
    for t, v in zip(times[:1200], w[:1200], strict=True):
        v = v + (6.0 if 60.0 <= t < 70.0 else 0.0) * np.eye(3)[0]
        e = biased.observe(t, float(v @ v), 3, False, "position", v)
        if e is not None:
            found.append(e)
    assert found and found[0].action == ISOLATE and 60.0 < found[0].t < 66.0


def test_monitor_isolates_on_a_persistent_plugin_indicator() -> None:
    """A flag that comes and goes only down-weights (the plugin's doing); one that persists for
    indicator_confirm_s (2 s) isolates."""
    mon = _monitor()
    assert mon.observe(0.0, 0.5, 1, False) is None
    for k in range(19):  # 1.9 s of flags, then a clean epoch: nothing
        assert mon.observe(0.1 * (k + 1), 0.5, 1, True) is None
    assert mon.observe(2.0, 0.5, 1, False) is None
    events = [mon.observe(2.1 + 0.1 * k, 0.5, 1, True) for k in range(22)]
    event = events[-1]  # 2.1 s after the first flag (2.0 s lands a rounding short of it)
    assert events[:-1] == [None] * 21
    assert event is not None and event.action == ISOLATE and event.reason == "plugin indicator"


def test_dead_reckoning_config_runs_and_refuses_plugins(tmp_path: Path) -> None:
    """dr_traditional integrates the odometer along the free attitude; plugins are an error."""
    simulate("seed000-carrier", tmp_path / "rec", seed=5, overrides=["face.cycles=1"])
    rec = read_recording(tmp_path / "rec")
    config = load_config(CONFIGS / "dr_traditional.yaml")
    result = Engine(config, rec).run()
    assert rec.odometer is not None and config.streams.odometer_max_rate_hz is not None
    odometer = combine_readings(rec.odometer, config.streams.odometer_max_rate_hz)
    np.testing.assert_array_equal(result.solution.t[1:], odometer.t[odometer.t > rec.imu.t[0]])
    travelled = np.abs(odometer.speed[1:] * np.diff(odometer.t)).sum()
    path = np.linalg.norm(np.diff(result.solution.position, axis=0), axis=1).sum()
    assert path == pytest.approx(travelled, rel=0.01)
    data = config.model_dump()
    data["plugins"] = [{"type": "odometer"}]
    with pytest.raises(ConfigError, match="dead_reckoning uses no plugins"):
        parse_config(data)


def test_standalone_architecture_needs_exactly_one_plugin() -> None:
    base = {"name": "x", "filter": {"architecture": "standalone"}}
    with pytest.raises(ConfigError, match="exactly one plugin"):
        parse_config({**base, "plugins": []})
    with pytest.raises(ConfigError, match="exactly one plugin"):
        parse_config({**base, "plugins": [{"type": "uwb"}, {"type": "odometer"}]})
    assert parse_config({**base, "plugins": [{"type": "uwb"}]}).filter.architecture == "standalone"


def _result(nis: float) -> UpdateResult:
    w = np.array([np.sqrt(nis)])
    return UpdateResult(True, w, w, nis, None, np.eye(1))


def test_the_only_local_that_holds_the_sins_is_kept_in_the_fusion_while_it_is_the_only_one() -> (
    None
):
    """A local failing its χ² test is isolated, but while no other healthy local holds the SINS
    (velocity or position) it stays a member: a MEMS SINS left to coast drifts further than a
    sensor's fault pulls (harsh random worlds: the odometer local of sins_od_mag_afkf isolated
    at a degraded IMU's static start, 24 m of horizontal RMS against the CKF's 1.4 m). Once
    another local holds it, the isolation takes effect."""
    options = FederatedOptions(fault_detection=FaultDetectionOptions(window_s=5.0, hold_s=60.0))
    fed = FederatedFilter(_layout(), [[], []], ["kinematic", "magnetic"], options, ["odo", "mag"])
    events = []
    for t in np.arange(0.0, 30.0, 0.1):
        nis = 400.0 if t >= 20.0 else 1.0
        fed.record(0, t, _result(nis), False, holds=True)
        fed.record(1, t, _result(1.0), False, holds=False)
        events += fed.faults[len(events) :]
    assert [e.action for e in events] == [ISOLATE]
    assert LAST_HOLDER in events[0].reason
    assert fed.in_fusion(0) and fed.in_fusion(1)
    fed.record(1, 30.0, _result(1.0), False, holds=True)  # the other local now holds the SINS
    assert not fed.in_fusion(0) and fed.in_fusion(1)
