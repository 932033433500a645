"""envs.dynamics against independent computations (scipy.signal, scipy.integrate)."""

import math
import re

import numpy as np
import pytest
import scipy.integrate
import scipy.interpolate
import scipy.signal

from manualcontrol.envs._interpolation import (
    bicubic_derivative_weights,
    bicubic_weights,
    interpolate_many,
)
from manualcontrol.envs.dynamics import (
    Block,
    DelayChannel,
    DelayLine,
    StateSpace,
    discretize,
    frequency_response,
    interconnect,
    pade,
    pade_coefficients,
    poly_multiply,
    simulate_lpv,
    tf_to_ccf,
)

# ----------------------------------------------------------------------------- Padé


def test_pade_third_order_matches_popovici_appendix():
    # Popovici eqs. 40-41: 120 + 60 tau s + 12 tau^2 s^2 + tau^3 s^3 (and -tau in the numerator)
    tau = 0.3
    num, den = pade(tau, 3)
    np.testing.assert_allclose(den * 120, [tau**3, 12 * tau**2, 60 * tau, 120], rtol=1e-15)
    np.testing.assert_allclose(num * 120, [-(tau**3), 12 * tau**2, -60 * tau, 120], rtol=1e-15)


@pytest.mark.parametrize("order", [1, 2, 3, 4, 5, 6])
def test_pade_matches_scipy_pade_of_exponential_series(order):
    # scipy solves a linear system for the coefficients; it becomes ill-conditioned
    # (rcond ~ 1e-17) beyond order 6, where the exact-fraction test below takes over
    tau = 0.26
    taylor = [(-1.0) ** k / math.factorial(k) for k in range(2 * order + 1)]
    p, q = scipy.interpolate.pade(taylor, order)
    # scipy's polynomials are in x = tau s; normalise both constant terms to 1
    expected_num = p.coeffs / p.coeffs[-1] * tau ** np.arange(order, -1, -1)
    expected_den = q.coeffs / q.coeffs[-1] * tau ** np.arange(order, -1, -1)
    num, den = pade(tau, order)
    np.testing.assert_allclose(num, expected_num, rtol=1e-10)
    np.testing.assert_allclose(den, expected_den, rtol=1e-10)


@pytest.mark.parametrize("order", [8, 10, 12])
def test_pade_coefficients_match_exact_fractions(order):
    # independent derivation: the [m/m] Padé denominator of exp(-x) has coefficients
    # C(m, k) (2m - k)! / (2m)! in exact rational arithmetic
    from fractions import Fraction

    expected = [
        Fraction(math.comb(order, k) * math.factorial(2 * order - k), math.factorial(2 * order))
        for k in range(order + 1)
    ]
    np.testing.assert_allclose(pade_coefficients(order), [float(c) for c in expected], rtol=1e-15)


def test_pade_is_all_pass_and_matches_delay_phase_at_low_frequency():
    tau, order = 0.3, 5
    num, den = pade(tau, order)
    omega = np.linspace(0.1, 10, 50)
    response = np.polyval(num, 1j * omega) / np.polyval(den, 1j * omega)
    np.testing.assert_allclose(np.abs(response), 1.0, rtol=1e-12)
    # within the forcing band the order-5 phase error is far below a degree
    phase_error = np.angle(response * np.exp(1j * omega * tau))
    assert np.max(np.abs(phase_error[omega < 5])) < 1e-4


def test_pade_batched_equals_scalar():
    taus = np.array([0.1, 0.25, 0.6])
    num, den = pade(taus, 3)
    for i, tau in enumerate(taus):
        n1, d1 = pade(tau, 3)
        np.testing.assert_array_equal(num[i], n1)
        np.testing.assert_array_equal(den[i], d1)


def test_pade_order_zero_is_unity():
    num, den = pade(0.4, 0)
    np.testing.assert_array_equal(num, [1.0])
    np.testing.assert_array_equal(den, [1.0])
    np.testing.assert_array_equal(pade_coefficients(0), [1.0])


@pytest.mark.parametrize(
    ("tau", "order", "error", "message"),
    [
        (-0.1, 3, ValueError, "tau must be >= 0 (a delay, not a preview), got -0.1"),
        (float("nan"), 3, ValueError, "tau must be finite, got nan"),
        (0.1, -1, ValueError, "order must be >= 0, got -1"),
        (0.1, 2.5, TypeError, "order must be an integer, got 2.5"),
    ],
)
def test_pade_rejects_bad_input(tau, order, error, message):
    with pytest.raises(error, match=re.escape(message)):
        pade(tau, order)


