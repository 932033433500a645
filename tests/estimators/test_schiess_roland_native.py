"""The Schiess-Roland filter's C port against its numba kernels: bit for bit, on every path.

The C port (``_schiess_roland_native.c``) runs wherever it builds and the numba kernels
elsewhere, so a user's numbers must not depend on which ran: every array of an
estimate (and the smoother's storage with ``Phi``), the filter's final belief and the
online updates are compared byte for byte. The configurations cover the kernel's
branches: the integer and the bicubic delay read, the held and the ramped delayed
input, the adaptive noise off, full and modified, the held and the paper's noise form,
several passes, known parameters, limits with a pinned parameter, a step split into
substeps (a fast pole), jitter, samples with one or both measurements missing, and the
three ways a filter stops (non-finite values, a covariance blow-up, dynamics beyond the
sample rate).
"""

import math

import numpy as np
import pytest

from manualcontrol.envs import _native
from manualcontrol.estimators.members import _schiess_roland_core, _schiess_roland_native
from manualcontrol.estimators.members.schiess_roland import PARAMETER_NAMES, SchiessRoland
from manualcontrol.pilots import Pilot, simulate

needs_compiler = pytest.mark.skipif(
    _native._compiler() is None, reason="no C compiler: the C port cannot be built here"
)

ARRAYS = (
    "mean",
    "std",
    "predictions",
    "innovations",
    "innovation_covariance",
    "finite",
    "covariance_ok",
    "dropped",
    "diverged",
    "pinned",
    "states",
    "pass_mean",
    "pass_std",
)


@pytest.fixture(scope="module")
def runs():
    base = simulate(
        Pilot("schiess-roland"),
        "schiess-roland1975",
        "schiess-roland1975",
        run_in=0.0,
        measurement_time=6.0,
        seed=0,
        measurement_noise={"u": 0.00092, "y": 0.00092},
    )
    u, y = np.array(base.u), np.array(base.y)
    y[100:120] = np.nan  # the stick alone corrects there
    u[300:310] = np.nan  # the plant output alone
    u[400:403] = np.nan
    y[401:405] = np.nan  # both missing at 401, 402: dropped
    # a stick of 1e308 overflows the correction at once; one of 1e300 leaves tau_1 near
    # 1e297, finite, and the next sample's flow beyond its cap
    overflow, spike = np.array(base.u), np.array(base.u)
    overflow[400], spike[400] = 1e308, 1e300
    return {
        "base": base,
        "gaps": base.with_signals(u=u, y=y),
        "overflow": base.with_signals(u=overflow),
        "spike": base.with_signals(u=spike),
    }


SOME = ("K_1", "theta", "tau_3")

CASES = {
    "defaults (integer read, ramp, held noise), smoothed": ("base", {}, {"smooth": True}),
    "bicubic read, held input, full adaptive noise, jitter": (
        "base",
        {
            "delay_read": "bicubic",
            "delayed_input": "hold",
            "adaptive": "full",
            "adaptive_window": 7,
            "jitter": 1e-9,
        },
        {"smoother_inputs": True},
    ),
    "modified adaptive noise, the paper's noise form and covariance": (
        "base",
        {"adaptive": "modified", "noise_form": "paper", "initial_covariance": "paper"},
        {},
    ),
    "three passes carrying the block": (
        "base",
        {"passes": 3, "carry": "block", "process_noise": 576.0},
        {},
    ),
    "known parameters, a limit pinning K_1": (
        "base",
        {"estimated": SOME, "limits": {"K_1": (1.1, 1.3)}, "pinned_time": 0.1},
        {},
    ),
    "a fast pole: steps split into substeps": (
        "base",
        {"initial": {"tau_2": 0.004}, "estimated": ("K_1", "tau_3", "theta")},
        {},
    ),
    "one or both measurements missing, adaptive": (
        "gaps",
        {"adaptive": "full", "delay_read": "bicubic"},
        {"smooth": True},
    ),
    "a non-finite stop": ("overflow", {"adaptive": "modified"}, {}),
    "a stop beyond the sample rate after a spike": ("spike", {"adaptive": "modified"}, {}),
    # a lag of a microsecond: ||A dt|| = 1e4, its flow over a sample would need 4,096
    # substeps
    "a stop beyond the sample rate at the first prediction": (
        "base",
        {"initial": {"tau_1": 1e-6}},
        {},
    ),
    "a covariance stop after a prediction": (
        "base",
        {"max_covariance": 90.0, "process_noise": 1e6},
        {},
    ),
}


