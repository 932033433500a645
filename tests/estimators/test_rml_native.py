"""The RML's C port against its numba kernels: the same numbers, bit for bit, on every path.

The C port (``_rml_native.c``) runs wherever it builds and the numba kernels elsewhere,
so a user's numbers must not depend on which ran: every array of an estimate (the
remnant's state traces included), the online updates, a block of samples and the
batched step are compared byte for byte (equal bytes is what identical means: signed
zeros and NaN payloads too). The configurations cover the bank's branches: the remnant
at the perception and at the stick, no remnant, the double integrator's remnant weight
on ``R``, a learned break frequency with the variance score on every parameter, the
noise parameters first and no drift rule, an unlimited spread, dropped samples with a
causal start, 50 Hz (four Euler substeps) smoothed, a restart, the preview model with and without
its anticipation delay, the causal choice between the two injections, and the two ways
a filter stops (non-finite values, a covariance blow-up).

The build itself is tested once, for the DEKF's port (``test_dekf_native.py``): the
RML's goes through the same :mod:`~manualcontrol.envs._native`; here only
the check of its own constants.
"""

import numpy as np
import pytest
from scenarios import PREVIEW as TYPICAL_PREVIEW

from manualcontrol.envs import _native
from manualcontrol.envs.signals import ForcingPair
from manualcontrol.estimators import RML
from manualcontrol.estimators._pilot_core import SC_SIZE
from manualcontrol.estimators.batch import FilterBatch
from manualcontrol.estimators.members import _rml_native
from manualcontrol.pilots import Pilot, simulate

