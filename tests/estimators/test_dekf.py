"""The compiled DEKF against independent answers, its limits, health, settings and files.

Tolerances, and why:
- Against the plain-numpy oracle (dekf_oracle.py: the papers' formulas, complex-step
  derivatives, the literal matrix equations): 1e-12 of each trace's scale in
  well-conditioned settings. With the papers' initial canonical variance (0.1, Popovici
  eq. 32) the first corrections cancel a prior about 1e11 times larger than the
  posterior in the output direction, so both implementations lose ~11 digits there and
  legitimately differ by rounding amplified to ~1e-7; that case is checked at 1e-5.
- Against a plain linear Kalman filter (all parameters held constant, fixed noise):
  1e-10; its steady state against scipy.linalg.solve_discrete_are: 1e-8.
- update() against estimate(), and repeated runs: bit for bit.
"""

import dataclasses
import math
import re
import sys
from pathlib import Path
from types import MappingProxyType

import numpy as np
import pytest
import scipy.linalg

from manualcontrol.envs.recording import Recording
from manualcontrol.envs.signals import ForcingPair, Multisine
from manualcontrol.estimators import (
    DEKF,
    DEKFSettings,
    Estimate,
    EstimationResult,
    Estimator,
    load_result,
)
from manualcontrol.estimators.members._targets import PeriodicExtension
from manualcontrol.estimators.members.pilot_filter import GenericValuesWarning

sys.path.insert(0, str(Path(__file__).parent))
from dekf_oracle import Model, NumpyDEKF
from scenarios import compensatory, preview, preview_initial

WELL_CONDITIONED = {"P0_canonical": 1e-8, "preset": "vertregt2020"}


def first_window_variances(dekf, recording, signals):
    n = round(dekf.settings.noise.window / recording.dt)
    return float(np.nanvar(signals["u"][: n + 1])), float(np.nanvar(signals["e"][: n + 1]))


def compare_with_oracle(dekf, recording, tolerance):
    result = dekf.estimate(recording)
    signals = dekf.signals(recording)
    var_u0, var_e0 = first_window_variances(dekf, recording, signals)
    oracle = NumpyDEKF(dekf, recording.dt, var_u0, var_e0)
    inputs = np.column_stack([signals[name] for name in dekf.internal_model.input_names])
    mean, std, scalars = oracle.run(inputs, signals["u"], signals["e"])
    for name, ours, theirs in (
        ("mean", result.mean, mean),
        ("std", result.std, std),
        ("prediction", result.prediction, scalars[:, 0]),
        ("innovation", result.innovation, scalars[:, 1]),
        ("innovation_variance", result.innovation_variance, scalars[:, 2]),
    ):
        np.testing.assert_array_equal(np.isnan(ours), np.isnan(theirs), err_msg=name)
        scale = np.nanmax(np.abs(theirs), axis=0) + 1e-300
        error = np.nanmax(np.abs(ours - theirs) / scale)
        assert error <= tolerance, f"{name}: relative difference {error:.3g} > {tolerance:g}"
    return result


def with_gaps(recording):
    """NaN in u for 0.5 s at 7 s and in e for three samples at 9 s (dropped samples)."""
    u = np.array(recording.u)
    e = np.array(recording.e)
    u[700:750] = np.nan
    e[900:903] = np.nan
    return recording.with_signals(u=u, e=e)


ORACLE_CASES = {
    "compensatory, remnant, limits hit, gaps": (
        lambda: with_gaps(compensatory(True).slice_samples(0, 1500)),
        {
            "model": "precision",
            "limits": {"K_v": (0.45, 0.55), "zeta_nms": (0.25, 0.32)},
            **WELL_CONDITIONED,
        },
    ),
    "compensatory, dimensional eq. 49, jitter": (
        lambda: compensatory(True).slice_samples(0, 1500),
        {
            "model": "precision",
            "total_derivative": "dimensional",
            "jitter": 1e-12,
            **WELL_CONDITIONED,
        },
    ),
    "compensatory, causal variances, r2_parameter": (
        lambda: compensatory(False).slice_samples(0, 1200),
        {
            "model": "precision",
            "initial_variance": "causal",
            "variance_floor": 0.1,  # R well above 0 on the first samples, where var(u) ~ 0
            "initial": {"K_p": 1.4},
            "r2_parameter": 3.0,
            **WELL_CONDITIONED,
        },
    ),
    "preview DI, remnant": (
        lambda: preview("DI", True).slice_samples(0, 1200),
        {
            "model": "preview",
            "ce": "DI",
            "anticipation_time": 1.5,
            "initial": preview_initial("DI"),
            **WELL_CONDITIONED,
        },
    ),
    "preview SI (K_v, omega_f constant), dimensional": (
        lambda: preview("SI").slice_samples(0, 1200),
        {
            "model": "preview",
            "ce": "SI",
            "anticipation_time": 0.9,
            "initial": preview_initial("SI"),
            "total_derivative": "dimensional",
            **WELL_CONDITIONED,
        },
    ),
}


