"""Zhao's UKF and multi-UKF on the cybernetic driver model; Algorithm 3; the Gramian."""

import dataclasses
import json
import math
import re

import numpy as np
import pytest
import scipy.linalg

from manualcontrol.envs.schedules import Ramp
from manualcontrol.estimators import MultiUKF, ZhaoUKF, ZhaoUKFSettings, observability_gramian
from manualcontrol.estimators.analysis.metrics import nrmse
from manualcontrol.estimators.members.zhao_ukf import (
    FastMemberSettings,
    FusionSettings,
    MultiUKFSettings,
    ZhaoNoiseSettings,
    zhao_tuning,
)
from manualcontrol.estimators.offline.smoothing import smooth
from manualcontrol.estimators.registry import ESTIMATORS, make_estimator
from manualcontrol.estimators.settings import GuardSettings
from manualcontrol.pilots.driver import Driver
from manualcontrol.pilots.driving import simulate_driving

TABLE_2 = np.array([3.4, 15.0, 1.0, 3.0, 0.04, 1.0, 12.0, 0.1])
BOTH_RISING = {"K_p": Ramp(3.4, 4.42, 40.0, 70.0), "K_c": Ramp(15.0, 19.5, 110.0, 140.0)}
SIGNALS = ("theta_far", "theta_near", "delta_d", "Gamma_s")


@pytest.fixture(scope="module")
def both_rising():
    return simulate_driving(Driver(BOTH_RISING))


@pytest.fixture(scope="module")
def short_drive():
    return simulate_driving(Driver({"K_p": Ramp(3.4, 4.0, 2.0, 6.0)}), measurement_time=8.0)


# -------------------------------------------------------------------- Algorithm 3


def test_observer_poles_of_zhaos_tuning_at_1_ms():
    """Eq. 18 with eq. 17 at T_s = 1 ms: the paper's "-1, -10, -50"."""
    poles = zhao_tuning(ZhaoUKFSettings(), 0.001, 18.0).observer_poles()
    np.testing.assert_allclose(poles.real, [-51.40, -10.16, -1.103], rtol=2e-3)
    np.testing.assert_allclose(poles.imag, 0.0, atol=1e-9)


def test_tuning_rules_and_their_conversion_to_the_sample_time():
    settings = ZhaoUKFSettings(preset="ukf2", estimated=("K_p", "K_c", "T_N"))
    tuning = zhao_tuning(settings, 0.01, 17.0)
    np.testing.assert_allclose(np.diag(tuning.R_d_reference), [9e-4, 25e-4])
    np.testing.assert_allclose(tuning.R_d, tuning.R_d_reference * 0.1)  # R_d = R/T_s, eq. 6
    np.testing.assert_allclose(tuning.Q_theta_reference, 1e-6 * np.array([3.4, 15.0, 0.1]) ** 2)
    np.testing.assert_allclose(
        np.diag(tuning.Q)[3:], tuning.Q_theta_reference * 10.0
    )  # Q_d = T_s Q
    np.testing.assert_allclose(tuning.Q_x_reference @ tuning.gramian, 1e-7 * np.eye(3), atol=1e-15)
    assert tuning.substeps == 10
    # eq. 13 from the outputs' largest magnitudes
    ratios = zhao_tuning(ZhaoUKFSettings(output_error_ratios=(0.1, 0.05)), 0.01, 17.0, (4.0, 0.2))
    np.testing.assert_allclose(np.diag(ratios.R_d_reference), [(0.1 * 4.0) ** 2, (0.05 * 0.2) ** 2])


def test_observability_gramian_against_the_sum():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(4, 4))
    A *= 0.9 / np.max(np.abs(np.linalg.eigvals(A)))
    C = rng.normal(size=(2, 4))
    brute = np.zeros((4, 4))
    power = np.eye(4)
    for _ in range(600):
        brute += (C @ power).T @ (C @ power)
        power = A @ power
    np.testing.assert_allclose(observability_gramian(A, C), brute, rtol=1e-10, atol=1e-12)
    first = (C.T @ C) + (C @ A).T @ (C @ A) + (C @ A @ A).T @ (C @ A @ A)
    np.testing.assert_allclose(observability_gramian(A, C, horizon=3), first, rtol=1e-12)
    unstable = 1.1 * np.eye(2)
    assert observability_gramian(unstable, np.eye(2), horizon=2) == pytest.approx(
        np.eye(2) * (1 + 1.21)
    )
    with pytest.raises(
        ValueError, match=re.escape("needs A stable (spectral radius < 1), got 1.1")
    ):
        observability_gramian(unstable, np.eye(2))
    with pytest.raises(ValueError, match=re.escape("C must have shape (m, 4), got (2, 3)")):
        observability_gramian(A, C[:, :3])