pytestmark = pytest.mark.skipif(
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

# the thesis's DI preview pilot, with a far-viewpoint anticipation delay
PREVIEW = {**TYPICAL_PREVIEW["DI"], "tau_f": 0.6}
PURSUIT = {name: value for name, value in PREVIEW.items() if name != "tau_f"}


@pytest.fixture(scope="module")
def runs():
    base = simulate(
        Pilot("precision"), "popovici2017", "popovici2017", seed=0, measurement_time=10.0
    )
    u, e = np.array(base.u), np.array(base.e)
    u[300:340] = np.nan  # 0.4 s of the stick lost, three samples of the display
    e[500:503] = np.nan
    gaps = base.with_signals(u=u, e=e)
    spike = np.array(base.u)
    spike[600] = 1e300
    fifty = simulate(
        Pilot("precision"), "popovici2017", "popovici2017", seed=0, measurement_time=10.0, dt=0.02
    )
    ahead = simulate(Pilot("preview", PREVIEW), "DI", "vanderel-bw4", seed=1, measurement_time=10.0)
    return {
        "base": base,
        "gaps": gaps,
        "spike": base.with_signals(u=spike),
        "fifty": fifty,
        "ahead": ahead,
    }


CASES = {
    "SI, remnant at the perception": ("base", {}, {}),
    "remnant at the stick": ("base", {"remnant_injection": "output"}, {}),
    "no remnant": ("base", {"remnant": "none", "r2_remnant": 0.0}, {}),
    "DI: R weighted by the remnant": ("base", {"ce": "DI"}, {}),
    "learned break, variance score on all, noise first, no drift rule": (
        "base",
        {
            "learn_break": True,
            "variance_score": "all",
            "noise_first": 2.0,
            "drift_gain": 0.0,
            "step": 2.0,
        },
        {},
    ),
    "no spread limit, fixed R, identity noise input": (
        "base",
        {"spread_limit": 0.0, "fixed_R": 0.05, "noise_input": "identity"},
        {},
    ),
    "dropped samples, causal start, a pinned parameter": (
        "gaps",
        {
            "initial_variance": "causal",
            "limits": {"K_v": (0.45, 0.55)},
            "pinned_time": 1.0,
        },
        {},
    ),
    "50 Hz, smoothed": ("fifty", {}, {"smooth": True}),
    "a restart from the first pass's smoothed estimate": (
        "base",
        {"restarts": 1, "r2_remnant": 0.0},
        {},
    ),
    "preview model": (
        "ahead",
        {"model": "preview", "ce": "DI", "anticipation_time": 1.5, "initial": PREVIEW},
        {},
    ),
    "preview model, no anticipation delay": (
        "ahead",
        {"model": "preview", "ce": "DI", "anticipation_time": 0.0, "initial": PURSUIT},
        {},
    ),
    "a non-finite stop": ("spike", {}, {}),
    "a covariance stop": ("base", {"max_covariance": 1.0}, {}),
}


def same_bytes(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def assert_same_result(native, numba):
    for name in ARRAYS:
        assert same_bytes(getattr(native, name), getattr(numba, name)), name
    assert native.health == numba.health
    assert native.parameter_names == numba.parameter_names
    assert native.state_names == numba.state_names


def numba_only(monkeypatch):
    monkeypatch.setenv("MANUALCONTROL_NATIVE", "0")


@pytest.mark.parametrize("case", list(CASES))
def test_the_c_port_estimates_what_numba_does_bit_for_bit(case, runs, monkeypatch):
    run, settings, options = CASES[case]
    recording = runs[run]
    native = RML(**settings).estimate(recording, **options)
    assert _rml_native.library() is not None
    numba_only(monkeypatch)
    assert _rml_native.library() is None
    numba = RML(**settings).estimate(recording, **options)
    assert_same_result(native, numba)
    if case.endswith("stop"):
        assert numba.health.diverged
    if options.get("smooth"):
        assert not same_bytes(native.mean, RML(**settings).estimate(recording).mean)


@pytest.fixture(scope="module")
def long_run():
    """Long enough for the causal choice's decisions (from half a forcing period on)."""
    return simulate(
        Pilot("precision"), "popovici2017", "popovici2017", seed=2, measurement_time=60.0
    )


def test_the_causal_choice_in_c_equals_numba_offline_and_stepped(long_run, monkeypatch):
    run = long_run
    estimator = RML(remnant_injection="choose-causal")
    window = slice(0, round(estimator.settings.noise.window / run.dt) + 1)
    reset = {
        "var_u0": float(np.var(run["u"][window])),
        "var_e0": float(np.var(run["e"][window])),
        "forcing": ForcingPair.from_dict(run.metadata["forcing"]),
    }

    def both():
        whole = RML(remnant_injection="choose-causal").estimate(run)
        stepped = online_means(RML(remnant_injection="choose-causal"), run, reset)
        return whole, stepped

    native, native_stepped = both()
    assert native.settings["remnant_injection"]["decisions"]
    numba_only(monkeypatch)
    numba, numba_stepped = both()
    assert_same_result(native, numba)
    assert native.settings == numba.settings
    assert same_bytes(native_stepped, numba_stepped)
    assert same_bytes(native_stepped, native.mean)


def online_means(estimator, recording, reset=None):
    estimator.reset(recording.dt, t0=float(recording.t[0]), **(reset or {}))
    keys = estimator.sample_keys
    columns = [np.asarray(recording[key]) for key in keys]
    rows = []
    for k in range(len(recording)):
        estimate = estimator.update(
            {key: float(c[k]) for key, c in zip(keys, columns, strict=True)}
        )
        rows.append([estimate.mean[name] for name in estimator.parameter_names])
    return np.array(rows)


@pytest.mark.parametrize(
    "settings", [{"initial_variance": "causal", "initial": {"K_p": 1.5}}, {"ce": "DI"}]
)
def test_online_updates_and_blocks_in_c_equal_numba_and_the_offline_run(
    settings, runs, monkeypatch
):
    recording = runs["gaps"]
    causal = settings.get("initial_variance") == "causal"
    reset = None
    if not causal:
        window = slice(0, round(RML().settings.noise.window / recording.dt) + 1)
        reset = {
            "var_u0": float(np.nanvar(recording["u"][window])),
            "var_e0": float(np.nanvar(recording["e"][window])),
        }
    native = online_means(RML(**settings), recording, reset)
    if causal:
        assert same_bytes(native, RML(**settings).estimate(recording).mean)
    # a block of samples in one call, then the rest one by one
    blocked = RML(**settings)
    blocked.reset(recording.dt, t0=float(recording.t[0]), **(reset or {}))
    values = np.column_stack([recording[key] for key in blocked.sample_keys])
    blocked.update_block(values[:700])
    assert same_bytes(blocked.latest()[0], native[699])
    for row in values[700:]:
        blocked.update(dict(zip(blocked.sample_keys, row.tolist(), strict=True)))
    assert same_bytes(blocked.latest()[0], native[-1])
    numba_only(monkeypatch)
    assert same_bytes(online_means(RML(**settings), recording, reset), native)
    blocked = RML(**settings)
    blocked.reset(recording.dt, t0=float(recording.t[0]), **(reset or {}))
    blocked.update_block(values[:700])
    assert same_bytes(blocked.latest()[0], native[699])


def test_the_batched_step_in_c_equals_numba_with_restarts_and_idle_copies(monkeypatch):
    recordings = [
        simulate(
            Pilot.typical("precision", "SI"), "SI", "popovici2017", seed=s, measurement_time=4.0
        )
        for s in range(3)
    ]
    estimator = RML(initial_variance="causal", initial={"K_p": 1.5})

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


def test_a_c_port_whose_constants_differ_from_the_modules_is_refused(monkeypatch):
    from manualcontrol.estimators import _pilot_core

    monkeypatch.setattr(_native, "_LOADED", {})
    monkeypatch.setattr(_native, "_FAILED", {})
    monkeypatch.setattr(_rml_native, "_CHECKED", {})
    monkeypatch.setattr(_pilot_core, "SC_SIZE", SC_SIZE + 1)
    with pytest.raises(RuntimeError, match=r"constants .* differ .* edit the two together"):
        _rml_native.library()
