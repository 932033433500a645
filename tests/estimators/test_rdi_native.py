"""The RDI's C port against its numba kernels: the same numbers, bit for bit, on every path.

The C port (``_rdi_native.c``) runs wherever it builds and the numba kernels
elsewhere, so a user's numbers must not depend on which ran: every array of an
estimate (and the smoother's storage), the online updates and the run's counters are
compared byte for byte. The configurations cover the kernel's branches: the paper's
ARMAX(1, 1) with decimation and sign constraints (holds), known coefficients removed
from the filter, no sign constraints, the gain-delay model on a closed-loop recording
with a zero delay (the one-sided cubic) pinned at its limit, higher orders with jitter,
dropped samples in the output and in the input, smoothing, and the two ways a filter
stops (non-finite values, a covariance blow-up). The resimulation of each estimate
(``resimulate``, ``simulate_output`` in C) is compared as well.
"""

import numpy as np
import pytest

from manualcontrol.envs import _native
from manualcontrol.envs.schedules import BandLimitedRandomWalk
from manualcontrol.estimators import RDI, RDISettings
from manualcontrol.estimators.members import _rdi_core, _rdi_native
from manualcontrol.pilots import Pilot, simulate
from manualcontrol.pilots.open_loop import ARMAXSystem, simulate_open_loop

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

A = (0.5924,)
B = (1.5119, -1.1043)


def open_loop(noise=0.0, seconds=20.0):
    walk = BandLimitedRandomWalk(0.1, 0.1 / 600, 0.3, 60.0, 11)
    system = ARMAXSystem(A, B, walk, noise_std=noise)
    return simulate_open_loop(
        system,
        "boer-kenyon1998",
        realisation=0,
        seed=1,
        measurement_time=seconds,
        run_in=2.0,
        keep_run_in=True,
    )


PAPER = {
    "n_a": 1,
    "n_b": 1,
    "decimation": 4,
    "input": "ft",
    "output": "u",
    "Q_d": 0.4,
    "Q_c": 1e-6,
    "R": 0.1,
    "P0_c": 0.1,
    "initial": {"d": 0.1, "a_1": A[0], "b_0": B[0], "b_1": B[1]},
}


@pytest.fixture(scope="module")
def runs():
    noisy = open_loop(noise=0.01, seconds=10.0)
    clean = open_loop(seconds=6.0)
    spike = np.array(noisy.u)
    spike[304] = 1.7e308  # after a small y[303]: a_1's gain ~1/y[303] overflows it
    closed = simulate(
        Pilot("precision"), "popovici2017", "popovici2017", seed=0, measurement_time=12.0
    )
    u, e = np.array(closed.u), np.array(closed.e)
    u[120:132] = np.nan  # the output lost for 12 samples
    e[300:303] = np.nan  # and the input for 3
    gaps = closed.with_signals(u=u, e=e)
    return {
        "noisy": noisy,
        "clean": clean,
        "gaps": gaps,
        "spike": noisy.with_signals(u=spike),
        "closed": closed,
    }


#: ARMAX(1, 1) on the closed loop's error and stick (the error may mark dropped samples)
GAPS = {"n_a": 1, "n_b": 1, "decimation": 2, "R": 0.01, "Q_c": 1e-4}