# --------------------------------------------------------------- canonical form


def test_tf_to_ccf_has_thesis_structure():
    # thesis eqs. 4.6-4.7 for (b2 s^2 + b1 s + b0)/(s^3 + a2 s^2 + a1 s + a0)
    b2, b1, b0, a2, a1, a0 = 2.0, 3.0, 5.0, 7.0, 11.0, 13.0
    model = tf_to_ccf([b2, b1, b0], [1.0, a2, a1, a0])
    np.testing.assert_array_equal(model.A, [[0, 1, 0], [0, 0, 1], [-a0, -a1, -a2]])
    np.testing.assert_array_equal(model.B, [[0], [0], [1]])
    np.testing.assert_array_equal(model.C, [[b0, b1, b2]])
    np.testing.assert_array_equal(model.D, [[0]])


@pytest.mark.parametrize(
    ("num", "den"),
    [
        ([4.0], [1.0, 3.0, 0.0]),
        ([2.0, 3.0, 1.0], [2.0, 4.0, 5.0]),  # biproper, non-monic
        ([1.0, -2.0, 0.5, 3.0], [1.0, 6.0, 11.0, 6.0]),
        ([3.0], [1.0]),  # static gain
    ],
)
def test_tf_to_ccf_realises_the_transfer_function(num, den):
    model = tf_to_ccf(num, den)
    omega = np.logspace(-1, 2, 30)
    expected = np.polyval(num, 1j * omega) / np.polyval(den, 1j * omega)
    got = frequency_response(model, omega)[:, 0, 0]
    np.testing.assert_allclose(got, expected, rtol=1e-12)


def test_tf_to_ccf_batched_equals_per_sample():
    omega_b = np.array([3.0, 2.0, 1.0])
    den = np.stack([np.ones(3), omega_b, np.zeros(3)], axis=-1)
    num = np.full((3, 1), 4.0)
    batched = tf_to_ccf(num, den)
    assert batched.batch_shape == (3,)
    for i in range(3):
        single = tf_to_ccf(num[i], den[i])
        np.testing.assert_array_equal(batched.A[i], single.A)
        np.testing.assert_array_equal(batched.C[i], single.C)


def test_tf_to_ccf_rejects_improper_and_zero_leading():
    with pytest.raises(ValueError, match="transfer function must be proper"):
        tf_to_ccf([1.0, 0.0, 0.0], [1.0, 1.0])
    with pytest.raises(ValueError, match="non-zero leading coefficient"):
        tf_to_ccf([1.0], [0.0, 1.0])


def test_state_space_checks_shapes():
    with pytest.raises(ValueError, match=re.escape("B must end in shape (2, 1)")):
        StateSpace(np.zeros((2, 2)), np.zeros((3, 1)), np.zeros((1, 2)), np.zeros((1, 1)))


def test_poly_multiply_matches_numpy():
    a, b = [1.0, 2.0, 3.0], [4.0, -1.0]
    np.testing.assert_array_equal(poly_multiply(a, b), np.polymul(a, b))


# ------------------------------------------------------------------ discretisation


def _second_order():
    A = np.array([[0.0, 1.0], [-64.0, -4.8]])
    B = np.array([[0.0, 1.0], [1.0, 0.5]])
    return A, B