def same_bytes(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def numba_only(monkeypatch):
    monkeypatch.setenv("MANUALCONTROL_NATIVE", "0")


def estimate(settings, recording, options):
    estimator = SchiessRoland(**settings)
    result = estimator.estimate(recording, **options)
    _, belief, monitor, _, scratch = estimator._records
    state = [belief.x, belief.P, belief.sc, belief.hist_d, belief.hist_c, belief.hist_rate]
    state += [belief.q_window, belief.q_sum, monitor.pins, monitor.pin_ring]
    state += [scratch.Z, scratch.J, scratch.Gw, scratch.work2.log_det, scratch.work1.log_det]
    return result, state


@needs_compiler
@pytest.mark.parametrize("case", list(CASES))
def test_the_c_port_estimates_what_numba_does_bit_for_bit(case, runs, monkeypatch):
    run, settings, options = CASES[case]
    recording = runs[run]
    native, native_state = estimate(settings, recording, options)
    assert _schiess_roland_native.library() is not None
    numba_only(monkeypatch)
    assert _schiess_roland_native.library() is None
    numba, numba_state = estimate(settings, recording, options)
    for name in ARRAYS:
        assert same_bytes(getattr(native, name), getattr(numba, name)), name
    for i, (a, b) in enumerate(zip(native_state, numba_state, strict=True)):
        assert same_bytes(a, b), i
    assert native.health == numba.health
    assert native.settings == numba.settings
    if options.get("smoother_inputs"):  # (a smoothed result is the storage smoothed)
        (a,) = native.smoother_inputs.blocks
        (b,) = numba.smoother_inputs.blocks
        for name in ("x_filtered", "P_filtered", "x_predicted", "P_predicted", "link"):
            assert same_bytes(getattr(a, name), getattr(b, name)), name
    if case == "a non-finite stop":
        assert numba.health.divergence_reason == "non-finite values"
        assert numba.health.divergence_time == recording.t[400]
    if case.startswith("a stop beyond the sample rate"):  # nothing predicted from there on
        stop = 401 if case.endswith("spike") else 1
        assert numba.health.divergence_reason == "dynamics beyond the sample rate"
        assert numba.health.divergence_time == recording.t[stop]
        assert np.isfinite(numba.predictions[stop - 1]).all()
        assert np.isnan(numba.predictions[stop:]).all()
        assert same_bytes(numba.states[stop], numba.states[stop - 1])
    if case.startswith("a covariance stop"):
        assert numba.health.divergence_reason == "covariance blow-up"
        assert numba.health.divergence_time > recording.t[0]
    if case.startswith("known parameters"):
        assert numba.pinned[:, 0].any()
    if case.startswith("one or both"):
        assert numba.dropped.sum() == 2
    if case.startswith("a fast pole"):
        x = np.zeros(_schiess_roland_core.N_STATES)
        x[_schiess_roland_core.I_TAU1 : _schiess_roland_core.I_TAU3] = (0.09, 0.004)
        assert _schiess_roland_core._series_norm(x, 10.0, recording.dt) > 4.0


def online_rows(estimator, recording, samples):
    estimator.reset(recording.dt, initial_states=estimator.initial_states_of(recording))
    rows = []
    for sample in samples:
        estimate = estimator.update(sample)
        rows.append(
            [estimate.mean[name] for name in PARAMETER_NAMES]
            + [estimate.std[name] for name in PARAMETER_NAMES]
            + list(estimate.innovations)
        )
    return np.array(rows)


@needs_compiler
def test_online_updates_in_c_equal_numba_and_the_offline_run(runs, monkeypatch):
    recording = runs["gaps"]
    settings = {"delay_read": "bicubic", "adaptive": "modified", "process_noise": 576.0}
    samples = [
        {"ft": float(recording.ft[k]), "u": float(recording.u[k]), "y": float(recording.y[k])}
        for k in range(len(recording))
    ]
    estimator = SchiessRoland(**settings)
    online_rows(estimator, recording, samples[:50])
    assert estimator._native[2] is not None  # the C step runs, bound to the one-row output
    native = online_rows(estimator, recording, samples)  # a second reset binds anew
    offline = estimator.estimate(recording)
    n = len(PARAMETER_NAMES)
    assert same_bytes(native[:, :n], offline.mean)
    assert same_bytes(native[:, n : 2 * n], offline.std)
    assert same_bytes(native[:, 2 * n :], offline.innovations)
    # a missing forcing (online only: recordings refuse NaN in ft) holds its last value
    held = [dict(sample) for sample in samples[:300]]
    for sample in held[150:160]:
        sample["ft"] = math.nan
    native_held = online_rows(SchiessRoland(**settings), recording, held)
    numba_only(monkeypatch)
    estimator = SchiessRoland(**settings)
    assert same_bytes(online_rows(estimator, recording, samples), native)
    assert estimator._native[2] is None
    assert same_bytes(online_rows(SchiessRoland(**settings), recording, held), native_held)


@pytest.fixture
def fresh_build_state(monkeypatch):
    """A process that has built nothing yet (the module's memory of builds emptied)."""
    monkeypatch.setattr(_native, "_LOADED", {})
    monkeypatch.setattr(_native, "_FAILED", {})
    monkeypatch.setattr(_schiess_roland_native, "_CHECKED", {})


def test_without_a_compiler_numba_runs_the_same_numbers_and_says_why(
    runs, monkeypatch, tmp_path, fresh_build_state
):
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    monkeypatch.setenv("PATH", "/nonexistent")  # and no cc either
    assert _schiess_roland_native.library() is None
    assert "no C compiler found" in _native.native_failure(_schiess_roland_native.SOURCE)
    result = SchiessRoland().estimate(runs["base"])
    monkeypatch.setenv("MANUALCONTROL_NATIVE", "0")
    assert same_bytes(result.mean, SchiessRoland().estimate(runs["base"]).mean)


@needs_compiler
def test_a_c_port_whose_constants_differ_from_the_modules_is_refused(
    monkeypatch, fresh_build_state
):
    monkeypatch.setattr(_schiess_roland_core, "_SERIES_TERMS", 61)
    with pytest.raises(RuntimeError, match=r"constants .* differ .* edit the two together"):
        _schiess_roland_native.library()


@needs_compiler
def test_records_the_c_port_cannot_read_are_refused(runs):
    estimator = SchiessRoland()
    estimator.reset(runs["base"].dt, initial_states=estimator.initial_states_of(runs["base"]))
    config, belief, monitor, report, scratch = estimator._records
    lib = _schiess_roland_native.library()
    bad = belief._replace(hist_c=belief.hist_c[:-1].copy())
    with pytest.raises(ValueError, match="record field hist_c has shape"):
        _schiess_roland_native.NativeRecords(
            lib, (config, bad, monitor, report, scratch), estimator._row
        )
    flags = config._replace(estimated=config.estimated.astype(np.int64))
    with pytest.raises(ValueError, match="record field estimated is int64"):
        _schiess_roland_native.NativeRecords(
            lib, (flags, belief, monitor, report, scratch), estimator._row
        )
