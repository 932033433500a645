"""JointUKF and DualUKF on the pilot models, smoothing of every member, result files.

Tolerances, and why:
- With every parameter held and fixed noise the joint UKF is a linear Kalman filter on
  the Euler-discretised canonical model (the unscented transform is exact for linear
  maps): 1e-10 against a plain numpy KF written here, as for the DEKF.
- update() against estimate(): bit for bit (one compiled step serves both).
- Smoothing of a time-varying parameter: the smoothed NRMSE must fall below the
  filtered one (the filtered estimate lags a sigmoid; the smoothed one does not).
"""

import re
import sys
from pathlib import Path

import numpy as np
import pytest

from manualcontrol.envs.recording import Recording
from manualcontrol.estimators import (
    DEKF,
    DualUKF,
    DualUKFSettings,
    EstimationResult,
    Estimator,
    JointUKF,
    UKFSettings,
    load_result,
    nrmse,
    smooth,
)
from manualcontrol.estimators.members.pilot_filter import GenericValuesWarning
from manualcontrol.pilots import Pilot, simulate

sys.path.insert(0, str(Path(__file__).parent))
from dekf_oracle import Model
from scenarios import (
    PREVIEW,
    assert_update_replays_estimate,
    compensatory,
    compensatory_tv,
    preview,
    preview_initial,
)

VALUES = {"K_p": 1.5, "K_v": 0.5, "tau_v": 0.2, "omega_nms": 8.0, "zeta_nms": 0.3}