def test_discretize_zoh_matches_cont2discrete():
    A, B = _second_order()
    C, D = np.eye(2), np.zeros((2, 2))
    exact = discretize(A, B, 0.01)
    phi, gamma, *_ = scipy.signal.cont2discrete((A, B, C, D), 0.01, method="zoh")
    np.testing.assert_allclose(exact.phi, phi, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(exact.gamma, gamma, rtol=1e-13, atol=1e-15)


def test_discretize_ramp_term_is_exact_for_piecewise_linear_inputs():
    # scipy's lsim with interp=True integrates linearly interpolated inputs exactly
    A, B = _second_order()
    C, D = np.eye(2), np.zeros((2, 2))
    dt = 0.01
    t = np.arange(0, 3, dt)
    u = np.stack([np.sin(3 * t), np.cos(1.3 * t) ** 2], axis=1)
    exact = discretize(A, B, dt)
    x = np.zeros(2)
    states = [x]
    for k in range(len(t) - 1):
        x = exact.phi @ x + exact.gamma @ u[k] + exact.gamma_ramp @ (u[k + 1] - u[k])
        states.append(x)
    _, _, reference = scipy.signal.lsim((A, B, C, D), u, t, interp=True)
    np.testing.assert_allclose(np.array(states), reference, rtol=1e-9, atol=1e-12)


def test_discretize_batched_equals_single():
    A, B = _second_order()
    batch = np.stack([A, 2 * A, A])
    exact = discretize(batch, B, 0.02)
    for i, Ai in enumerate(batch):
        single = discretize(Ai, B, 0.02)
        np.testing.assert_array_equal(exact.phi[i], single.phi)


def test_discretize_rejects_bad_dt():
    A, B = _second_order()
    with pytest.raises(ValueError, match=re.escape("dt must be > 0, got 0.0")):
        discretize(A, B, 0.0)


# ---------------------------------------------------------------------- LPV stepping


def test_simulate_lpv_time_invariant_matches_dlsim():
    A, B = _second_order()
    C = np.array([[1.0, 0.0]])
    D = np.array([[0.0, 0.2]])
    dt = 0.01
    t = np.arange(0, 5, dt)
    u = np.stack([np.sin(2 * t), np.sign(np.sin(0.7 * t))], axis=1)
    exact = discretize(A, B, dt)
    _, y = simulate_lpv(exact, C, D, u, dt)
    _, reference, _ = scipy.signal.dlsim((exact.phi, exact.gamma, C, D, dt), u)
    np.testing.assert_allclose(y, reference, rtol=1e-12, atol=1e-14)


def test_simulate_lpv_time_varying_matches_fine_ode_integration():
    # parameters frozen over each sample (the LPV discretisation): the exact
    # piecewise solution from solve_ivp must agree to the ODE tolerance
    dt = 0.01
    n = 300
    t = np.arange(n) * dt
    omega = 4.0 + 3.0 * np.sin(0.8 * t)
    A = np.zeros((n, 2, 2))
    A[:, 0, 1] = 1.0
    A[:, 1, 0] = -(omega**2)
    A[:, 1, 1] = -0.6 * omega
    B = np.array([[0.0], [1.0]])
    u = np.cos(1.7 * t)[:, None]
    exact = discretize(A, B, dt)
    states, _ = simulate_lpv(exact, np.eye(2), np.zeros((2, 1)), u, dt)
    x = np.zeros(2)
    for k in range(n - 1):
        assert np.allclose(states[k], x, rtol=1e-8, atol=1e-10)
        solution = scipy.integrate.solve_ivp(
            lambda _s, z, k=k: A[k] @ z + B[:, 0] * u[k, 0],
            (0.0, dt),
            x,
            rtol=1e-12,
            atol=1e-14,
        )
        x = solution.y[:, -1]


def _delayed_cascade(source, dt, tau=0.2345, t_end=8.0):
    """Simulated and fine-grid reference output of ``source -> delay tau -> 1/(s+1)``.

    ``source`` is a block from the held input ``r`` to ``v``. The reference runs
    scipy's ``lsim`` with zero-order hold on a grid 40x finer whose step divides
    ``tau``, so the delay there is an exact shift of whole fine samples.
    """
    lag = tf_to_ccf([1.0], [1.0, 1.0])
    diagram = interconnect(
        [Block(source, ("r",), ("v",)), Block(lag, ("w",), ("y",))],
        inputs=("r",),
        outputs=("y",),
        delays=(DelayChannel("v", "w"),),
    )
    t = np.arange(0, t_end, dt)
    r = np.sin(2 * t) + 0.5 * np.sin(5.3 * t + 1.0)
    exact = discretize(diagram.system.A, diagram.system.B, dt)
    _, outputs = simulate_lpv(
        exact,
        diagram.system.C,
        diagram.system.D,
        np.stack([r, np.zeros_like(t)], axis=1),
        dt,
        delay_inputs=diagram.delay_inputs,
        delay_outputs=diagram.delay_outputs,
        delays=np.full((len(t), 1), tau),
    )
    fine = 40
    fine_dt = dt / fine
    shift = round(tau / fine_dt)
    assert abs(shift * fine_dt - tau) < 1e-12
    t_fine = np.arange(len(t) * fine) * fine_dt
    r_fine = np.repeat(r, fine)  # the held input
    system = (source.A, source.B, source.C, source.D)
    v_fine = scipy.signal.lsim(system, r_fine, t_fine, interp=False)[1]
    w_fine = np.concatenate([np.zeros(shift), v_fine[:-shift]])
    # a held source delays into a staircase (exact with zero-order hold); a smooth
    # one into a smooth signal (linear interpolation between fine samples)
    smooth = source.D[0, 0] == 0.0
    y_fine = scipy.signal.lsim(([1.0], [1.0, 1.0]), w_fine, t_fine, interp=smooth)[1]
    return outputs[:, 0], y_fine[::fine]


SMOOTH_SOURCE = tf_to_ccf([1.0], [0.05, 1.0])  # v = C x: no feedthrough
HELD_SOURCE = StateSpace(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.ones((1, 1)))


@pytest.mark.parametrize(
    ("source", "bound"), [(SMOOTH_SOURCE, 3e-4), (HELD_SOURCE, 3e-5)], ids=["smooth", "held"]
)
def test_exact_delay_channel_matches_fine_grid_reference_to_second_order(source, bound):
    # smooth part: bicubic read, linear between samples; held part: mean of the
    # delayed staircase. Both errors are second order in dt.
    errors = []
    for dt in (0.01, 0.005):
        got, reference = _delayed_cascade(source, dt)
        errors.append(np.max(np.abs(got - reference)))
    # (omega dt)^2 / 8 for the 5.3 rad/s component is 3.5e-4 of its amplitude
    assert errors[0] < bound
    assert errors[0] / errors[1] > 3.5  # halving dt quarters the error


def test_delay_of_whole_samples_is_exact_for_held_signals():
    got, reference = _delayed_cascade(HELD_SOURCE, 0.01, tau=0.23)
    np.testing.assert_allclose(got, reference, atol=1e-12)


def test_delay_feedback_loop_matches_method_of_steps():
    # y' = r(t) - a y(t - tau), y(t <= 0) = 0, r = 1: a retarded equation in feedback
    a, tau, dt, t_end = 2.0, 0.3, 0.01, 6.0
    integrator = StateSpace([[0.0]], [[1.0]], [[1.0]], [[0.0]])
    diagram = interconnect(
        [Block(integrator, ("dy",), ("y",))],
        inputs=("r",),
        outputs=("y",),
        sums={"dy": {"r": 1.0, "w": -a}},
        delays=(DelayChannel("y", "w"),),
    )
    t = np.arange(0, t_end, dt)
    exact = discretize(diagram.system.A, diagram.system.B, dt)
    _, outputs = simulate_lpv(
        exact,
        diagram.system.C,
        diagram.system.D,
        np.stack([np.ones_like(t), np.zeros_like(t)], axis=1),
        dt,
        delay_inputs=diagram.delay_inputs,
        delay_outputs=diagram.delay_outputs,
        delays=tau,
    )
    # method of steps with dense outputs of the previous interval
    pieces = []

    def history(s):
        if s <= 0:
            return 0.0
        for start, sol in pieces:
            if s <= start + tau + 1e-12:
                return float(sol(s)[0])
        raise AssertionError("history beyond the integrated range")

    y0, start = 0.0, 0.0
    while start < t_end:
        sol = scipy.integrate.solve_ivp(
            lambda s, y: [1.0 - a * history(s - tau)],
            (start, start + tau),
            [y0],
            dense_output=True,
            rtol=1e-11,
            atol=1e-13,
        )
        pieces.append((start, sol.sol))
        y0, start = sol.y[0, -1], start + tau
    reference = np.array([history(s) for s in t])
    np.testing.assert_allclose(outputs[:, 0], reference, atol=2e-4)


def test_interconnect_feedback_equals_analytic_closed_loop():
    # unity feedback of K/s^2 with lead (kp + kv s): T = G C / (1 + G C)
    plant = tf_to_ccf([5.0], [1.0, 0.0, 0.0])
    controller = tf_to_ccf([0.4, 0.2], [0.05, 1.0])
    loop = interconnect(
        [Block(controller, ("e",), ("u",)), Block(plant, ("u",), ("y",))],
        inputs=("ft",),
        outputs=("y", "u"),
        sums={"e": {"ft": 1.0, "y": -1.0}},
    )
    open_num = np.polymul([5.0], [0.4, 0.2])
    open_den = np.polymul([1.0, 0.0, 0.0], [0.05, 1.0])
    omega = np.logspace(-1, 1.5, 20)
    L = np.polyval(open_num, 1j * omega) / np.polyval(open_den, 1j * omega)
    got = frequency_response(loop.system, omega)
    np.testing.assert_allclose(got[:, 0, 0], L / (1 + L), rtol=1e-10)


def test_interconnect_rejects_algebraic_loop_and_unknown_signal():
    gain = StateSpace(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), [[1.0]])
    with pytest.raises(ValueError, match="algebraic loop"):
        interconnect(
            [Block(gain, ("e",), ("y",))], ("r",), ("y",), sums={"e": {"r": 1.0, "y": 1.0}}
        )
    with pytest.raises(ValueError, match="signal 'q' is not a block output, an input or a sum"):
        interconnect([Block(gain, ("q",), ("y",))], ("r",), ("y",))