# ----------------------------------------------------------------- the filter itself


def _oracle_matrices(p, v):
    K_p, K_c, T_I, T_L, tau, K_r, K_t, T_N = p
    g, c, lead = K_r * v + K_t, K_c / v, T_L / T_I
    A = np.array(
        [
            [-1 / T_I, 0, 0],
            [c * 2 / tau * (1 - lead), -2 / tau, 0],
            [-g * c * (1 - lead) / T_N, 2 * g / T_N, -1 / T_N],
        ]
    )
    B = np.array(
        [
            [0, 1 / T_I, 0, 0],
            [K_p * 2 / tau, c * 2 / tau * lead, 0, 0],
            [-K_p * g / T_N, -g * c * lead / T_N, -K_t / T_N, -1 / T_N],
        ]
    )
    C = np.array([[0, 0, 1], [-c * (1 - lead), 2, 0]])
    D = np.array([[0, 0, 0, 0], [-K_p, -c * lead, 0, 0]])
    return A, B, C, D


def _oracle_ukf(recording, q_theta):
    """Zhao Algorithms 1-2 with eq. 6 (ten Euler steps a sample), plain numpy."""
    v, dt, ts = recording.metadata["speed"], recording.dt, 0.001
    A0, _, C0, _ = _oracle_matrices(TABLE_2, v)
    Ad = np.eye(3) + ts * A0
    gramian = scipy.linalg.solve_discrete_lyapunov(Ad.T, C0.T @ C0)
    Q = np.zeros((5, 5))
    Q[:3, :3] = 1e-7 * np.linalg.inv(gramian) * dt / ts
    Q[3:, 3:] = np.diag(q_theta * TABLE_2[:2] ** 2 * dt / ts)
    R = np.diag([9e-4, 25e-4]) * ts / dt
    x = np.array([0, 0, 0, 3.4, 15.0])
    P = np.diag([1e-2, 1e-2, 1e-2, 0.34**2, 1.5**2])
    u_all = np.column_stack([recording[n] for n in SIGNALS])
    y_all = np.column_stack([recording["Gamma_d"], recording["delta_sw"]])

    def points(x, P):
        root = np.linalg.cholesky(P) * math.sqrt(5)
        return np.vstack([x + root.T, x - root.T])

    def parameters(point):
        return np.concatenate([point[3:], TABLE_2[2:]])

    posterior = []
    for u, y in zip(u_all, y_all, strict=True):
        X = points(x, P)
        Z = np.array(
            [
                _oracle_matrices(parameters(p), v)[2] @ p[:3]
                + _oracle_matrices(parameters(p), v)[3] @ u
                for p in X
            ]
        )
        z = Z.mean(axis=0)
        S = (Z - z).T @ (Z - z) / 10 + R
        Cxz = (X - x).T @ (Z - z) / 10
        K = np.linalg.solve(S, Cxz.T).T
        x = x + K @ (y - z)
        P = P - K @ Cxz.T
        posterior.append(x.copy())
        X = points(x, P)
        Y = []
        for p in X:
            A, B, _, _ = _oracle_matrices(parameters(p), v)
            state = p[:3].copy()
            for _ in range(10):
                state = state + 0.001 * (A @ state + B @ u)
            Y.append(np.concatenate([state, p[3:]]))
        Y = np.array(Y)
        x = Y.mean(axis=0)
        P = (Y - x).T @ (Y - x) / 10 + Q
    return np.array(posterior)


@pytest.mark.parametrize("preset", ["ukf1", "ukf2"])
def test_ukf_equals_a_plain_numpy_ukf(short_drive, preset):
    recording = short_drive.slice_samples(0, 300)
    result = ZhaoUKF(preset=preset).estimate(recording)
    expected = _oracle_ukf(recording, 1e-8 if preset == "ukf1" else 1e-6)
    np.testing.assert_allclose(result.mean_of("K_p"), expected[:, 3], rtol=1e-10)
    np.testing.assert_allclose(result.mean_of("K_c"), expected[:, 4], rtol=1e-10)
    np.testing.assert_allclose(result.states, expected[:, :3], rtol=1e-8, atol=1e-12)


def _samples(recording):
    names = (*SIGNALS, "Gamma_d", "delta_sw")
    return [
        dict(zip(names, (float(recording[n][k]) for n in names), strict=True))
        for k in range(len(recording))
    ]


