"""Zhao's UKF's C port against its numba kernels: the same numbers, bit for bit.

The C port (``_zhao_native.c``) runs wherever it builds and the numba kernels
elsewhere, so a user's numbers must not depend on which ran: every array of an
estimate (and, smoothed, the smoother's storage) and the online updates are compared
byte for byte (equal bytes is what identical means: signed zeros and NaN payloads
included). The configurations cover the kernel's branches: Zhao's defaults (cubature
points, the centre row not propagated), the Merwe points (all rows, a negative centre
weight) with four estimated parameters, jitter and three Euler substeps, dropped
samples (NaN inputs and outputs) with tight limits and a pinned parameter, 50 Hz with
eq. 13's ``R_d``, a finite Gramian horizon and smoother storage, no limits, and the
ways a filter stops (non-finite values, a covariance blow-up).
"""

import numpy as np
import pytest

from manualcontrol.envs import _native
from manualcontrol.envs.schedules import Ramp
from manualcontrol.estimators import MultiUKF, ZhaoUKF
from manualcontrol.estimators.members import _zhao_native
from manualcontrol.estimators.members.zhao_ukf import _SAMPLE_KEYS
from manualcontrol.pilots.driver import Driver
from manualcontrol.pilots.driving import simulate_driving

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
)


@pytest.fixture(scope="module")
def runs():
    base = simulate_driving(Driver(), measurement_time=12.0, seed=0)
    gaps = {}
    for name in _SAMPLE_KEYS:
        gaps[name] = np.array(base[name])
    gaps["theta_near"][300:340] = np.nan  # 0.4 s of one input lost
    gaps["Gamma_d"][500:503] = np.nan  # three samples of an output
    gaps["delta_sw"][700] = np.nan
    spike = np.array(base["delta_sw"])
    spike[600] = 1e300
    fifty = simulate_driving(Driver(), measurement_time=12.0, seed=1, dt=0.02)
    rising = {"K_p": Ramp(3.4, 4.4, 3.0, 8.0), "K_c": Ramp(15.0, 12.0, 4.0, 9.0)}
    ramps = simulate_driving(Driver(rising), measurement_time=12.0, seed=2)
    gamma = np.array(ramps["Gamma_d"])
    gamma[400:405] = np.nan
    return {
        "ramps": ramps.with_signals(Gamma_d=gamma),
        "base": base,
        "gaps": base.with_signals(**gaps),
        "spike": base.with_signals(delta_sw=spike),
        "fifty": fifty,
    }


CASES = {
    "Zhao's defaults": ("base", {}, {}),
    "Merwe points, four parameters, jitter, three substeps, ukf2": (
        "base",
        {
            "preset": "ukf2",
            "scheme": "merwe",
            "estimated": ("K_p", "K_c", "T_N", "tau_p"),
            "substeps": 3,
            "jitter": 1e-12,
            "initial_states": (0.01, -0.02, 0.0),
        },
        {},
    ),
    "dropped samples, tight limits, a pinned parameter": (
        "gaps",
        {"limits": {"K_p": (3.3, 3.41), "K_c": (14.0, 16.0)}, "pinned_time": 1.0},
        {},
    ),
    "50 Hz, eq. 13, finite Gramian, Q_theta, smoothed": (
        "fifty",
        {
            "output_error_ratios": (0.05, 0.05),
            "gramian_horizon": 2.0,
            "Q_theta": {"K_c": 1e-5},
            "P0_fraction": 0.3,
        },
        {"smooth": True},
    ),
    "smoother storage, no limits, held parameters": (
        "base",
        {"limits": "none", "estimated": ("K_c",), "initial": {"T_I": 1.2}, "speed": 17.0},
        {"smoother_inputs": True},
    ),
    "a non-finite stop": ("spike", {}, {}),
    "a covariance stop at the first sample": ("base", {"max_covariance": 1e-3}, {}),
    "a covariance stop mid-run": ("base", {"max_covariance": 2.3, "preset": "ukf2"}, {}),
    "a covariance stop of a wide prior without limits": (
        "base",
        {"P0_fraction": 3.0, "limits": "none", "estimated": ("K_p", "K_c", "tau_p", "T_I")},
        {},
    ),
    # outputs measured with almost no noise leave a covariance singular but for
    # rounding: the unpivoted factor refused it (the filter stopped at 2.55 s), the
    # pivoted one takes it
    "R_d near zero, Merwe points (the pivoted factor)": (
        "base",
        {"R_d": (1e-30, 1e-30), "scheme": "merwe"},
        {},
    ),
}


