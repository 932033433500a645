"""Every metric against an answer computed by hand (written before the metrics were relied on).

The resimulations use the pure gain and delay pilot ``u(t) = K_p e(t - tau_v)``: with
the delay a whole number of samples and perceptions held over each sample, the
isolated model's output is the error shifted by that many samples and scaled, zero
before (it starts at rest), so every VAF below can be written down from the numbers.
Nothing of the package computes the expected values.
"""

import math

import numpy as np
import pytest

from manualcontrol.envs.recording import Recording
from manualcontrol.estimators.analysis.metrics import (
    evaluate,
    innovation_cost,
    innovation_fractions,
    innovation_whiteness,
    moving_vaf,
    nrmse,
    relative_bias,
    resimulate,
    resimulate_parameters,
    vaf,
)
from manualcontrol.estimators.protocol import EstimationResult, HealthSummary

DT = 0.01
SHIFT = 3  # tau_v = 0.03 s: three samples


def test_vaf_divides_by_the_power_of_the_reference_not_its_variance():
    # eq. 38: 1 - sum (u - u_hat)^2 / sum u^2; a constant u has power but no variance
    assert vaf([2.0, 2.0], [1.0, 1.0]) == pytest.approx(75.0)
    assert vaf([1.0, -1.0, 2.0], [0.0, -1.0, 0.0]) == pytest.approx(100.0 * (1 - 5.0 / 6.0))
    # the reference is the first argument: swapping them changes the answer
    assert vaf([1.0, 1.0], [2.0, 2.0]) == pytest.approx(0.0)


def test_a_diverged_model_scores_minus_infinity_without_a_warning():
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert vaf([1.0, -1.0], [1e200, 0.0]) == -math.inf


def test_moving_vaf_by_hand():
    u = np.array([1.0, 2.0, 2.0, 1.0])
    u_hat = np.array([1.0, 1.0, 2.0, 0.0])
    moving = moving_vaf(u, u_hat, dt=0.5, window=1.0)  # two samples a window
    assert math.isnan(moving[0])
    np.testing.assert_allclose(
        moving[1:], [100 * (1 - 1 / 5), 100 * (1 - 1 / 8), 100 * (1 - 1 / 5)]
    )


def test_relative_bias_has_the_sign_of_the_error_and_divides_by_the_magnitude():
    truth = np.array([1.0, 3.0])  # mean 2
    assert relative_bias([2.0, 3.0], truth) == pytest.approx(0.25)  # overestimated: +
    assert relative_bias([0.0, 3.0], truth) == pytest.approx(-0.25)  # underestimated: -
    # a negative parameter overestimated in magnitude: error -0.2, |mean| 2
    assert relative_bias([-2.2, -2.2], [-2.0, -2.0]) == pytest.approx(-0.1)
    assert nrmse([-2.2, -2.2], [-2.0, -2.0]) == pytest.approx(0.1)


def test_nrmse_normalises_by_the_mean_truth_not_sample_by_sample():
    # errors 1 and 0: RMS sqrt(1/2), over |mean truth| = 2 (sample-wise: sqrt(1/2)/1)
    assert nrmse([2.0, 3.0], [1.0, 3.0]) == pytest.approx(math.sqrt(0.5) / 2.0)
    # near-zero truth (thesis Part II eq. 5.7): the plain RMSE and mean error
    assert nrmse([0.03, -0.01], [0.0, 0.0]) == pytest.approx(math.sqrt((0.0009 + 0.0001) / 2))
    assert relative_bias([0.03, -0.01], [0.0, 0.0]) == pytest.approx(0.01)


def test_innovation_fractions_by_hand():
    within_1, within_2 = innovation_fractions([0.5, 1.5, -2.5, -0.9], [1.0, 1.0, 1.0, 1.0])
    assert (within_1, within_2) == (0.5, 0.75)
    within_1, within_2 = innovation_fractions([1.9, 3.0], [4.0, 1.0])  # sigma 2 and 1
    assert (within_1, within_2) == (0.5, 0.5)