CASES = {
    "the paper's ARMAX(1, 1), decimation 4, sign constraints": ("noisy", PAPER, {}),
    "known coefficients": ("noisy", {**PAPER, "estimated": ("d", "a_1")}, {}),
    "no sign constraints, decimation 1, smoothed": (
        "noisy",
        {**PAPER, "sign_constraints": False, "decimation": 1},
        {"smooth": True},
    ),
    "gain-delay, closed loop, a zero delay pinned at its limit": (
        "closed",
        {"n_a": 0, "n_b": 0, "R": 0.01, "Q_d": 0.01, "Q_c": 1e-4, "initial": {"d": 0.0}},
        {},
    ),
    "gain-delay, closed loop, default settings, smoother storage": (
        "closed",
        {"n_a": 0, "n_b": 0},
        {"smoother_inputs": True},
    ),
    "ARMAX(2, 2), decimation 2, jitter, renamed": (
        "clean",
        {
            **PAPER,
            "n_a": 2,
            "n_b": 2,
            "decimation": 2,
            "R": 1e-4,
            "jitter": 1e-9,
            "initial": {"d": 0.3},
            "delay_limits": (0.05, 0.6),
            "report_names": {"d": "tau"},
        },
        {},
    ),
    "dropped samples in the output and the input": ("gaps", GAPS, {"smooth": True}),
    "a non-finite stop": (
        "spike",
        {**PAPER, "R": 1e-12, "decimation": 1, "sign_constraints": False, "estimated": ("a_1",)},
        {},
    ),
    "a covariance stop": (
        "clean",
        {**PAPER, "R": 1e-4, "estimated": ("d", "a_1"), "max_covariance": 1e-5, "P0_c": 1.0},
        {},
    ),
}