@pytest.mark.parametrize("make", [lambda: ZhaoUKF(preset="ukf2"), lambda: MultiUKF()])
def test_update_equals_estimate(short_drive, make):
    recording = short_drive.slice_samples(0, 400).with_signals(
        theta_near=np.where(np.arange(400) % 97 == 5, np.nan, short_drive["theta_near"][:400])
    )
    result = make().estimate(recording)
    online = make()
    online.reset(recording.dt, speed=recording.metadata["speed"], t0=float(recording.t[0]))
    estimates = [online.update(sample) for sample in _samples(recording)]
    np.testing.assert_array_equal([e.mean["K_c"] for e in estimates], result.mean_of("K_c"))
    np.testing.assert_array_equal([e.innovations for e in estimates], result.innovations)
    np.testing.assert_array_equal([e.health.dropped for e in estimates], result.dropped)
    assert result.dropped.sum() == 5 and np.isnan(result.innovation[result.dropped]).all()


def test_remnant_free_accuracy_and_the_straight(both_rising):
    """Done when: NRMSE <= 0.10 after 20 s; within 2 % on the straight (74-89 s)."""
    after = both_rising.t >= 20.0
    straight = (both_rising.t >= 76.0) & (both_rising.t <= 89.0)
    for preset in ("ukf1", "ukf2"):
        result = ZhaoUKF(preset=preset).estimate(both_rising)
        assert not result.health.diverged
        for name in ("K_p", "K_c"):
            truth = both_rising.parameters[name]
            assert nrmse(result.mean_of(name)[after], truth[after]) < 0.02
            on_straight = result.mean_of(name)[straight]
            assert np.max(np.abs(on_straight / on_straight[0] - 1.0)) < 0.02


def test_smoothing_removes_the_lag(both_rising):
    result = ZhaoUKF().estimate(both_rising, smoother_inputs=True)
    smoothed = smooth(result)
    ramp = (both_rising.t > 110) & (both_rising.t < 140)
    truth = both_rising.parameters["K_c"][ramp]
    assert nrmse(smoothed.mean_of("K_c")[ramp], truth) < 0.5 * nrmse(
        result.mean_of("K_c")[ramp], truth
    )


def test_divergence_is_reported_not_silent(short_drive):
    broken = short_drive.with_signals(
        Gamma_d=np.where(short_drive.t > 2.0, 1e300, short_drive["Gamma_d"])
    )
    result = ZhaoUKF().estimate(broken)
    assert result.health.diverged and result.health.stopped
    assert result.health.divergence_time == pytest.approx(2.01, abs=0.02)
    assert np.all(np.isfinite(result.mean))


def test_the_family_knows_them():
    assert {"zhao-ukf", "zhao-multi-ukf"} <= set(ESTIMATORS)
    ukf = make_estimator({"name": "zhao-ukf", "preset": "ukf2", "estimated": ["K_c"]})
    assert isinstance(ukf, ZhaoUKF) and ukf.settings.estimated == ("K_c",)
    multi = make_estimator({"name": "zhao-multi-ukf", "dead_zone": 0.0})
    assert isinstance(multi, MultiUKF) and multi.settings.members()[1].preset == "ukf2"


FLAT_NOISE = {
    "output_error_ratios": (0.08, 0.05),
    "Q_x_scale": 0.1,
    "Q_theta_scale": 1e-9,
    "Q_theta": {"K_c": 1e-3},
    "reference_dt": 0.002,
    "gramian_horizon": 5.0,
    "P0_states": 0.02,
    "P0_fraction": 0.2,
}
FLAT_MULTI = {
    **FLAT_NOISE,
    "jitter": 1e-9,
    "smoothing_time": 1.0,
    "level_time": 100.0,
    "dead_zone": 0.0,
    "feedback": False,
    "fast_preset": "ukf1",
    "fast_Q_theta_scale": 1e-5,
}


def test_flat_keys_and_the_nested_form_build_the_same_settings():
    noise = ZhaoNoiseSettings(**FLAT_NOISE)
    flat = ZhaoUKFSettings(preset="ukf2", **FLAT_NOISE)
    assert flat == ZhaoUKFSettings(preset="ukf2", noise=noise)
    assert flat == ZhaoUKFSettings.from_dict({"preset": "ukf2", "noise": dict(FLAT_NOISE)})
    assert flat == make_estimator({"name": "zhao-ukf", "preset": "ukf2", **FLAT_NOISE}).settings
    assert flat.replace(P0_states=0.5).noise == dataclasses.replace(noise, P0_states=0.5)

    multi = MultiUKFSettings(**FLAT_MULTI)
    nested = MultiUKFSettings(
        noise=noise,
        guard=GuardSettings(jitter=1e-9, pinned_time=math.inf),
        fusion=FusionSettings(smoothing_time=1.0, level_time=100.0, dead_zone=0.0, feedback=False),
        fast=FastMemberSettings(preset="ukf1", Q_theta_scale=1e-5),
    )
    tables = MultiUKFSettings.from_dict(
        {
            "noise": dict(FLAT_NOISE),
            "guard": {"jitter": 1e-9},
            "fusion": {"smoothing_time": 1, "level_time": 100, "dead_zone": 0, "feedback": False},
            "fast": {"preset": "ukf1", "Q_theta_scale": 1e-5},
        }
    )
    assert multi == nested == tables
    assert multi == make_estimator({"name": "zhao-multi-ukf", **FLAT_MULTI}).settings
    with pytest.raises(ValueError, match=r"fast_preset and fast\.preset, one setting"):
        MultiUKFSettings.from_dict({"fast": {"preset": "ukf1"}, "fast_preset": "ukf2"})
    with pytest.raises(ValueError, match=re.escape("fast_preset must be one of 'ukf1', 'ukf2'")):
        MultiUKFSettings(fast_preset="ukf3")