def same_bytes(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def assert_same_result(native, numba):
    for name in ARRAYS:
        assert same_bytes(getattr(native, name), getattr(numba, name)), name
    assert native.health == numba.health
    assert native.parameter_names == numba.parameter_names


def numba_only(monkeypatch):
    monkeypatch.setenv("MANUALCONTROL_NATIVE", "0")


def kept_outputs(estimator):
    """The arguments of every ``_run`` (C port's or numba's): the run's output records."""
    kept = []
    run = estimator._run

    def spy(*arguments):
        run(*arguments)
        kept.append(arguments)

    estimator._run = spy
    return kept


def counted(monkeypatch, binding_class):
    """Calls of ``binding_class.run`` from now on: the C port's whole runs."""
    calls = []
    run = binding_class.run

    def counting(self, *arguments):
        calls.append(1)
        return run(self, *arguments)

    monkeypatch.setattr(binding_class, "run", counting)
    return calls


@needs_compiler
@pytest.mark.parametrize("case", list(CASES))
def test_the_c_port_estimates_what_numba_does_bit_for_bit(case, runs, monkeypatch):
    run, settings, options = CASES[case]
    recording = runs[run]
    c_runs = counted(monkeypatch, _zhao_native.NativeRecords)
    estimator = ZhaoUKF(**settings)
    runs_kept = kept_outputs(estimator)
    native = estimator.estimate(recording, **options)
    assert _zhao_native.library() is not None
    assert len(c_runs) == 1
    native_out = runs_kept[-1][-1]
    numba_only(monkeypatch)
    assert _zhao_native.library() is None
    other = ZhaoUKF(**settings)
    runs_kept = kept_outputs(other)
    numba = other.estimate(recording, **options)
    assert len(c_runs) == 1  # no C run this time
    assert_same_result(native, numba)
    numba_out = runs_kept[-1][-1]
    for name in native_out._fields:
        assert same_bytes(getattr(native_out, name), getattr(numba_out, name)), name
    assert same_bytes(estimator._records[1].x, other._records[1].x)
    assert same_bytes(estimator._records[1].P, other._records[1].P)
    if case.startswith("a non-finite"):
        assert numba.health.diverged
    if case.startswith("a covariance"):
        assert numba.health.diverged
    if case.startswith("R_d near zero"):
        assert not numba.health.diverged
    if case.startswith("dropped"):
        assert np.asarray(numba.dropped).any() and np.asarray(numba.pinned).any()
    if options.get("smooth") or options.get("smoother_inputs"):
        assert np.asarray(native_out.P_post).size and np.asarray(native_out.link).any()


def online_samples(recording):
    return [{key: float(recording[key][k]) for key in _SAMPLE_KEYS} for k in range(len(recording))]


def online_rows(estimator, recording, samples):
    estimator.reset(recording.dt, speed=recording.metadata["speed"], t0=float(recording.t[0]))
    rows = []
    for sample in samples:
        estimate = estimator.update(sample)
        row = estimator._row
        rows.append(
            np.concatenate(
                [
                    [estimate.mean[name] for name in estimator.parameter_names],
                    row.std[0],
                    row.predictions[0],
                    row.innovations[0],
                    row.S[0].ravel(),
                    row.states[0],
                ]
            )
        )
    return np.array(rows)


@needs_compiler
def test_online_updates_in_c_equal_numba_and_the_offline_run(runs, monkeypatch):
    recording = runs["gaps"]
    samples = online_samples(recording)
    settings = {"preset": "ukf2", "initial": {"K_p": 3.0}}
    estimator = ZhaoUKF(**settings)
    native = online_rows(estimator, recording, samples)
    assert estimator._native[2] is not None
    assert "NativeRecords.entry" in estimator._entry.__qualname__  # the C step, not numba's
    offline = ZhaoUKF(**settings).estimate(recording)
    assert same_bytes(native[:, :8], offline.mean)
    assert same_bytes(native[:, -3:], offline.states)
    numba_only(monkeypatch)
    other = ZhaoUKF(**settings)
    assert same_bytes(online_rows(other, recording, samples), native)
    assert other._native[2] is None


@pytest.fixture
def fresh_build_state(monkeypatch):
    """A process that has built nothing yet (the module's memory of builds emptied)."""
    monkeypatch.setattr(_native, "_LOADED", {})
    monkeypatch.setattr(_native, "_FAILED", {})
    monkeypatch.setattr(_zhao_native, "_CHECKED", {})


@needs_compiler
def test_a_c_port_whose_constants_differ_from_the_modules_is_refused(
    monkeypatch, fresh_build_state
):
    from manualcontrol.estimators.filters import linalg

    monkeypatch.setattr(linalg, "SEMIDEFINITE_TOLERANCE", 1e-12)
    with pytest.raises(RuntimeError, match=r"constants .* differ .* edit the two together"):
        _zhao_native.library()


def test_without_a_compiler_numba_runs_and_says_why(runs, monkeypatch, fresh_build_state):
    monkeypatch.setenv("CC", "/nonexistent/no-such-compiler")
    monkeypatch.setenv("PATH", "/nonexistent")  # and no cc either
    assert _zhao_native.library() is None
    assert "no C compiler found" in _native.native_failure(_zhao_native.SOURCE)
    c_runs = counted(monkeypatch, _zhao_native.NativeRecords)
    ZhaoUKF().estimate(runs["base"])
    assert c_runs == []


# ---------------------------------------------------------------------- multi-UKF

MULTI_CASES = {
    "Zhao's multi-UKF, the fusion's defaults": ("base", {}),
    "ramps: gates between 0 and 1": ("ramps", {}),
    "ramps, a quick fusion, a faster fast member": (
        "ramps",
        {"smoothing_time": 0.5, "level_time": 5.0, "dead_zone": 0.001, "fast_Q_theta_scale": 1e-3},
    ),
    "no feedback, no dead zone, a quick fusion, Merwe points": (
        "base",
        {
            "feedback": False,
            "dead_zone": 0.0,
            "smoothing_time": 0.2,
            "level_time": 1.0,
            "scheme": "merwe",
            "fast_Q_theta_scale": 1e-4,
        },
    ),
    "feedback onto tight limits, dropped samples, pins": (
        "gaps",
        {
            "dead_zone": 0.0,
            "smoothing_time": 0.1,
            "level_time": 0.5,
            "limits": {"K_p": (3.3, 3.41), "K_c": (14.0, 16.0)},
            "pinned_time": 1.0,
            "estimated": ("K_p", "K_c", "T_N"),
        },
    ),
    "a non-finite stop": ("spike", {}),
    "the fast member stops alone": ("base", {"max_covariance": 2.3, "fast_Q_theta_scale": 1e-3}),
}


@needs_compiler
@pytest.mark.parametrize("case", list(MULTI_CASES))
def test_the_c_port_runs_the_multi_ukf_as_numba_does_bit_for_bit(case, runs, monkeypatch):
    run, settings = MULTI_CASES[case]
    recording = runs[run]
    c_runs = counted(monkeypatch, _zhao_native.NativeMulti)
    estimator = MultiUKF(**settings)
    runs_kept = kept_outputs(estimator)
    native = estimator.estimate(recording)
    assert len(c_runs) == 1
    native_outs = runs_kept[-1][2:5]
    numba_only(monkeypatch)
    other = MultiUKF(**settings)
    runs_kept = kept_outputs(other)
    numba = other.estimate(recording)
    assert len(c_runs) == 1  # no C run this time
    assert_same_result(native, numba)
    for mine, theirs in zip(native_outs, runs_kept[-1][2:5], strict=True):
        for name in mine._fields:
            assert same_bytes(getattr(mine, name), getattr(theirs, name)), name
    for member in ("_slow", "_fast"):
        for a, b in zip(
            getattr(estimator, member)._records[1], getattr(other, member)._records[1], strict=True
        ):
            assert same_bytes(a, b)
    for a, b in zip(estimator._records[3], other._records[3], strict=True):
        assert same_bytes(a, b)
    gate = np.asarray(native_outs[2].gate)
    if case.startswith(("no feedback", "feedback")):
        assert gate.any()
    if case.startswith("ramps"):
        assert ((gate > 0.0) & (gate < 1.0)).any()
    if case.startswith(("a non-finite", "the fast")):
        assert numba.health.diverged


def online_multi_rows(estimator, recording, samples):
    estimator.reset(recording.dt, speed=recording.metadata["speed"], t0=float(recording.t[0]))
    rows = []
    for sample in samples:
        estimator.update(sample)
        row = estimator._row
        rows.append(np.concatenate([row.mean[0], row.std[0], row.gate[0], row.members[0]]))
    return np.array(rows)


@needs_compiler
def test_online_multi_ukf_updates_in_c_equal_numba_and_the_offline_run(runs, monkeypatch):
    recording = runs["ramps"]
    samples = online_samples(recording)
    settings = {"smoothing_time": 0.5, "level_time": 5.0, "fast_Q_theta_scale": 1e-3}
    estimator = MultiUKF(**settings)
    native = online_multi_rows(estimator, recording, samples)
    assert "NativeMulti.entry" in estimator._entry.__qualname__
    offline = MultiUKF(**settings).estimate(recording)
    assert same_bytes(native[:, :8], offline.mean)
    assert same_bytes(native[:, 8:16], offline.std)
    assert ((native[:, 16:18] > 0.0) & (native[:, 16:18] < 1.0)).any()
    numba_only(monkeypatch)
    other = MultiUKF(**settings)
    assert same_bytes(online_multi_rows(other, recording, samples), native)
    assert other._native[4] is None