def test_innovation_cost_by_hand():
    # mean of ln S + nu^2 / S over the samples with a finite nu and a positive S
    cost = innovation_cost([1.0, 2.0, math.nan, 3.0], [1.0, 4.0, 1.0, 0.0])
    assert cost == pytest.approx((0.0 + 1.0 + math.log(4.0) + 1.0) / 2.0)
    # a larger innovation costs more, a variance that explains it costs less
    assert innovation_cost([2.0], [1.0]) > innovation_cost([1.0], [1.0])
    assert innovation_cost([2.0], [4.0]) < innovation_cost([2.0], [1.0])
    assert math.isnan(innovation_cost([math.nan], [1.0]))


def test_innovation_whiteness_by_hand():
    z = np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0])  # mean 0, sum z^2 = 6
    r1, outside = innovation_whiteness(z, np.ones(6), max_lag=2)
    assert r1 == pytest.approx(-5.0 / 6.0)
    # r_2 = 4/6 lies inside the band 1.96/sqrt(6) = 0.80, r_1 outside: half the lags
    assert outside == 0.5
    # the innovations are normalised by their predicted standard deviation first
    r1_scaled, _ = innovation_whiteness(z * np.array([1, 2, 1, 2, 1, 2]), [1, 4, 1, 4, 1, 4], 2)
    assert r1_scaled == pytest.approx(r1)


# ------------------------------------------------------------------ resimulations


def _recording(with_remnant_parts=True, gain=2.0):
    """A compensatory run of the gain-delay pilot, written by hand.

    The remnant-free error is ``e_free``; the remnant moves the output by ``y_n`` (so
    the recorded error is ``e_free - y_n``) and the stick by ``u_n``. The stick is the
    pilot's response to the error it saw plus what the remnant added on top.
    """
    n = 12
    t = np.arange(n) * DT
    e_free = np.array([1.0, 2.0, 0.0, -1.0, 3.0, 1.0, -2.0, 0.0, 1.0, 2.0, -1.0, 0.5])
    y_n = np.array([0.0, 0.5, 1.0, -0.5, 0.0, 1.5, 0.5, -1.0, 0.0, 0.5, 1.0, 0.0])
    e = e_free - y_n
    u_free = gain * np.concatenate([np.zeros(SHIFT), e_free[:-SHIFT]])
    u_n = np.array([0.0, 0.0, 0.0, 1.5, -1.0, 0.5, 1.5, -2.0, 1.0, 0.0, 0.5, -0.5])
    signals = {"t": t, "e": e, "u": u_free + u_n}
    if with_remnant_parts:
        signals.update(u_n=u_n, y_n=y_n)
    parameters = {"K_p": np.full(n, gain), "tau_v": np.full(n, SHIFT * DT)}
    return Recording(signals, DT, parameters=parameters)


def _result(recording, K_p, tau_v=SHIFT * DT):
    n = len(recording)
    mean = np.column_stack([np.broadcast_to(K_p, (n,)), np.full(n, tau_v)])
    return EstimationResult(
        estimator="by-hand",
        t=np.asarray(recording.t),
        parameter_names=("K_p", "tau_v"),
        estimated=("K_p", "tau_v"),
        mean=mean,
        std=np.zeros((n, 2)),
        outputs=("u",),
        predictions=np.asarray(recording.u)[:, None] * 0.5,
        innovations=np.ones((n, 1)),
        innovation_covariance=np.ones((n, 1, 1)),
        finite=np.ones(n, bool),
        covariance_ok=np.ones(n, bool),
        dropped=np.zeros(n, bool),
        diverged=np.zeros(n, bool),
        pinned=np.zeros((n, 2), bool),
        settings={"settings": {"model": "gain-delay"}},
        health=HealthSummary(False, math.nan, "", False, 0, (), {"K_p": 0.0, "tau_v": 0.0}),
    )