@pytest.mark.parametrize("case", list(ORACLE_CASES))
def test_compiled_dekf_equals_numpy_oracle(case):
    make_recording, settings = ORACLE_CASES[case]
    recording = make_recording()
    result = compare_with_oracle(DEKF(**settings), recording, 1e-12)
    assert result.health.divergence_reason in ("", "zeta_nms pinned at a limit for 30 s")
    if "gaps" in case:
        assert result.pinned.any()  # the projection of eqs. 20, 25 was exercised
        assert result.dropped.sum() == 53


def test_compiled_dekf_follows_oracle_with_the_papers_defaults():
    recording = compensatory(True).slice_samples(0, 1500)
    compare_with_oracle(DEKF(model="precision"), recording, 1e-5)


# ------------------------------------------------------------- linear Kalman filter


def test_constant_parameters_make_a_linear_kalman_filter():
    """All parameters held: the state filter is a plain KF; steady state from the DARE."""
    values = {"K_p": 1.5, "K_v": 0.5, "tau_v": 0.2, "omega_nms": 8.0, "zeta_nms": 0.3}
    R, q = 0.05, 0.3
    recording = compensatory(True).slice_samples(0, 3000)
    dekf = DEKF(
        model="precision",
        estimated=(),
        initial=values,
        fixed_R=R,
        fixed_Q_error=q,
        P0_canonical=1e-12,  # C P0 C^T ~ 2: well conditioned, see the module docstring
    )
    result = dekf.estimate(recording)
    assert result.estimated == ()
    np.testing.assert_array_equal(result.std, 0.0)
    np.testing.assert_array_equal(
        result.mean, np.tile([values[n] for n in result.parameter_names], (len(result), 1))
    )
    # plain KF on the Euler-discretised canonical model (eqs. 8-11), Gamma = I dt
    dt = recording.dt
    model = Model("precision", list(values))
    p = np.array([values[n] for n in model.names])
    F = model.F(p)
    Phi = np.eye(5) + F * dt
    B = model.f(np.zeros(5), np.array([1.0]), p) * dt
    C = model.dgdx(p)
    Q = np.zeros((5, 5))
    Q[4, 4] = q * dt * dt
    x = np.zeros(5)
    P = 1e-12 * np.eye(5)
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
        A = np.eye(5) - np.outer(K, C)
        P = A @ P @ A.T + R * np.outer(K, K)
    scale = np.max(np.abs(u))
    np.testing.assert_allclose(result.prediction, predictions, rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(result.innovation_variance, variances, rtol=1e-10)
    # steady state: a-priori covariance from the discrete algebraic Riccati equation
    P_inf = scipy.linalg.solve_discrete_are(Phi.T, C[:, None], Q, np.array([[R]]))
    assert result.innovation_variance[-1] == pytest.approx(C @ P_inf @ C + R, rel=1e-8)


# ----------------------------------------------------------------- limits, identity


def test_limits_hold_and_constants_stay_constant():
    recording = compensatory(True)
    limits = {"K_p": (1.2, 1.6), "K_v": (0.45, 0.6), "tau_v": (0.15, 0.25), "zeta_nms": (0.2, 0.5)}
    dekf = DEKF(
        model="precision",
        estimated=("K_p", "K_v", "tau_v", "zeta_nms"),
        initial={"omega_nms": 8.5},
        limits=limits,
    )
    result = dekf.estimate(recording)
    for name, (low, high) in limits.items():
        trace = result.mean_of(name)
        assert np.all(trace >= low) and np.all(trace <= high), name
        at_limit = (trace == low) | (trace == high)
        np.testing.assert_array_equal(
            result.pinned[:, result.parameter_names.index(name)], at_limit
        )
        assert at_limit.any(), f"{name} never reached its limits: the test would not notice"
    np.testing.assert_array_equal(result.mean_of("omega_nms"), 8.5)
    np.testing.assert_array_equal(result.std_of("omega_nms"), 0.0)
    assert not result.pinned[:, result.parameter_names.index("omega_nms")].any()


def test_table_one_limits_per_ce_type():
    dekf = DEKF(model="preview", ce="DI", anticipation_time=1.5)
    dekf.reset(0.01, var_u0=1.0, var_e0=1.0)
    limits = dekf.resolved.limits
    assert limits["K_p"] == (0.05, 1.0) and limits["K_v"] == (0.05, 1.5)
    assert limits["omega_f"] == (0.1, 10.0)
    assert limits["tau_f"] == pytest.approx((0.1, 1.4))
    si = DEKF(model="preview", ce="SI", anticipation_time=0.9)
    si.reset(0.01, var_u0=1.0, var_e0=1.0)
    assert si.resolved.limits["K_p"] == (0.2, 2.5)
    assert set(si.resolved.estimated) == {"K_f", "tau_f", "K_p", "tau_v", "omega_nms", "zeta_nms"}
    assert si.resolved.initial["K_v"] == 0.0
    assert si.resolved.theta == ("omega_nms", "zeta_nms", "tau_v", "K_f", "tau_f")  # eq. 41


def test_same_recording_and_settings_give_bit_identical_results():
    recording = compensatory(True)
    first = DEKF(model="precision").estimate(recording)
    second = DEKF(model="precision").estimate(recording)
    assert first.equals(second)
    reused = DEKF(model="precision")
    reused.estimate(compensatory(False))  # a previous run leaves nothing behind
    assert reused.estimate(recording) == first


@pytest.mark.parametrize("model", ["precision", "preview"])
def test_update_gives_exactly_the_numbers_of_estimate(model):
    if model == "precision":
        recording = with_gaps(compensatory(True).slice_samples(0, 2000))
        dekf = DEKF(model="precision")
    else:
        recording = preview("DI", True).slice_samples(0, 2000)
        dekf = DEKF(model="preview", ce="DI", anticipation_time=1.5, initial=preview_initial("DI"))
    result = dekf.estimate(recording)
    signals = dekf.signals(recording)
    var_u0, var_e0 = first_window_variances(dekf, recording, signals)
    dekf.reset(recording.dt, var_u0=var_u0, var_e0=var_e0)
    for k in range(len(recording)):
        estimate = dekf.update({key: signals[key][k] for key in dekf.sample_keys})
        assert estimate.t == pytest.approx(recording.t[k])
        assert [estimate.mean[n] for n in result.parameter_names] == result.mean[k].tolist()
        assert [estimate.std[n] for n in result.parameter_names] == result.std[k].tolist()
        np.testing.assert_array_equal(
            [estimate.prediction, estimate.innovation, estimate.innovation_variance],
            [result.prediction[k], result.innovation[k], result.innovation_variance[k]],
        )
        assert estimate.health.dropped == result.dropped[k]


def test_update_reads_plain_floats_and_checked_samples_alike_with_every_health_flag():
    # limits the estimates reach, so samples with and without pinned parameters occur
    recording = with_gaps(compensatory(True).slice_samples(0, 1500))
    dekf = DEKF(
        model="precision",
        initial_variance="causal",
        initial={"K_p": 1.3},
        limits={"K_p": (1.2, 1.45)},
    )
    result = dekf.estimate(recording)
    assert result.pinned.any(axis=1).any() and not result.pinned.any(axis=1).all()
    signals = dekf.signals(recording)
    plain = [
        {key: float(signals[key][k]) for key in dekf.sample_keys} for k in range(len(recording))
    ]
    checked = [
        MappingProxyType({key: signals[key][k] for key in dekf.sample_keys})  # numpy floats
        for k in range(len(recording))
    ]
    names = result.parameter_names
    for samples in (plain, checked):
        dekf.reset(recording.dt, t0=float(recording.t[0]))
        for k, sample in enumerate(samples):
            estimate = dekf.update(sample)
            assert [estimate.mean[n] for n in names] == result.mean[k].tolist()
            assert [estimate.std[n] for n in names] == result.std[k].tolist()
            health = estimate.health
            assert health.pinned == tuple(n for j, n in enumerate(names) if result.pinned[k, j])
            assert (health.finite, health.covariance_ok, health.dropped, health.diverged) == (
                result.finite[k],
                result.covariance_ok[k],
                result.dropped[k],
                result.diverged[k],
            )
            # the fast constructor builds what the dataclass's own __init__ builds
            assert estimate == Estimate(
                t=estimate.t,
                mean=dict(estimate.mean),
                std=dict(estimate.std),
                estimated=estimate.estimated,
                prediction=estimate.prediction,
                innovation=estimate.innovation,
                innovation_variance=estimate.innovation_variance,
                health=health,
            )


def test_update_refuses_bad_samples_by_key():
    dekf = DEKF(model="precision", initial_variance="causal", initial={"K_p": 1.3})
    dekf.reset(0.01)
    with pytest.raises(ValueError, match="'u'\\] must be finite or NaN"):
        dekf.update({"e": 0.1, "u": math.inf})
    with pytest.raises(ValueError, match="lacks 'u'"):
        dekf.update({"e": 0.1})
    with pytest.raises(TypeError, match=r"sample\['e'\] must be a number"):
        dekf.update({"e": "0.1", "u": 0.0})
    with pytest.raises(TypeError, match="unknown key\\(s\\) 'y'"):
        dekf.update({"e": 0.1, "u": 0.0, "y": 0.0})
    assert dekf.update({"e": 1, "u": 0.0}).mean["K_p"] > 0  # an int is a number


# ------------------------------------------------------------------ dropped samples


def test_dropped_samples_skip_the_corrections_and_are_reported():
    recording = with_gaps(compensatory(False).slice_samples(0, 1500))
    result = DEKF(model="precision").estimate(recording)
    gap = slice(700, 750)
    # no correction: the random-walk parameters keep their means, their variances grow
    np.testing.assert_array_equal(np.diff(result.mean[gap], axis=0), 0.0)
    assert np.all(np.diff(result.std[gap], axis=0) > 0.0)
    assert np.all(np.isnan(result.innovation[gap]))
    assert np.all(np.isfinite(result.prediction[gap]))
    assert result.dropped[gap].all() and result.dropped[900:903].all()
    assert result.health.dropped_samples == 53
    (start_1, length_1), (start_2, length_2) = result.health.dropped_stretches
    assert (start_1, start_2) == pytest.approx((7.0, 9.0))
    assert (length_1, length_2) == pytest.approx((0.5, 0.03))
    assert not result.health.diverged


# ----------------------------------------------------------------------- divergence


def test_non_finite_values_stop_the_filter_and_are_reported():
    recording = compensatory(False).slice_samples(0, 1500)
    u = np.array(recording.u)
    u[1000] = 1e300
    result = DEKF(model="precision").estimate(recording.with_signals(u=u))
    health = result.health
    assert health.diverged and health.stopped
    assert health.divergence_reason == "non-finite values"
    assert 10.0 <= health.divergence_time < 10.5  # the overflow takes a few steps
    k = round(health.divergence_time / recording.dt)
    assert np.all(np.isfinite(result.mean)) and np.all(np.isfinite(result.std))
    np.testing.assert_array_equal(result.mean[k:], np.tile(result.mean[k - 1], (1500 - k, 1)))
    assert np.all(np.isnan(result.prediction[k:])) and np.all(np.isnan(result.innovation[k:]))
    assert not result.finite[k:].any() and result.diverged[k:].all()
    assert result.finite[:k].all() and not result.diverged[:k].any()


def test_covariance_blow_up_is_reported():
    recording = compensatory(False).slice_samples(0, 500)
    result = DEKF(model="precision", max_covariance=11.0).estimate(recording)
    assert result.health.stopped
    assert result.health.divergence_reason == "covariance blow-up"
    assert not result.covariance_ok.all()


def test_a_parameter_pinned_for_long_is_reported_but_the_filter_goes_on():
    recording = compensatory(False)
    dekf = DEKF(model="precision", limits={"K_p": (0.5, 0.6)}, pinned_time=5.0)
    result = dekf.estimate(recording)
    health = result.health
    assert health.diverged and not health.stopped
    assert health.divergence_reason == "K_p pinned at a limit for 5 s"
    assert health.pinned_fraction["K_p"] > 0.5
    assert np.all(np.isfinite(result.prediction))


# --------------------------------------------------------------------- bad settings


BAD_SETTINGS = [
    (
        {"model": "preview", "anticipation_time": 0.9, "initial": {"tau_f": 0.9}},
        "initial tau_f must be < anticipation_time = 0.9 s (tau_f* = tau_a - tau_f > 0, "
        "thesis eq. 26), got 0.9",
    ),
    (
        {"model": "preview", "anticipation_time": 0.9, "initial": {"tau_f": 1.2}},
        "initial tau_f must be < anticipation_time = 0.9 s",
    ),
    (
        {"model": "preview", "anticipation_time": 0.9, "limits": {"tau_f": (0.1, 0.95)}},
        "limits['tau_f'] must stay below anticipation_time = 0.9 s, got (0.1, 0.95)",
    ),
    ({"model": "preview"}, "anticipation_time (tau_a, s) is required for the preview model"),
    (
        {"model": "precision", "anticipation_time": 1.0},
        "anticipation_time applies to the preview model only, not 'precision'; got 1.0",
    ),
    (
        {"model": "precision", "estimated": ("K_p", "tau_f")},
        "estimated: unknown parameter(s) 'tau_f' for the 'precision' model; its parameters "
        "are K_p, K_v, tau_v, omega_nms, zeta_nms",
    ),
    ({"model": "precision", "initial": {"Kp": 1.0}}, "initial: unknown parameter(s) 'Kp'"),
    ({"model": "precision", "Q": {"omega_n": 1.0}}, "Q: unknown parameter(s) 'omega_n'"),
    ({"model": "precision", "P0": {"K_p": 0.0}}, "P0['K_p'] must be > 0, got 0.0"),
    ({"model": "precision", "Q": {"K_v": -1.0}}, "Q['K_v'] must be > 0, got -1.0"),
    ({"model": "precision", "P0_canonical": 0.0}, "P0_canonical must be > 0, got 0.0"),
    ({"model": "precision", "r2": 0.0}, "r2 must be > 0, got 0.0"),
    ({"model": "precision", "q2": -0.4}, "q2 must be > 0, got -0.4"),
    ({"model": "precision", "r2": math.inf}, "r2 must be finite, got inf"),
    ({"model": "precision", "r2_parameter": 0.0}, "r2_parameter must be > 0, got 0.0"),
    (
        {"model": "precision", "limits": {"K_p": (2.0, 1.0)}},
        "limits['K_p'] must satisfy low < high, got (2.0, 1.0)",
    ),
    ({"model": "precision", "limits": "table"}, "limits must be one of 'table-I', 'human', 'none'"),
    ({"model": "pid"}, "model must be one of 'precision', 'preview'"),
    ({"model": "precision", "ce": "TI"}, "ce must be one of 'SI', 'DI', got 'TI'"),
    ({"model": "precision", "preset": "paper"}, "preset must be one of 'popovici2017'"),
    (
        {"model": "precision", "total_derivative": "eq44"},
        "total_derivative must be one of 'printed', 'dimensional', got 'eq44'",
    ),
    ({"model": "precision", "delay_order": 0}, "delay_order must be >= 1, got 0"),
    ({"model": "precision", "delay_order": 5}, "delay_order must be <= 4, got 5: higher orders"),
    ({"model": "precision", "pinned_time": 0.0}, "pinned_time must be > 0 s (inf: never)"),
]


@pytest.mark.parametrize(("settings", "message"), BAD_SETTINGS)
def test_bad_settings_raise(settings, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        DEKFSettings(**settings)


def test_settings_that_resolve_to_zero_covariance_raise():
    with pytest.warns(GenericValuesWarning, match="holds tau_v, omega_nms, zeta_nms"):
        dekf = DEKF(model="precision", ce="SI", estimated=("K_p", "K_v"))
    with pytest.raises(ValueError, match=re.escape("Q['K_v'] resolves to 0.0")):
        dekf.reset(0.01, var_u0=1.0, var_e0=1.0)
    outside = DEKF(model="precision", initial={"K_p": 3.0})
    with pytest.raises(ValueError, match=re.escape("initial K_p = 3.0 lies outside its limits")):
        outside.reset(0.01, var_u0=1.0, var_e0=1.0)


def test_the_filter_refuses_to_run_unconfigured_or_with_bad_samples():
    dekf = DEKF(model="precision")
    with pytest.raises(RuntimeError, match="call reset"):
        dekf.update({"e": 0.1, "u": 0.2})
    with pytest.raises(ValueError, match=re.escape("reset needs var_u0 and var_e0")):
        dekf.reset(0.01)
    dekf.reset(0.01, var_u0=1.0, var_e0=0.5)
    with pytest.raises(ValueError, match=re.escape("DEKF.update sample lacks 'u'")):
        dekf.update({"e": 0.1})
    with pytest.raises(TypeError, match=re.escape("unknown key(s) 'y'")):
        dekf.update({"e": 0.1, "u": 0.2, "y": 0.0})
    with pytest.raises(ValueError, match=re.escape("sample['u'] must be finite or NaN")):
        dekf.update({"e": 0.1, "u": math.inf})
    causal = DEKF(model="precision", initial_variance="causal")
    with pytest.raises(ValueError, match=re.escape("initial K_p is needed")):
        causal.reset(0.01)
    with pytest.raises(TypeError, match="settings must be DEKFSettings"):
        DEKF({"model": "precision"})


# ------------------------------------------------------------------------ protocol


def test_dekf_follows_the_estimator_protocol():
    dekf = DEKF(model="precision", ce="SI")
    assert isinstance(dekf, Estimator)
    other = dekf.configure(r2=4.0)
    assert other.settings.noise.r2 == 4.0 and dekf.settings.noise.r2 is None
    assert other.settings == dataclasses.replace(dekf.settings, r2=4.0)
    dekf.reset(0.01, var_u0=1.0, var_e0=0.25)
    estimate = dekf.update({"e": 0.1, "u": 0.2, "t": 3.0})
    assert estimate.t == 3.0
    assert tuple(estimate.mean) == ("K_p", "K_v", "tau_v", "omega_nms", "zeta_nms")
    assert estimate.std["K_v"] == 0.0 and estimate.mean["K_v"] == 0.0  # SI: held at 0
    assert estimate.std["K_p"] > 0.0
    assert estimate.estimated == ("K_p", "tau_v", "omega_nms", "zeta_nms")
    assert estimate.health.ok
    assert dekf.resolved.initial["K_p"] == pytest.approx(2.0)  # eq. 27: sigma_u / sigma_e


def test_settings_round_trip_through_json():
    settings = DEKFSettings(
        model="preview",
        ce="DI",
        anticipation_time=1.5,
        estimated=("tau_f", "K_p"),
        initial={"K_p": 0.3},
        limits={"K_p": (0.01, math.inf)},
        Q={"tau_f": 0.01},
        pinned_time=math.inf,
    )
    assert DEKFSettings.from_dict(settings.to_dict()) == settings


# --------------------------------------------------------------------------- files


def test_result_saves_and_loads_exactly(tmp_path):
    recording = with_gaps(compensatory(True).slice_samples(0, 1500))
    result = DEKF(model="precision").estimate(recording)
    path = result.save(tmp_path / "run.npz")
    loaded = load_result(path)
    assert loaded == result
    assert loaded.settings["resolved"]["initial"]["omega_nms"] == 10.0
    assert list(tmp_path.iterdir()) == [path]


def test_loading_validates_the_file(tmp_path):
    result = DEKF(model="precision").estimate(compensatory(False).slice_samples(0, 600))
    with pytest.raises(ValueError, match=re.escape("results are saved as .npz")):
        result.save(tmp_path / "run.csv")
    recording_file = compensatory(False).slice_samples(0, 10).save(tmp_path / "rec.npz")
    with pytest.raises(ValueError, match="not a saved EstimationResult"):
        EstimationResult.load(recording_file)
    path = result.save(tmp_path / "run.npz")
    with np.load(path) as archive:
        entries = {name: archive[name] for name in archive.files}
    entries["mean"] = entries["mean"][:, :3]
    np.savez(tmp_path / "broken.npz", **entries)
    with pytest.raises(ValueError, match=re.escape("mean must have shape (600, 5), got (600, 3)")):
        EstimationResult.load(tmp_path / "broken.npz")
    del entries["health"]
    np.savez(tmp_path / "partial.npz", **entries)
    with pytest.raises(ValueError, match=re.escape("saved result lacks entries ['health']")):
        EstimationResult.load(tmp_path / "partial.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match=re.escape("not a readable .npz file")):
        EstimationResult.load(tmp_path / "junk.npz")


# ------------------------------------------------------------ the target ahead


def test_anticipated_target_from_forcing_metadata_or_periodic_extension():
    recording = preview("SI").slice_samples(0, 12000)  # the first 120 s: one period
    dekf = DEKF(model="preview", ce="SI", anticipation_time=0.9, initial=preview_initial("SI"))
    pair = ForcingPair.from_dict(recording.metadata["forcing"])
    expected = pair.target(recording.t + 0.9)
    from_metadata = dekf.signals(recording)["ft_ahead"]
    np.testing.assert_allclose(from_metadata, expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(
        dekf.signals(recording, forcing=pair)["ft_ahead"], expected, atol=1e-12
    )
    bare = Recording(dict(recording.signals), recording.dt)
    periodic = dekf.signals(bare, target_period=120.0)["ft_ahead"]
    np.testing.assert_allclose(periodic, expected, rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match=re.escape("the target ahead of the samples is unknown")):
        dekf.signals(bare)
    with pytest.raises(ValueError, match=re.escape("not a whole number of periods of 50 s")):
        dekf.signals(bare, target_period=50.0)
    wrong = Multisine.sine(1.0, 0.5)
    with pytest.raises(ValueError, match="does not reproduce the recording's ft"):
        dekf.signals(recording, forcing=wrong)


def test_periodic_extension_is_exact_for_a_multisine():
    signal = Multisine([2 * np.pi / 10, 2 * np.pi * 3 / 10], [1.0, 0.3], [0.2, 1.0], 10.0)
    t = np.arange(2000) * 0.01
    extension = PeriodicExtension(signal(t), 0.01)
    later = np.linspace(-7.0, 40.0, 301)
    np.testing.assert_allclose(extension(later), signal(later), atol=1e-12)


def test_a_subclass_with_its_own_step_is_called_every_sample_and_in_a_block():
    class Counting(DEKF):
        steps = 0

        def _step(self, inputs, u, e, out):
            type(self).steps += 1
            super()._step(inputs, u, e, out)

    dekf = Counting(model="precision", initial_variance="causal", initial={"K_p": 1.3})
    dekf.reset(0.01)
    for k in range(5):
        dekf.update({"e": 0.1 * k, "u": 0.05 * k})
    assert Counting.steps == 5
    # a block (the online observer's "none" form) calls it too, and a subclass that
    # reads its samples its own way gets them (without "t"), as update gives them
    samples = np.column_stack([0.1 * np.arange(5), 0.05 * np.arange(5)])  # e, u
    dekf.reset(0.01)
    assert dekf.update_block(samples) == pytest.approx(0.04)
    assert Counting.steps == 10

    class Doubled(DEKF):
        def _consume(self, sample):
            return super()._consume({**sample, "u": 2.0 * sample["u"]})

    settings = dict(model="precision", initial_variance="causal", initial={"K_p": 1.3})
    stepped, blocked = Doubled(**settings), Doubled(**settings)
    stepped.reset(0.01)
    for e, u in samples:
        stepped.update({"e": e, "u": u})
    blocked.reset(0.01)
    blocked.update_block(samples)
    assert blocked.latest()[0].tobytes() == stepped.latest()[0].tobytes()
    plain = DEKF(**settings)
    plain.reset(0.01)
    plain.update_block(samples)
    assert plain.latest()[0].tobytes() != blocked.latest()[0].tobytes()