def test_joint_ukf_with_parameters_held_is_a_linear_kalman_filter():
    R, q = 0.05, 0.3
    recording = compensatory(True).slice_samples(0, 2000)
    ukf = JointUKF(
        model="precision",
        estimated=(),
        initial=VALUES,
        fixed_R=R,
        fixed_Q_error=q,
        P0_canonical=1e-12,
    )
    result = ukf.estimate(recording)
    assert result.estimated == ()
    dt = recording.dt
    model = Model("precision", list(VALUES))
    p = np.array([VALUES[n] for n in model.names])
    Phi = np.eye(5) + model.F(p) * dt
    B = model.f(np.zeros(5), np.array([1.0]), p) * dt
    C = model.dgdx(p)
    Q = np.zeros((5, 5))
    Q[4, 4] = q * dt * dt
    x, P = np.zeros(5), 1e-12 * np.eye(5)
    e, u = np.asarray(recording.e), np.asarray(recording.u)
    predictions, variances = [], []
    for k in range(len(u)):
        if k > 0:
            x = Phi @ x + B * e[k - 1]
            P = Phi @ P @ Phi.T + Q
        S = C @ P @ C + R
        K = P @ C / S
        predictions.append(C @ x)
        variances.append(S)
        x = x + K * (u[k] - C @ x)
        P = P - np.outer(K, K) * S
    scale = np.max(np.abs(u))
    np.testing.assert_allclose(result.prediction, predictions, rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(result.innovation_variance, variances, rtol=1e-10)


@pytest.mark.parametrize("kind", [JointUKF, DualUKF])
@pytest.mark.parametrize("model", ["precision", "preview"])
def test_update_gives_exactly_the_numbers_of_estimate(kind, model):
    if model == "precision":
        recording = compensatory(True).slice_samples(0, 1500)
        u = np.array(recording.u)
        u[700:720] = np.nan
        recording = recording.with_signals(u=u)
        estimator = kind(model="precision")
    else:
        recording = preview("DI", True).slice_samples(0, 1500)
        estimator = kind(
            model="preview", ce="DI", anticipation_time=1.5, initial=preview_initial("DI")
        )
    result = assert_update_replays_estimate(estimator, recording)
    assert result.dropped[700:720].all() if model == "precision" else True


@pytest.mark.parametrize(
    ("kind", "preset"), [(JointUKF, "popovici2017"), (DualUKF, "vertregt2020")]
)
def test_unscented_filters_identify_the_popovici_pilot(kind, preset):
    """Remnant-free Popovici run (Sec. IV-A-1): the final estimates near the truth.

    The dual UKF with the papers' wide P0 ends further off (see estimators._ukf_core).
    """
    result = kind(model="precision", preset=preset).estimate(compensatory(False))
    assert not result.health.diverged
    final = result.final()
    for name, tolerance in (("K_p", 0.05), ("K_v", 0.3), ("tau_v", 0.1), ("omega_nms", 0.2)):
        assert final[name] == pytest.approx(VALUES[name], rel=tolerance), name
    assert isinstance(kind(model="precision"), Estimator)


@pytest.mark.parametrize(
    ("kind", "element", "truth"),
    [
        (JointUKF, "DI", {"K_p": 0.24, "K_v": 0.36, "tau_v": 0.3, "omega_nms": 8.0}),
        (DualUKF, "SI", {"K_p": 1.3, "K_v": 0.0, "tau_v": 0.26, "omega_nms": 10.5}),
    ],
)
def test_a_causal_start_from_a_still_stick_follows_the_first_windows_start(kind, element, truth):
    # the pilot starts at rest, so a causal start's first variances are the floor: the
    # first update, by a stick measured with almost no noise, left a covariance singular
    # but for rounding, which the unpivoted factor refused; the filter stopped at the
    # first sample and never moved (the online observer's only start)
    pilot = Pilot("precision", {**truth, "zeta_nms": 0.45 if element == "DI" else 0.35})
    run = simulate(pilot, element, "vanderel-bw4", seed=3, run_in=0.0, measurement_time=60.0)
    start = {"K_p": truth["K_p"]}
    causal = kind(model="precision", ce=element, initial_variance="causal", initial=start)
    result = causal.estimate(run)
    assert not result.health.diverged
    window = kind(model="precision", ce=element, initial=start).estimate(run).final()
    for name in ("K_p", "tau_v", "omega_nms"):  # after a minute, where the papers' start is
        assert result.final()[name] == pytest.approx(window[name], rel=0.2), name


def test_sigma_points_are_projected_onto_the_limits():
    """The papers' P0 (tau_v std 1 s) would put sigma points at negative delays."""
    result = JointUKF(model="precision", preset="popovici2017").estimate(
        compensatory(False).slice_samples(0, 3000)
    )
    assert not result.health.diverged
    low, high = result.settings["resolved"]["limits"]["tau_v"]
    tau_v = result.mean_of("tau_v")
    assert low <= tau_v.min() and tau_v.max() <= high


@pytest.mark.parametrize("kind", [DEKF, JointUKF, DualUKF])
def test_smoothing_removes_the_lag_of_a_time_varying_gain(kind):
    recording = compensatory_tv(False)
    estimator = kind(model="precision", preset="vertregt2020", initial=VALUES)
    filtered = estimator.estimate(recording, smoother_inputs=True)
    smoothed = smooth(filtered)
    assert smoothed.smoothed and not filtered.smoothed
    assert smoothed.smoother_inputs is None
    # innovations and health stay the filter's
    np.testing.assert_array_equal(smoothed.innovations, filtered.innovations)
    truth = np.asarray(recording.parameters["K_p"])
    late = np.asarray(recording.t) >= 15.0
    filtered_error = nrmse(filtered.mean_of("K_p")[late], truth[late])
    smoothed_error = nrmse(smoothed.mean_of("K_p")[late], truth[late])
    assert smoothed_error < 0.8 * filtered_error, (filtered_error, smoothed_error)
    # the smoother lives on the limits the filter used
    low, high = filtered.settings["resolved"]["limits"]["K_p"]
    assert low <= smoothed.mean_of("K_p").min() and smoothed.mean_of("K_p").max() <= high
    # estimate(..., smooth=True) is the same thing in one call
    assert (
        kind(model="precision", preset="vertregt2020", initial=VALUES)
        .estimate(recording, smooth=True)
        .equals(smoothed)
    )


def test_smoothing_needs_the_stored_run():
    result = DEKF(model="precision").estimate(compensatory(False).slice_samples(0, 600))
    with pytest.raises(ValueError, match=re.escape("kept no smoother inputs: run estimate(")):
        smooth(result)
    with pytest.raises(TypeError, match="result must be an EstimationResult"):
        smooth("result.npz")
    smoothed = DEKF(model="precision").estimate(
        compensatory(False).slice_samples(0, 600), smooth=True
    )
    with pytest.raises(ValueError, match="smoothed already"):
        smooth(smoothed)


def test_results_of_version_two_round_trip_and_version_one_files_still_load(tmp_path):
    recording = compensatory(False).slice_samples(0, 800)
    result = JointUKF(model="precision").estimate(recording, smooth=True)
    loaded = load_result(result.save(tmp_path / "run.npz"))
    assert loaded == result and loaded.smoothed and loaded.outputs == ("u",)
    # a file as the first format wrote it: one output, 1-D traces
    entries = {
        "result_format": np.array("manualcontrol.estimation/1"),
        "estimator": np.array("dekf"),
        "parameter_names": np.array('["K_p", "K_v"]'),
        "estimated": np.array('["K_p"]'),
        "settings": np.array("{}"),
        "health": np.array(
            '{"diverged": false, "divergence_time": null, "divergence_reason": "", '
            '"stopped": false, "dropped_samples": 0, "dropped_stretches": [], '
            '"pinned_fraction": {"K_p": 0.0, "K_v": 0.0}}'
        ),
        "t": np.arange(3) * 0.01,
        "prediction": np.array([0.1, 0.2, 0.3]),
        "innovation": np.array([0.0, 0.1, -0.1]),
        "innovation_variance": np.array([1.0, 0.5, 0.4]),
        "mean": np.ones((3, 2)),
        "std": np.zeros((3, 2)),
        "pinned": np.zeros((3, 2), dtype=bool),
        **{name: np.zeros(3, dtype=bool) for name in ("finite", "covariance_ok", "dropped")},
        "diverged": np.zeros(3, dtype=bool),
    }
    np.savez(tmp_path / "old.npz", **entries)
    old = EstimationResult.load(tmp_path / "old.npz")
    assert old.outputs == ("u",) and old.passes == 1 and not old.smoothed
    np.testing.assert_array_equal(old.prediction, [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(old.innovation_covariance[:, 0, 0], [1.0, 0.5, 0.4])
    np.testing.assert_array_equal(old.pass_mean, [[1.0, 1.0]])
    entries["result_format"] = np.array("manualcontrol.estimation/9")
    np.savez(tmp_path / "future.npz", **entries)
    with pytest.raises(ValueError, match="not a saved EstimationResult"):
        EstimationResult.load(tmp_path / "future.npz")


def test_results_hold_m_outputs():
    n = 4
    result = EstimationResult(
        estimator="two-outputs",
        t=np.arange(n) * 0.01,
        parameter_names=("K_1",),
        estimated=("K_1",),
        mean=np.ones((n, 1)),
        std=np.ones((n, 1)),
        outputs=("u", "y"),
        predictions=np.arange(2 * n, dtype=float).reshape(n, 2),
        innovations=np.zeros((n, 2)),
        innovation_covariance=np.tile(np.eye(2), (n, 1, 1)),
        finite=np.ones(n, bool),
        covariance_ok=np.ones(n, bool),
        dropped=np.zeros(n, bool),
        diverged=np.zeros(n, bool),
        pinned=np.zeros((n, 1), bool),
        settings={},
        health=DEKF(model="precision").estimate(compensatory(False).slice_samples(0, 200)).health,
        passes=2,
        pass_mean=np.array([[0.9], [1.0]]),
        pass_std=np.array([[0.2], [0.1]]),
    )
    np.testing.assert_array_equal(result.prediction_of("y"), [1, 3, 5, 7])
    np.testing.assert_array_equal(result.prediction, [0, 2, 4, 6])
    with pytest.raises(ValueError, match="output must be one of"):
        result.prediction_of("z")
    with pytest.raises(ValueError, match=re.escape("innovations must have shape (4, 2)")):
        EstimationResult(**{**result.__dict__, "innovations": np.zeros((n, 1))})
    with pytest.raises(ValueError, match=re.escape("passes must be an integer >= 1")):
        EstimationResult(**{**result.__dict__, "passes": 0})


@pytest.mark.parametrize(
    ("kind", "settings", "message"),
    [
        (UKFSettings, {"sigma_points": "julier"}, "sigma_points must be one of"),
        (UKFSettings, {"alpha": 0.0}, "alpha must be > 0"),
        (UKFSettings, {"beta": float("nan")}, "beta must be finite, got nan"),
        (DualUKFSettings, {"r2_parameter": -1.0}, "r2_parameter must be > 0"),
        (UKFSettings, {"r2_parameter": 2.0}, "unknown key(s) 'r2_parameter'"),
        (UKFSettings, {"model": "preview"}, "anticipation_time (tau_a, s) is required"),
    ],
)
def test_bad_ukf_settings_raise(kind, settings, message):
    with pytest.raises((ValueError, TypeError), match=re.escape(message)):
        kind(**settings)


def test_ukf_settings_round_trip_and_reject_unknown_keys():
    settings = DualUKFSettings(model="precision", ce="DI", sigma_points="merwe", alpha=0.5)
    assert DualUKFSettings.from_dict(settings.to_dict()) == settings
    with pytest.raises(
        TypeError, match=re.escape("DualUKFSettings.from_dict got unknown key(s) 'sigma'")
    ):
        DualUKFSettings.from_dict({"model": "precision", "sigma": 1})


def test_a_pursuit_fit_needs_no_target_ahead():
    """anticipation_time = 0: the far view reads the current target (van der El's pursuit)."""
    from manualcontrol.pilots import Pilot, simulate

    truth = {**PREVIEW["SI"], "tau_f": 0.0}
    recording = simulate(
        Pilot("preview", truth),
        "SI",
        "vanderel-bw4",
        task="pursuit",
        seed=1,
        measurement_time=60.0,
        keep_run_in=True,
    )
    # nothing says what the target will do: no forcing in the metadata
    bare = Recording(recording.signals, recording.dt, recording.parameters, {})
    initial = {k: v for k, v in truth.items() if k != "tau_f"}
    for kind in (DEKF, JointUKF):
        estimator = kind(
            model="preview", ce="SI", anticipation_time=0.0, preset="vertregt2020", initial=initial
        )
        assert estimator.sample_keys == ("ft", "y", "e", "u")
        result = estimator.estimate(bare)
        assert not result.health.diverged
        assert "tau_f" not in result.estimated
        np.testing.assert_array_equal(result.mean_of("tau_f"), 0.0)
        assert result.final()["K_f"] == pytest.approx(1.0, rel=0.05)
        assert result.final()["K_p"] == pytest.approx(1.3, rel=0.05)
    with pytest.raises(ValueError, match=re.escape("holds tau_f at 0")):
        DEKF(model="preview", anticipation_time=0.0, initial={"tau_f": 0.3})
    with pytest.raises(ValueError, match=re.escape("leave tau_f out of estimated")):
        with pytest.warns(GenericValuesWarning):  # and holds the rest at generic values
            pursuit = DEKF(model="preview", anticipation_time=0.0, estimated=("K_f", "tau_f"))
        pursuit.estimate(bare)
    with pytest.raises(ValueError, match=re.escape("or 0 for a pursuit fit; got 0.1")):
        DEKF(model="preview", anticipation_time=0.1)