def test_the_multi_ukf_members_keep_their_settings():
    slow, fast = MultiUKFSettings(**FLAT_MULTI).members()
    assert type(slow) is type(fast) is ZhaoUKFSettings
    assert slow == ZhaoUKFSettings(jitter=1e-9, **FLAT_NOISE)
    assert fast == slow.replace(preset="ukf1", Q_theta_scale=1e-5)
    # the fast member's Q_theta_scale is its own: None takes its preset's, not the slow one's
    _, fast = MultiUKFSettings(Q_theta_scale=1e-9).members()
    assert fast.preset == "ukf2" and fast.noise.Q_theta_scale is None


def test_to_dict_writes_the_nested_form_and_round_trips():
    settings = MultiUKFSettings(**FLAT_MULTI)
    data = json.loads(json.dumps(settings.to_dict()))
    assert data["noise"] == {
        **FLAT_NOISE,
        "R_d": None,
        "output_error_ratios": [0.08, 0.05],
    }
    assert data["fusion"] == {
        "smoothing_time": 1.0,
        "level_time": 100.0,
        "dead_zone": 0.0,
        "feedback": False,
    }
    assert data["fast"] == {"preset": "ukf1", "Q_theta_scale": 1e-5}
    assert data["guard"]["pinned_time"] == "inf"
    assert set(data) == {item.name for item in dataclasses.fields(MultiUKFSettings)}
    assert not set(FLAT_MULTI) & set(data)
    assert MultiUKFSettings.from_dict(data) == settings
    single = ZhaoUKFSettings(**FLAT_NOISE)
    assert ZhaoUKFSettings.from_dict(json.loads(json.dumps(single.to_dict()))) == single


def test_settings_round_trip_and_bad_values():
    settings = MultiUKFSettings(
        limits={"K_p": (1.0, math.inf)}, Q_theta={"K_c": 1e-3}, dead_zone=0.01
    )
    assert MultiUKFSettings.from_dict(settings.to_dict()) == settings
    cases = [
        ({"preset": "ukf3"}, ValueError, "preset must be one of 'ukf1', 'ukf2', got 'ukf3'"),
        ({"estimated": ("K_x",)}, ValueError, "estimated parameter must be one of"),
        ({"estimated": "K_p"}, TypeError, "estimated must be a tuple of parameter names"),
        ({"R_d": (1e-3, -1.0)}, ValueError, "R_d[1] must be > 0, got -1.0"),
        (
            {"R_d": (1.0, 1.0), "output_error_ratios": (0.1, 0.1)},
            ValueError,
            "give R_d or output_error_ratios",
        ),
        ({"Q_theta": {"T_N": 1.0}}, ValueError, "Q_theta names 'T_N', which is not estimated"),
        ({"limits": {"K_p": (2.0, 1.0)}}, ValueError, "limits['K_p'] must satisfy low < high"),
        ({"substeps": 0}, ValueError, "substeps must be >= 1, got 0"),
    ]
    for kwargs, error, message in cases:
        with pytest.raises(error, match=re.escape(message)):
            ZhaoUKFSettings(**kwargs)
    with pytest.raises(
        TypeError, match=re.escape("ZhaoUKFSettings.from_dict got unknown key(s) 'Q'")
    ):
        ZhaoUKFSettings.from_dict({"Q": 1.0})
    with pytest.raises(ValueError, match=re.escape("reset needs the car's speed")):
        ZhaoUKF().reset(0.01)
    with pytest.raises(ValueError, match="the recording lacks 'Gamma_d'"):
        ZhaoUKF().estimate(simulate_driving(Driver(), steering="angle", measurement_time=1.0))


def test_docstring_example():
    import doctest

    from manualcontrol.estimators.members import zhao_ukf

    results = doctest.testmod(zhao_ukf)
    assert results.attempted >= 1 and results.failed == 0
