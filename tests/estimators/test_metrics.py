"""Metrics against hand computations and brute force; resimulation against the simulation."""

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from manualcontrol.estimators import (
    DEKF,
    evaluate,
    innovation_fractions,
    moving_vaf,
    nrmse,
    relative_bias,
    resimulate,
    vaf,
)

sys.path.insert(0, str(Path(__file__).parent))
from scenarios import compensatory, preview, preview_initial


def test_vaf_is_thesis_eq_38():
    u = np.array([1.0, -2.0, 3.0, np.nan])
    assert vaf(u, u) == 100.0
    assert vaf(u, np.zeros(4)) == 0.0
    u_hat = np.array([1.5, -2.0, 2.0, 7.0])  # the NaN sample is left out
    assert vaf(u, u_hat) == pytest.approx((1.0 - (0.25 + 1.0) / 14.0) * 100.0)
    assert math.isnan(vaf(np.zeros(3), np.ones(3)))
    with pytest.raises(ValueError, match="same length"):
        vaf(u, u[:2])


def test_moving_vaf_equals_brute_force():
    rng = np.random.default_rng(3)
    u = rng.standard_normal(500)
    u_hat = u + 0.3 * rng.standard_normal(500)
    u_hat[100] = np.nan
    moving = moving_vaf(u, u_hat, dt=0.01, window=0.5)
    assert np.all(np.isnan(moving[:49]))
    for k in (49, 120, 499):
        assert moving[k] == pytest.approx(vaf(u[k - 49 : k + 1], u_hat[k - 49 : k + 1]), rel=1e-12)


def test_nrmse_switches_to_rmse_near_zero_and_bias_is_relative():
    truth = np.full(100, 2.0)
    estimate = truth + np.where(np.arange(100) % 2, 0.2, -0.1)
    assert nrmse(estimate, truth) == pytest.approx(math.sqrt((0.04 + 0.01) / 2) / 2.0)
    assert relative_bias(estimate, truth) == pytest.approx(0.05 / 2.0)
    zero = np.zeros(100)  # K_v of a single-integrator pilot: thesis Part II eq. 5.7
    assert nrmse(zero + 0.03, zero) == pytest.approx(0.03)
    assert relative_bias(zero + 0.03, zero) == pytest.approx(0.03)
    assert nrmse(-truth, -truth) == 0.0


def test_innovation_fractions_of_a_consistent_filter():
    rng = np.random.default_rng(11)
    variance = rng.uniform(0.5, 2.0, 200_000)
    innovation = rng.standard_normal(200_000) * np.sqrt(variance)
    within_1, within_2 = innovation_fractions(innovation, variance)
    assert within_1 == pytest.approx(0.6827, abs=0.005)
    assert within_2 == pytest.approx(0.9545, abs=0.003)


def true_parameter_result(result, recording):
    """The same result with the recording's true parameter traces as its means."""
    mean = np.column_stack([recording.parameters[name] for name in result.parameter_names])
    return dataclasses.replace(result, mean=mean)


@pytest.mark.parametrize("kind", ["compensatory", "preview"])
def test_resimulation_with_the_true_parameters_reproduces_the_pilot(kind):
    if kind == "compensatory":
        recording = compensatory(False)
        result = DEKF(model="precision").estimate(recording)
    else:
        recording = preview("DI")
        result = DEKF(
            model="preview", ce="DI", anticipation_time=1.5, initial=preview_initial("DI")
        ).estimate(recording)
    exact = resimulate(true_parameter_result(result, recording), recording)
    settled = recording.t >= 10.0  # the isolated model starts at rest
    # the measured perceptions are held over each sample (in the closed loop they are
    # continuous): about half a sample of lag, 1e-4 of the variance at these frequencies
    assert vaf(recording.u[settled], exact[settled]) > 99.97
    pade = resimulate(true_parameter_result(result, recording), recording, delay_order=3)
    assert vaf(recording.u[settled], pade[settled]) > 99.0
    assert np.max(np.abs(pade - exact)) > 1e-4  # the Padé option is a different model


def test_evaluate_collects_every_metric():
    recording = compensatory(False).slice_samples(0, 3000)
    result = DEKF(model="precision").estimate(recording)
    metrics = evaluate(result, recording, start=15.0)
    mask = recording.t >= 15.0
    assert metrics.one_step_vaf == pytest.approx(vaf(recording.u[mask], result.prediction[mask]))
    assert metrics.one_step_vaf > 99.0 and metrics.resimulated_vaf > 98.0
    assert set(metrics.nrmse) == set(result.estimated)
    assert metrics.nrmse["K_p"] == pytest.approx(
        nrmse(result.mean_of("K_p")[mask], recording.parameters["K_p"][mask])
    )
    assert metrics.error_kind["K_v"] == "nrmse"
    assert 0.6 < metrics.within_1_sigma <= metrics.within_2_sigma <= 1.0
    with pytest.raises(ValueError, match="after the last sample"):
        evaluate(result, recording, start=1000.0)


def test_dekf_refuses_recordings_it_cannot_use_with_the_reason():
    import re

    import numpy as np
    import pytest

    from manualcontrol.envs.recording import Recording
    from manualcontrol.estimators import DEKF

    dekf = DEKF(model="precision", ce="SI")
    short = Recording({"t": np.arange(3) * 0.01, "u": np.zeros(3), "e": np.zeros(3)}, 0.01)
    with pytest.raises(ValueError, match=re.escape("the recording has 3 samples; the estimator")):
        dekf.estimate(short)
    n = 2000
    blank = Recording({"t": np.arange(n) * 0.01, "u": np.full(n, np.nan), "e": np.ones(n)}, 0.01)
    with pytest.raises(ValueError, match=re.escape("the recording's u has no finite sample")):
        dekf.estimate(blank)


def test_innovation_whiteness_tells_white_from_coloured():
    import numpy as np

    from manualcontrol.estimators.analysis.metrics import innovation_whiteness

    rng = np.random.default_rng(0)
    white = rng.standard_normal(20000)
    r1, outside = innovation_whiteness(white, np.ones_like(white))
    assert abs(r1) < 0.03 and outside < 0.15  # 95 % band: about 5 % of lags outside
    coloured = np.convolve(white, np.ones(20) / 20, "same")
    r1, outside = innovation_whiteness(coloured, np.ones_like(coloured))
    assert r1 > 0.9 and outside > 0.3