# -------------------------------------------------------------- interpolation


@pytest.mark.parametrize("d", [0.0, 0.13, 0.5, 0.77, 1.0])
def test_bicubic_weights_partition_unity_and_match_boer_kenyon(d):
    f = lambda x: 1.5 * x**3 - 2.5 * x**2 + 1  # noqa: E731
    g = lambda x: -0.5 * x**3 + 2.5 * x**2 - 4 * x + 2  # noqa: E731
    weights = bicubic_weights(d)
    np.testing.assert_allclose(weights, [g(1 + d), f(d), f(1 - d), g(2 - d)], atol=1e-15)
    assert sum(weights) == pytest.approx(1.0, abs=1e-15)
    assert sum(bicubic_derivative_weights(d)) == pytest.approx(0.0, abs=1e-14)


def test_bicubic_interpolation_reproduces_quadratics_and_smooth_signals():
    samples = np.arange(20.0)
    quadratic = 0.3 * samples**2 - 2 * samples + 1
    positions = np.linspace(1.0, 17.0, 41)
    values, slopes = interpolate_many(quadratic, positions)
    np.testing.assert_allclose(values, 0.3 * positions**2 - 2 * positions + 1, rtol=1e-12)
    np.testing.assert_allclose(slopes, 0.6 * positions - 2, rtol=1e-12)
    dt = 0.01
    signal = np.sin(1.5 * np.arange(2000) * dt)
    positions = np.linspace(5, 1990, 777)
    values, slopes = interpolate_many(signal, positions)
    np.testing.assert_allclose(values, np.sin(1.5 * positions * dt), atol=1e-7)
    np.testing.assert_allclose(slopes / dt, 1.5 * np.cos(1.5 * positions * dt), atol=1e-4)


