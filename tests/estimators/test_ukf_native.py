"""The unscented filters' C port against their numba kernels: the same numbers, bit for bit.

The C port (``_ukf_native.c``) runs wherever it builds and the numba kernels
(``_ukf_core.py``) elsewhere, so a user's numbers must not depend on which ran: every
array of an estimate, the online updates, a block of samples and the batched step are
compared byte for byte, for the joint and the dual filter. The configurations cover the
kernels' branches: SI and DI, dropped samples with limits that bind (projected sigma
points, a constrained prior), a tight limit (estimates at it: pinned flags), a
parameter without spread (zero pivots), an empty variance window, a causal start with
jitter, 50 Hz (two Euler substeps) with a second-order Padé delay, smoother storage and
the smoother, a fourth-order Padé delay, the Merwe points (a weighted centre), the
preview model with and without its anticipation delay, a dual filter without a
parameter filter and one without output gains, and the two ways a filter stops
(non-finite values, a covariance blow-up).
"""

import math

import numpy as np
import pytest
from scenarios import PREVIEW as TYPICAL_PREVIEW

from manualcontrol.envs import _native
from manualcontrol.estimators import DualUKF, JointUKF
from manualcontrol.estimators._pilot_core import SC_SIZE
from manualcontrol.estimators.batch import FilterBatch
from manualcontrol.estimators.members import _ukf_native
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
)
FILTERS = {"joint": JointUKF, "dual": DualUKF}

# the thesis's DI preview pilot (its tau_f left to the preset's start)
PREVIEW = TYPICAL_PREVIEW["DI"]
# precision pilots on SI and DI whose runs start at rest (a still stick)
STILL_PILOTS = {
    "SI": {"K_p": 1.3, "K_v": 0.0, "tau_v": 0.26, "omega_nms": 10.5, "zeta_nms": 0.35},
    "DI": {"K_p": 0.24, "K_v": 0.36, "tau_v": 0.3, "omega_nms": 8.0, "zeta_nms": 0.45},
}


@pytest.fixture(scope="module")
def runs():
    base = simulate(
        Pilot("precision"), "popovici2017", "popovici2017", seed=0, measurement_time=8.0
    )
    u, e = np.array(base.u), np.array(base.e)
    u[300:340] = np.nan  # 0.4 s of the stick lost, three samples of the display
    e[500:503] = np.nan
    gaps = base.with_signals(u=u, e=e)
    u, e = np.array(base.u), np.array(base.e)
    u[100:700] = np.nan  # 6 s of nothing: the 5-s variance windows run empty
    e[100:700] = np.nan
    blackout = base.with_signals(u=u, e=e)
    spike = np.array(base.u)
    spike[700] = 1e300  # after the first 5-s window
    fifty = simulate(
        Pilot("precision"), "popovici2017", "popovici2017", seed=0, measurement_time=8.0, dt=0.02
    )
    preview = Pilot("preview", PREVIEW)
    ahead = simulate(preview, "DI", "vanderel-bw4", seed=1, measurement_time=8.0)
    # pilots starting at rest: a causal start's first variances are the floor
    still = {
        element: simulate(
            Pilot("precision", STILL_PILOTS[element]),
            element,
            "vanderel-bw4",
            seed=3,
            run_in=0.0,
            measurement_time=8.0,
        )
        for element in ("SI", "DI")
    }
    return {
        "still SI": still["SI"],
        "still DI": still["DI"],
        "base": base,
        "gaps": gaps,
        "blackout": blackout,
        "spike": base.with_signals(u=spike),
        "fifty": fifty,
        "ahead": ahead,
    }


