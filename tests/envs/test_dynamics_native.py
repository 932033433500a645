"""The LPV toolkit's C port against its numba kernels: the same numbers, bit for bit.

The C port (``_dynamics_native.c``) runs wherever it builds and the numba kernels
elsewhere, so no number may depend on which ran: the matrix exponentials and the LPV
runs are compared byte for byte (``tobytes``: equal bytes is what identical means,
signed zeros included). The exponentials cover every branch of Al-Mohy & Higham's
Algorithm 3.1: each Padé order 3, 5, 7, 9 and 13, order 13 with and without scaling
and squaring, the zero matrix, runs of equal consecutive matrices, and the badly
scaled canonical forms of high-order Padé delays. The LPV runs cover shared and
per-sample matrices, several delay channels, fractional and time-varying delays,
held states, a start from rest and from a past (``history="initial"``), delays
shorter than the interpolation's reach and the first-order-hold ramp; then the
isolated pilot of the resimulation end to end.

Also: where no compiler is found the numba kernels run and say why; the binding
refuses a build whose argument lists differ and arrays the C would misread; and a
process that discretises and simulates through the C port never imports numba.
"""

import math
import os
import subprocess
import sys

import numpy as np
import pytest

from manualcontrol.envs import _dynamics_native, _expm, _native
from manualcontrol.envs.dynamics import (
    Block,
    DelayChannel,
    Discretization,
    discretize,
    interconnect,
    pade,
    simulate_lpv,
    tf_to_ccf,
)

needs_compiler = pytest.mark.skipif(
    _native._compiler() is None, reason="no C compiler: the C port cannot be built here"
)