def test_delay_line_reads_fractional_and_varying_delays():
    dt = 0.01
    line = DelayLine(max_delay=0.5, dt=dt)
    assert line._buffer.shape[0] == 54  # bounded memory: ceil(0.5/0.01) + 4
    rng = np.random.default_rng(3)
    for k in range(400):
        line.push(math.sin(2.0 * k * dt))
        if k > 60:
            delay = float(rng.uniform(0.03, 0.5))
            value, slope = line.read_with_derivative(delay)
            t_read = k * dt - delay
            assert value == pytest.approx(math.sin(2.0 * t_read), abs=2e-6)
            assert slope == pytest.approx(2.0 * math.cos(2.0 * t_read), abs=2e-4)


def test_delay_line_starts_at_initial_value_and_rejects_bad_delays():
    line = DelayLine(max_delay=0.2, dt=0.01, initial=1.5)
    line.push(2.0)
    assert line.read(0.1) == 1.5
    assert line.read(0.0) == 2.0
    with pytest.raises(ValueError, match=re.escape("delay must lie in [0, 0.2] s, got 0.3")):
        line.read(0.3)
    with pytest.raises(ValueError, match=re.escape("max_delay must be >= 0, got -1.0")):
        DelayLine(max_delay=-1.0, dt=0.01)