CASES = {
    "SI": ("base", {}, {}),
    "DI": ("base", {"ce": "DI"}, {}),
    "dropped samples, limits, a pinned parameter": (
        "gaps",
        {"limits": {"K_v": (0.45, 0.55), "zeta_nms": (0.29, 0.30)}, "pinned_time": 1.0},
        {},
    ),
    "an empty variance window": ("blackout", {}, {}),
    "a tight limit (pinned flags)": (
        "base",
        {"limits": {"omega_nms": (5.0, 6.0)}, "pinned_time": 1.0},
        {},
    ),
    "a parameter without spread (a semidefinite factor)": (
        "base",
        {"P0": {"tau_v": 1e-20}, "Q": {"tau_v": 1e-30}},
        {},
    ),
    "causal start, jitter": (
        "base",
        {
            "jitter": 1e-12,
            "initial_variance": "causal",
            "initial": {"K_p": 1.5, "zeta_nms": 0.3},
            "estimated": ("K_p", "K_v", "tau_v", "omega_nms"),
            "pinned_time": math.inf,
        },
        {},
    ),
    # the pivoted factor (the dual's state filter on SI, the joint's on DI): the
    # first update by a still stick leaves a covariance singular but for rounding
    "causal start from a still stick, SI": (
        "still SI",
        {"ce": "SI", "initial_variance": "causal", "initial": {"K_p": 1.3}},
        {},
    ),
    "causal start from a still stick, DI": (
        "still DI",
        {"ce": "DI", "initial_variance": "causal", "initial": {"K_p": 0.24}},
        {},
    ),
    "50 Hz, second-order Pade, smoothed": ("fifty", {"delay_order": 2}, {"smooth": True}),
    "fourth-order Pade": ("base", {"delay_order": 4}, {}),
    "smoothed": ("base", {}, {"smooth": True}),
    "Merwe points": ("base", {"sigma_points": "merwe", "alpha": 1.0, "kappa": 1.0}, {}),
    "preview model": (
        "ahead",
        {"model": "preview", "ce": "DI", "anticipation_time": 1.5, "initial": PREVIEW},
        {},
    ),
    "preview model, no anticipation delay": (
        "ahead",
        {"model": "preview", "ce": "DI", "anticipation_time": 0.0, "initial": PREVIEW},
        {},
    ),
    "gains only (no parameter filter)": ("base", {"estimated": ("K_p", "K_v")}, {}),
    "no gains (parameters only)": ("base", {"estimated": ("tau_v", "omega_nms")}, {}),
    "a non-finite stop": ("spike", {}, {}),
    "a covariance stop": ("base", {"max_covariance": 10.0}, {}),
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


@needs_compiler
@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("kind", list(FILTERS))
@pytest.mark.parametrize("case", list(CASES))
def test_the_c_port_estimates_what_numba_does_bit_for_bit(kind, case, runs, monkeypatch):
    cls = FILTERS[kind]
    run, settings, options = CASES[case]
    recording = runs[run]
    native = cls(**settings).estimate(recording, **options)
    assert _ukf_native.library() is not None
    numba_only(monkeypatch)
    assert _ukf_native.library() is None
    numba = cls(**settings).estimate(recording, **options)
    assert_same_result(native, numba)
    if case == "a non-finite stop":
        assert numba.health.diverged
    if case == "a covariance stop":
        assert numba.health.diverged
    if options.get("smooth"):
        assert not same_bytes(native.mean, cls(**settings).estimate(recording).mean)


def stored_outputs(estimator, recording):
    """Every output record (smoother storage included) ``estimate(smooth=True)`` fills."""
    outputs = []
    build = estimator._new_output

    def capture(n, store):
        out = build(n, store)
        outputs.append(out)
        return out

    estimator._new_output = capture
    estimator.estimate(recording, smooth=True)
    return outputs


@needs_compiler
@pytest.mark.parametrize("kind", list(FILTERS))
@pytest.mark.parametrize("run", ["fifty", "gaps"])
def test_the_smoother_storage_in_c_equals_numba(kind, run, runs, monkeypatch):
    """Priors, posteriors and the prediction's cross-covariance, of both dual filters."""
    settings = {"limits": {"K_v": (0.45, 0.55)}} if run == "gaps" else {}
    native = stored_outputs(FILTERS[kind](**settings), runs[run])
    numba_only(monkeypatch)
    numba = stored_outputs(FILTERS[kind](**settings), runs[run])
    assert len(native) == len(numba)
    assert any(out.cross.shape[0] == len(runs[run]) for out in native)  # stored
    for ours, theirs in zip(native, numba, strict=True):
        for name in ours._fields:
            assert same_bytes(getattr(ours, name), getattr(theirs, name)), name


def online_samples(recording):
    keys = ("e", "u")
    return [{key: float(recording[key][k]) for key in keys} for k in range(len(recording))]


def online_means(estimator, recording, samples):
    estimator.reset(recording.dt, t0=float(recording.t[0]))
    rows = []
    for sample in samples:
        estimate = estimator.update(sample)
        rows.append([estimate.mean[name] for name in estimator.parameter_names])
    return np.array(rows)


@needs_compiler
@pytest.mark.parametrize("kind", list(FILTERS))
def test_online_updates_and_blocks_in_c_equal_numba_and_the_offline_run(kind, runs, monkeypatch):
    cls = FILTERS[kind]
    recording = runs["gaps"]
    samples = online_samples(recording)
    settings = {"initial_variance": "causal", "initial": {"K_p": 1.5}}
    native = online_means(cls(**settings), recording, samples)
    offline = cls(**settings).estimate(recording)
    assert same_bytes(native, offline.mean)
    # a block of samples in one call, then the rest one by one
    blocked = cls(**settings)
    blocked.reset(recording.dt, t0=float(recording.t[0]))
    values = np.array([[s["e"], s["u"]] for s in samples[:500]])
    blocked.update_block(values)
    assert same_bytes(blocked.latest()[0], native[499])
    for sample in samples[500:]:
        blocked.update(sample)
    assert same_bytes(blocked.latest()[0], native[-1])
    numba_only(monkeypatch)
    assert same_bytes(online_means(cls(**settings), recording, samples), native)
    blocked = cls(**settings)
    blocked.reset(recording.dt, t0=float(recording.t[0]))
    blocked.update_block(values)
    assert same_bytes(blocked.latest()[0], native[499])


@needs_compiler
@pytest.mark.parametrize("kind", list(FILTERS))
def test_the_batched_step_in_c_equals_numba_with_restarts_and_idle_copies(kind, monkeypatch):
    recordings = [
        simulate(
            Pilot.typical("precision", "SI"), "SI", "popovici2017", seed=s, measurement_time=3.0
        )
        for s in range(3)
    ]
    estimator = FILTERS[kind](initial_variance="causal", initial={"K_p": 1.5})

    def batched():
        batch = FilterBatch(estimator, 3)
        batch.reset(recordings[0].dt)
        means = []
        for k in range(len(recordings[0])):
            signals = {key: np.array([r[key][k] for r in recordings]) for key in ("e", "u")}
            active = np.array([True, k % 7 != 0, True])
            batch.step(signals, active)
            if k == 150:
                batch.reset_copies([2])
            means.append(batch.latest()[0].copy())
        return np.array(means), batch

    native, batch = batched()
    assert batch._native is not None
    numba_only(monkeypatch)
    numba, batch = batched()
    assert batch._native is None
    assert same_bytes(native, numba)
    assert not same_bytes(native[:, 0], native[:, 1])  # the copies do differ


@pytest.fixture
def fresh_build_state(monkeypatch):
    """A process that has built nothing yet (the module's memory of builds emptied)."""
    monkeypatch.setattr(_native, "_LOADED", {})
    monkeypatch.setattr(_native, "_FAILED", {})
    monkeypatch.setattr(_ukf_native, "_CHECKED", {})


@needs_compiler
def test_a_c_port_whose_constants_differ_from_the_modules_is_refused(
    monkeypatch, fresh_build_state
):
    from manualcontrol.estimators import _pilot_core

    monkeypatch.setattr(_pilot_core, "SC_SIZE", SC_SIZE + 1)
    with pytest.raises(RuntimeError, match=r"constants .* differ .* edit the two together"):
        _ukf_native.library()


@needs_compiler
def test_records_the_c_port_cannot_read_are_refused(runs):
    estimator = DualUKF()
    estimator.estimate(runs["base"])  # a reset's records
    lib = _ukf_native.library()
    records = list(estimator._records)
    out = estimator._new_output(4, store=False)
    _ukf_native.NativeRecords(lib, tuple(records), out)
    theta = records[6]
    records[6] = theta._replace(D=np.zeros(theta.D.shape[::-1]).T)  # not C-contiguous
    with pytest.raises(ValueError, match="field D is float64, not C-contiguous"):
        _ukf_native.NativeRecords(lib, tuple(records), out)