def same_bytes(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def both(monkeypatch, compute):
    """``compute()`` through the C port, then through the numba kernels."""
    monkeypatch.delenv("MANUALCONTROL_NATIVE", raising=False)
    assert _dynamics_native.library() is not None
    native = compute()
    monkeypatch.setenv("MANUALCONTROL_NATIVE", "0")
    assert _dynamics_native.library() is None
    return native, compute()


# ------------------------------------------------------------ matrix exponential


def chosen_orders(matrix):
    """The Padé order and the squarings Algorithm 3.1 picks for ``matrix`` (float64).

    The selection of ``expm_batch_kernel`` retold in numpy, to show which branch each
    case reaches (the norms are those of the transpose, as the kernel's).
    """
    a = matrix.T
    powers = [a, a @ a]
    powers += [powers[1] @ powers[1], powers[1] @ (powers[1] @ powers[1])]
    norm = [np.abs(p).sum(axis=0).max() for p in powers]
    if norm[0] == 0.0:
        return 0, 0

    def ell(scale, m):
        v = np.ones(a.shape[0])
        for _ in range(2 * m + 1):
            v = scale * (v @ np.abs(a))
        if v.max() == 0.0:
            return 0
        alpha = v.max() / (scale * norm[0] * _expm._ELL_RECIPROCAL[list(_expm._ORDERS).index(m)])
        return max(math.ceil(math.log2(alpha / _expm._UNIT_ROUNDOFF) / (2 * m)), 0)

    d6 = norm[3] ** (1 / 6)
    eta = max(norm[2] ** 0.25, d6)
    d8 = 0.0
    for option, m in enumerate(_expm._ORDERS[:4]):
        if option == 2:
            d8 = np.abs(powers[2] @ powers[2]).sum(axis=0).max() ** 0.125
            eta = max(d6, d8)
        if eta < _expm._THETA[option] and ell(1.0, m) == 0:
            return int(m), 0
    eta5 = min(eta, max(d8, np.abs(powers[2] @ powers[3]).sum(axis=0).max() ** 0.1))
    s = max(math.ceil(math.log2(eta5 / _expm._THETA[4])), 0) if eta5 > 0 else 0
    return 13, s + ell(2.0**-s, 13)


def scaled(seed, n, norms):
    rng = np.random.default_rng(seed)
    matrices = rng.standard_normal((len(norms), n, n))
    norms = np.asarray(norms, dtype=float)
    return matrices * (norms / np.abs(matrices).sum(axis=-2).max(axis=-1))[:, None, None]


def pade_loop_augmented(order, dt):
    """A Padé delay closed around 5/s^2, augmented as discretize does (test_expm.py)."""
    num, den = pade(0.3, order)
    delay = tf_to_ccf(num, den)
    element = tf_to_ccf([5.0], [1.0, 0.0, 0.0])
    n = order + 2
    A = np.zeros((n, n))
    A[:order, :order] = delay.A
    A[order:, order:] = element.A
    A[order:, :order] = element.B @ delay.C
    A[:order, order:] = -delay.B @ element.C
    augmented = np.zeros((n + 2, n + 2))
    augmented[:n, :n] = A * dt
    augmented[:order, n : n + 1] = delay.B * dt
    augmented[n, n + 1] = 1.0
    return augmented


NORMS = [1e-6, 5e-3, 0.1, 0.5, 1.5, 3.0, 8.0, 60.0, 900.0]
EXPM_CASES = {
    **{f"dense {n}x{n}": scaled(n, n, NORMS) for n in (1, 2, 3, 5, 9, 13)},
    "zero and identity-like": np.stack([np.zeros((4, 4)), np.eye(4) * 1e-9, np.zeros((4, 4))]),
    "runs of equal matrices": np.stack(
        [m for m in scaled(7, 4, [0.3, 4.0]) for _ in range(3)] + [scaled(7, 4, [0.3])[0]]
    ),
    "signed zeros": np.stack([np.zeros((3, 3)), -np.zeros((3, 3)), np.diag([0.0, -0.0, 1.0])]),
    **{
        f"Padé delay of order {order}": pade_loop_augmented(order, 0.01)[None]
        for order in (3, 5, 8)
    },
    "Padé delay at 0.1 s": pade_loop_augmented(5, 0.1)[None],
    "triangular, large": np.triu(scaled(3, 6, [1e4, 2.0]), 0),
}


def test_the_cases_reach_every_branch_of_the_algorithm():
    reached = {chosen_orders(m) for matrices in EXPM_CASES.values() for m in matrices}
    orders = {order for order, _ in reached}
    assert orders == {0, 3, 5, 7, 9, 13}
    assert (13, 0) in reached
    assert any(order == 13 and s > 0 for order, s in reached)


@needs_compiler
@pytest.mark.parametrize("case", list(EXPM_CASES))
def test_expm_in_c_equals_numba_bit_for_bit(case, monkeypatch):
    matrices = EXPM_CASES[case]
    native, numba = both(monkeypatch, lambda: _expm.expm_batch(matrices))
    assert same_bytes(native, numba)
    one_by_one = [_expm.expm_batch(m[None])[0] for m in matrices]  # numba, alone
    assert same_bytes(np.stack(one_by_one), native)


@needs_compiler
def test_discretize_in_c_equals_numba_on_a_per_sample_pilot(monkeypatch):
    # a pilot's lead-lag and neuromuscular dynamics whose parameters vary per sample,
    # with runs of equal samples, and two uncoupled groups of states
    t = np.arange(400) * 0.01
    K = np.where(t < 2.0, 1.5, 1.5 + 0.3 * np.sin(t))
    lead = tf_to_ccf(np.stack([K * 0.4, K], axis=-1), [0.1, 1.0])
    nms = tf_to_ccf([100.0], [1.0, 2 * 0.2 * 10.0, 100.0])
    blocks = [Block(lead, ("e",), ("v",)), Block(nms, ("w",), ("u",))]
    system = interconnect(blocks, ("e",), ("u",), delays=[DelayChannel("v", "w")]).system
    native, numba = both(monkeypatch, lambda: discretize(system.A, system.B, 0.01, [1]))
    for name in ("phi", "gamma", "gamma_ramp"):
        assert same_bytes(getattr(native, name), getattr(numba, name)), name


# ------------------------------------------------------------------ LPV stepping


def lpv_case(seed, n_samples, n_x, n_u, n_y, per_sample, n_delay, held=(), history="rest"):
    """A random stable discrete LPV system; ``per_sample``: which matrices vary."""
    rng = np.random.default_rng(seed)

    def matrices(name, shape, scale):
        count = n_samples if name in per_sample else 1
        return scale * rng.standard_normal((count, *shape))

    phi = matrices("phi", (n_x, n_x), 0.3 / max(n_x, 1)) + np.eye(n_x) * 0.6
    gamma = matrices("gamma", (n_x, n_u), 0.1)
    ramp = matrices("gamma", (n_x, n_u), 0.05)
    c = matrices("c", (n_y, n_x), 1.0)
    d = matrices("d", (n_y, n_u), 0.5)
    inputs = rng.standard_normal((n_samples, n_u))
    channels = rng.choice(n_u, size=n_delay, replace=False)
    delays = 0.01 * (rng.uniform(0.5, 25.0, size=(n_samples, n_delay)))
    return {
        "discretization": Discretization(phi, gamma, ramp),
        "C": c,
        "D": d,
        "inputs": inputs,
        "dt": 0.01,
        "x0": rng.standard_normal(n_x),
        "delay_inputs": channels,
        "delay_outputs": rng.choice(n_y, size=n_delay),
        "delays": delays if n_delay else None,
        "held_states": held,
        "history": history,
    }


LPV_CASES = {
    "time invariant, no delay": lpv_case(1, 300, 3, 2, 2, (), 0),
    "time varying, no delay": lpv_case(2, 300, 4, 2, 3, ("phi", "gamma", "c", "d"), 0),
    "one delay, shared matrices": lpv_case(3, 400, 3, 2, 2, (), 1),
    "one delay, varying phi and c": lpv_case(4, 400, 4, 2, 2, ("phi", "c"), 1),
    "three delay channels, all varying": lpv_case(5, 500, 5, 4, 3, ("phi", "gamma", "c", "d"), 3),
    "held states": lpv_case(6, 400, 4, 3, 2, ("gamma", "d"), 2, held=(0, 2)),
    "a past before the start": lpv_case(7, 400, 3, 2, 2, ("phi",), 2, history="initial"),
    "held states and a past": lpv_case(8, 300, 3, 3, 3, ("c",), 2, held=(1,), history="initial"),
    "one sample": lpv_case(9, 1, 2, 2, 1, (), 1),
    "no states": lpv_case(10, 50, 0, 2, 1, (), 1),
}
# a delay shorter than the four interpolation samples and one constant in time
LPV_CASES["short and constant delays"] = {
    **LPV_CASES["one delay, shared matrices"],
    "delays": np.array([0.012]),
}
LPV_CASES["whole-sample delays"] = {
    **LPV_CASES["three delay channels, all varying"],
    "delays": np.array([[0.05, 0.1, 0.2]]),
}
# a ramp matrix shared while gamma varies (both are read at gamma's sample)
LPV_CASES["shared ramp, varying gamma"] = {
    **LPV_CASES["held states"],
    "discretization": Discretization(
        LPV_CASES["held states"]["discretization"].phi,
        LPV_CASES["held states"]["discretization"].gamma,
        LPV_CASES["held states"]["discretization"].gamma_ramp[:1],
    ),
}
LPV_CASES["negative channel indices"] = {
    **LPV_CASES["one delay, shared matrices"],
    "delay_inputs": [-1],
    "delay_outputs": [-2],
}


@needs_compiler
@pytest.mark.parametrize("case", list(LPV_CASES))
def test_simulate_lpv_in_c_equals_numba_bit_for_bit(case, monkeypatch):
    arguments = LPV_CASES[case]
    native, numba = both(monkeypatch, lambda: simulate_lpv(**arguments))
    for got, expected in zip(native, numba, strict=True):
        assert same_bytes(got, expected)
        assert np.all(np.isfinite(got))


@needs_compiler
def test_a_delayed_pilot_with_first_order_hold_in_c_equals_numba(monkeypatch):
    # the resimulation's own path: a per-sample pilot discretised with its ramp column,
    # run through an exact delay with time-varying tau
    n = 600
    t = np.arange(n) * 0.01
    K = 2.0 + 0.5 * np.sin(0.7 * t)
    lead = tf_to_ccf(np.stack([K * 0.5, K], axis=-1), [0.05, 1.0])
    nms = tf_to_ccf([100.0], [1.0, 2 * 0.15 * 10.0, 100.0])
    blocks = [Block(lead, ("e",), ("v",)), Block(nms, ("w",), ("u",))]
    model = interconnect(blocks, ("e",), ("u",), delays=[DelayChannel("v", "w")])
    system = model.system
    e = np.sin(1.3 * t)[:, None] + 0.2 * np.cos(5.1 * t)[:, None]
    inputs = np.concatenate([e, np.zeros((n, 1))], axis=1)
    tau = (0.25 + 0.05 * np.sin(0.3 * t))[:, None]

    def run():
        discretization = discretize(system.A, system.B, 0.01, model.delay_inputs)
        return simulate_lpv(
            discretization,
            system.C,
            system.D,
            inputs,
            0.01,
            delay_inputs=model.delay_inputs,
            delay_outputs=[model.outputs.index("v")],
            delays=tau,
        )

    native, numba = both(monkeypatch, run)
    for got, expected in zip(native, numba, strict=True):
        assert same_bytes(got, expected)


@needs_compiler
def test_the_isolated_pilot_of_a_resimulation_in_c_equals_numba(monkeypatch):
    from manualcontrol.estimators.analysis.metrics import resimulate_parameters
    from manualcontrol.pilots import Pilot, simulate

    recording = simulate(Pilot("precision"), "popovici2017", "popovici2017", measurement_time=8.0)
    n = len(recording)
    parameters = {"K_p": 1.5, "K_v": 0.5, "tau_v": 0.2, "omega_nms": 8.0, "zeta_nms": 0.3}
    parameters["K_p"] = 1.5 * (1.0 + 0.1 * np.sin(np.arange(n) * 0.01))
    parameters["tau_v"] = np.where(np.arange(n) < n // 2, 0.2, 0.23)
    native, numba = both(
        monkeypatch, lambda: resimulate_parameters("precision", parameters, recording)
    )
    assert same_bytes(native, numba)


# ------------------------------------------------------------------ the build


@pytest.fixture
def fresh_build_state(monkeypatch):
    """A process that has built nothing yet (the module's memory of builds emptied)."""
    monkeypatch.setattr(_native, "_LOADED", {})
    monkeypatch.setattr(_native, "_FAILED", {})
    monkeypatch.setattr(_dynamics_native, "_CHECKED", {})


def test_without_a_compiler_numba_runs_the_same_numbers_and_says_why(
    monkeypatch, tmp_path, fresh_build_state
):
    arguments = LPV_CASES["held states and a past"]
    matrices = EXPM_CASES["dense 5x5"]
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    monkeypatch.setenv("PATH", str(tmp_path))  # and no cc either
    assert _dynamics_native.library() is None
    assert "no C compiler found" in _native.native_failure(_dynamics_native.SOURCE)
    exponentials = _expm.expm_batch(matrices)
    outputs = simulate_lpv(**arguments)[1]
    monkeypatch.setenv("MANUALCONTROL_NATIVE", "0")
    assert "MANUALCONTROL_NATIVE=0" in _native.native_failure(_dynamics_native.SOURCE)
    assert same_bytes(exponentials, _expm.expm_batch(matrices))
    assert same_bytes(outputs, simulate_lpv(**arguments)[1])


@needs_compiler
def test_a_build_whose_argument_lists_differ_is_refused(monkeypatch, fresh_build_state):
    monkeypatch.setattr(_dynamics_native, "ABI", _dynamics_native.ABI + 1)
    with pytest.raises(RuntimeError, match=r"differ from its binding.*edit the two together"):
        _dynamics_native.library()


@needs_compiler
def test_arrays_the_c_would_misread_are_refused():
    lib = _dynamics_native.library()
    tables = (_expm._COEFFICIENTS, _expm._THETA, _expm._ORDERS, _expm._ELL_RECIPROCAL, 2.0**-53)
    matrices = np.zeros((2, 3, 3))
    with pytest.raises(ValueError, match="matrices must be C-contiguous float64"):
        _dynamics_native.expm_batch(lib, np.asfortranarray(matrices), *tables)
    with pytest.raises(ValueError, match="orders must be C-contiguous int64"):
        _dynamics_native.expm_batch(lib, matrices, *tables[:2], tables[2] * 1.0, *tables[3:])
    phi = np.zeros((1, 2, 2))
    arguments = [phi, np.zeros((1, 2, 1)), np.zeros((1, 2, 1)), np.zeros((1, 1, 2)),
                 np.zeros((1, 1, 1)), np.zeros((5, 1)), np.zeros(2), np.array([0]),
                 np.array([0]), np.zeros((5, 1)), 4, np.zeros(2, dtype=bool)]  # fmt: skip
    _dynamics_native.simulate_lpv(lib, *arguments)
    wrong = list(arguments)
    wrong[7] = np.array([1])  # input 1 of one
    with pytest.raises(ValueError, match="delay channel indices"):
        _dynamics_native.simulate_lpv(lib, *wrong)
    wrong = list(arguments)
    wrong[11] = np.zeros(2, dtype=np.int64)
    with pytest.raises(ValueError, match="held_state must be C-contiguous bool"):
        _dynamics_native.simulate_lpv(lib, *wrong)
    with pytest.raises(ValueError, match="delay_inputs must be indices into 1 signals"):
        simulate_lpv(
            discretize(np.zeros((1, 1)), np.ones((1, 1)), 0.01),
            np.ones((1, 1)),
            np.zeros((1, 1)),
            np.zeros((5, 1)),
            0.01,
            delay_inputs=[1],
            delay_outputs=[0],
            delays=0.05,
        )


@needs_compiler
def test_discretizing_and_simulating_through_the_c_port_never_imports_numba():
    script = """
import sys
import numpy as np
from manualcontrol.envs import _dynamics_native
from manualcontrol.envs.dynamics import discretize, pade, simulate_lpv, tf_to_ccf
assert _dynamics_native.library() is not None
num, den = pade(np.linspace(0.2, 0.3, 200), 3)
system = tf_to_ccf(num, den)
d = discretize(system.A, system.B, 0.01)
states, outputs = simulate_lpv(d, system.C, system.D, np.ones((200, 1)), 0.01,
                               delay_inputs=[0], delay_outputs=[0], delays=0.1)
assert np.all(np.isfinite(outputs))
print(sorted(name for name in sys.modules if name.split(".")[0] in ("numba", "llvmlite")))
"""
    environment = {**os.environ}
    environment.pop("MANUALCONTROL_NATIVE", None)
    done = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        env=environment,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"