def same_bytes(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def numba_only(monkeypatch):
    monkeypatch.setenv("MANUALCONTROL_NATIVE", "0")


def estimate(settings, recording, options):
    rdi = RDI(RDISettings(**settings))
    result = rdi.estimate(recording, **options)
    _, belief, scratch = rdi._records
    state = [belief.x, belief.P, belief.p, belief.ring_r, belief.ring_y, belief.sc]
    state += [scratch.work.S, scratch.work.K, scratch.work.log_det]
    return result, state


@needs_compiler
@pytest.mark.parametrize("case", list(CASES))
def test_the_c_port_estimates_what_numba_does_bit_for_bit(case, runs, monkeypatch):
    run, settings, options = CASES[case]
    recording = runs[run]
    native, native_state = estimate(settings, recording, options)
    assert _rdi_native.library() is not None
    numba_only(monkeypatch)
    assert _rdi_native.library() is None
    numba, numba_state = estimate(settings, recording, options)
    for name in ARRAYS:
        assert same_bytes(getattr(native, name), getattr(numba, name)), name
    for i, (a, b) in enumerate(zip(native_state, numba_state, strict=True)):
        assert same_bytes(a, b), i
    assert native.health == numba.health
    assert native.parameter_names == numba.parameter_names
    assert native.settings == numba.settings
    if options.get("smoother_inputs"):
        (a,) = native.smoother_inputs.blocks
        (b,) = numba.smoother_inputs.blocks
        for name in ("x_filtered", "P_filtered", "x_predicted", "P_predicted"):
            assert same_bytes(getattr(a, name), getattr(b, name)), name
    if case == "a non-finite stop":
        assert numba.health.divergence_reason == "non-finite values"
    if case == "a covariance stop":
        assert numba.health.divergence_reason == "covariance blow-up"
    if case.startswith("the paper's"):
        assert numba.settings["resolved"]["held_fraction"] > 0.0
    if case.startswith("dropped"):
        # the output's NaN at once, the input's where the delayed reads reach it
        assert numba.dropped[120:132].all() and numba.dropped[303:360].any()
        assert not numba.dropped[:120].any()
    if case.startswith("gain-delay, closed loop, a zero"):
        assert numba.pinned[:, 0].any()


@needs_compiler
@pytest.mark.parametrize("case", list(CASES))
def test_the_c_port_resimulates_what_numba_does_bit_for_bit(case, runs, monkeypatch):
    from manualcontrol.estimators.members.rdi import resimulate

    run, settings, options = CASES[case]
    recording = runs[run]
    result, _ = estimate(settings, recording, options)
    native = resimulate(result, recording)
    numba_only(monkeypatch)
    assert _rdi_native.library() is None
    assert same_bytes(native, resimulate(result, recording))


@needs_compiler
def test_simulate_output_in_c_is_numba_s_on_any_orders():
    from manualcontrol.estimators.members import _rdi_kernels

    lib = _rdi_native.library()
    rng = np.random.default_rng(0)
    for n, lam, n_a, n_b in ((500, 1, 2, 3), (700, 3, 1, 0), (1, 1, 0, 0), (0, 2, 1, 1)):
        p = rng.normal(size=(n, 2 + n_a + n_b)) * 0.3
        p[:, 0] = np.abs(p[:, 0]) * 0.05  # delays from none to a few samples
        r = rng.normal(size=n)
        native = _rdi_native.simulate_output(lib, p, r, 0.01, lam, n_a, n_b)
        assert same_bytes(native, _rdi_kernels.simulate_output(p, r, 0.01, lam, n_a, n_b))
    with pytest.raises(ValueError, match="p must be"):
        _rdi_native.simulate_output(lib, np.zeros((3, 5)), np.zeros(3), 0.01, 1, 1, 1)


def online_means(rdi, recording, samples):
    rdi.reset(recording.dt, t0=float(recording.t[0]))
    rows = []
    for sample in samples:
        estimate = rdi.update(sample)
        rows.append(
            [estimate.mean[name] for name in rdi.parameter_names]
            + [estimate.std[name] for name in rdi.parameter_names]
            + [estimate.prediction]
        )
    return np.array(rows)


@needs_compiler
def test_online_updates_in_c_equal_numba_and_the_offline_run(runs, monkeypatch):
    recording = runs["gaps"]
    settings = RDISettings(**GAPS)
    samples = [
        {"e": float(recording.e[k]), "u": float(recording.u[k])} for k in range(len(recording))
    ]
    rdi = RDI(settings)
    native = online_means(rdi, recording, samples[:200])
    assert rdi._native[2] is not None  # the C step runs, bound to the one-row output
    assert not isinstance(rdi._entry, type(_rdi_core.rdi_step))
    native = online_means(rdi, recording, samples)  # a second reset binds anew
    offline = rdi.estimate(recording)
    n = len(rdi.parameter_names)
    assert same_bytes(native[:, :n], offline.mean)
    assert same_bytes(native[:, n : 2 * n], offline.std)
    assert same_bytes(native[:, -1], offline.predictions[:, 0])
    numba_only(monkeypatch)
    rdi = RDI(settings)
    assert same_bytes(online_means(rdi, recording, samples), native)
    assert rdi._native[2] is None


@pytest.fixture
def fresh_build_state(monkeypatch):
    """A process that has built nothing yet (the module's memory of builds emptied)."""
    monkeypatch.setattr(_native, "_LOADED", {})
    monkeypatch.setattr(_native, "_FAILED", {})
    monkeypatch.setattr(_rdi_native, "_CHECKED", {})


def test_without_a_compiler_numba_runs_the_same_numbers_and_says_why(
    runs, monkeypatch, tmp_path, fresh_build_state
):
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    monkeypatch.setenv("PATH", "/nonexistent")  # and no cc either
    assert _rdi_native.library() is None
    assert "no C compiler found" in _native.native_failure(_rdi_native.SOURCE)
    result = RDI(RDISettings(**PAPER)).estimate(runs["noisy"])
    monkeypatch.setenv("MANUALCONTROL_NATIVE", "0")
    assert same_bytes(result.mean, RDI(RDISettings(**PAPER)).estimate(runs["noisy"]).mean)


@needs_compiler
def test_a_c_port_whose_constants_differ_from_the_modules_is_refused(
    monkeypatch, fresh_build_state
):
    monkeypatch.setattr(_rdi_core, "SC_SIZE", _rdi_core.SC_SIZE + 1)
    with pytest.raises(RuntimeError, match=r"constants .* differ .* edit the two together"):
        _rdi_native.library()


@needs_compiler
def test_records_the_c_port_cannot_read_are_refused(runs):
    rdi = RDI(RDISettings(**PAPER))
    rdi.reset(runs["noisy"].dt)
    config, belief, scratch = rdi._records
    lib = _rdi_native.library()
    bad = belief._replace(P=np.asfortranarray(np.zeros((4, 4)))[:, :3])
    with pytest.raises(ValueError, match="record field P"):
        _rdi_native.NativeRecords(lib, (config, bad, scratch), rdi._row)
    short = belief._replace(ring_y=belief.ring_y[:-1].copy())
    with pytest.raises(ValueError, match="record field ring_y has shape"):
        _rdi_native.NativeRecords(lib, (config, short, scratch), rdi._row)