def _shifted(values, gain):
    return gain * np.concatenate([np.zeros(SHIFT), np.asarray(values)[:-SHIFT]])


def test_resimulation_is_the_isolated_model_on_the_recorded_or_remnant_free_perceptions():
    recording = _recording()
    result = _result(recording, K_p=1.5)
    measured = resimulate(result, recording)
    np.testing.assert_allclose(measured, _shifted(recording.e, 1.5), atol=1e-12)
    free = resimulate(result, recording, remnant_free=True)
    e_free = np.asarray(recording.e) + np.asarray(recording["y_n"])
    np.testing.assert_allclose(free, _shifted(e_free, 1.5), atol=1e-12)
    truth = resimulate_parameters("gain-delay", recording.parameters, recording, remnant_free=True)
    u_free = np.asarray(recording.u) - np.asarray(recording["u_n"])
    np.testing.assert_allclose(truth, u_free, atol=1e-12)  # the true pilot, remnant-free


def test_evaluate_scores_each_vaf_against_its_own_reference_beside_its_ceiling():
    recording = _recording()
    u = np.asarray(recording.u)
    u_free = u - np.asarray(recording["u_n"])
    e = np.asarray(recording.e)
    e_free = e + np.asarray(recording["y_n"])
    metrics = evaluate(_result(recording, K_p=1.5), recording)

    def by_hand(reference, model):
        return 100.0 * (1.0 - np.sum((reference - model) ** 2) / np.sum(reference**2))

    assert metrics.one_step_vaf == pytest.approx(by_hand(u, 0.5 * u))
    assert metrics.resimulated_vaf == pytest.approx(by_hand(u, _shifted(e, 1.5)))
    assert metrics.resimulated_vaf_ceiling == pytest.approx(by_hand(u, _shifted(e, 2.0)))
    assert metrics.remnant_free_vaf == pytest.approx(by_hand(u_free, _shifted(e_free, 1.5)))
    assert metrics.remnant_free_vaf_ceiling == pytest.approx(100.0)
    # the remnant-free ceiling is 100 % only because both the reference and the
    # perceptions leave the remnant out: scoring either way round would not be
    assert by_hand(u, _shifted(e_free, 2.0)) < 90.0
    assert by_hand(u_free, _shifted(e, 2.0)) < 90.0
    assert metrics.nrmse["K_p"] == pytest.approx(0.25)
    assert metrics.relative_bias["K_p"] == pytest.approx(-0.25)
    assert metrics.nrmse["tau_v"] == pytest.approx(0.0)


def test_scores_from_start_only():
    recording = _recording()
    metrics = evaluate(_result(recording, K_p=np.linspace(1.0, 3.0, 12)), recording, start=0.06)
    late = slice(6, None)
    K_p = np.linspace(1.0, 3.0, 12)[late]
    error = K_p - 2.0
    assert metrics.nrmse["K_p"] == pytest.approx(math.sqrt(np.mean(error**2)) / 2.0)
    assert metrics.relative_bias["K_p"] == pytest.approx(np.mean(error) / 2.0)


def test_without_the_remnant_parts_the_remnant_free_vaf_is_unknown():
    recording = _recording(with_remnant_parts=False)
    metrics = evaluate(_result(recording, K_p=1.5), recording)
    assert math.isnan(metrics.remnant_free_vaf) and math.isnan(metrics.remnant_free_vaf_ceiling)
    assert math.isfinite(metrics.resimulated_vaf)
    with pytest.raises(ValueError, match="needs the recording's u_n and y_n"):
        resimulate(_result(recording, K_p=1.5), recording, remnant_free=True)
    without_truth = recording.with_parameters(K_p=None, tau_v=None)
    metrics = evaluate(_result(without_truth, K_p=1.5), without_truth)
    assert math.isnan(metrics.resimulated_vaf_ceiling) and metrics.nrmse == {}
