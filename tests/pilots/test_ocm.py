"""The optimal control model (Kleinman, Baron & Levison 1970/1971) as a pilot."""

from __future__ import annotations

import math
import re

import gymnasium as gym
import numpy as np
import pytest
import scipy.linalg

import manualcontrol.envs
from manualcontrol.envs.signals import ForcingPair, Multisine
from manualcontrol.estimators.analysis.frequency import describing_function
from manualcontrol.pilots import OptimalControlPilot, simulate_ocm, solve_ocm

# a short periodic forcing: 20.4 s is a whole number of samples at 60 and 100 Hz
PERIOD = 20.4
HARMONICS = np.array([3, 7, 13, 23, 37, 53])  # 0.92 ... 16.3 rad/s
FREQUENCIES = 2 * np.pi * HARMONICS / PERIOD
SHORT = ForcingPair(
    Multisine(FREQUENCIES, np.where(FREQUENCIES < 3, 0.5, 0.15), np.linspace(0, 5, 6), PERIOD),
    None,
)


def _measured(element: str, dt: float, seed: int | None = None, noise: bool = False):
    pilot = OptimalControlPilot(noise=noise)
    recording = simulate_ocm(
        pilot, element, SHORT, dt=dt, run_in=15.0, measurement_time=PERIOD, seed=seed
    )
    return pilot, describing_function(recording, SHORT, element=element)


# ----------------------------------------------------------------------- 1. independent LQG


def test_lqr_and_kalman_gains_match_scipy_riccati_solutions():
    """K/s with one second-order forcing filter, written out here from the model's text."""
    K_c = 1.5
    solution = solve_ocm("SI", "popovici2017", tau_v=0.2, tau_nms=0.1)
    (channel,) = solution.forcing
    w_b = channel.omega_b
    # state [x_c, w, w_dot, u]; element K/s in controllable canonical form: x_c' = u, y = K x_c
    A0 = np.zeros((4, 4))
    A0[0, 3] = 1.0
    A0[1, 2] = 1.0
    A0[2, 1] = -(w_b**2)
    A0[2, 2] = -2 * w_b
    b0 = np.array([0.0, 0.0, 0.0, 1.0])
    c_e = np.array([-K_c, 1.0, 0.0, 0.0])  # e = w - K x_c
    S = scipy.linalg.solve_continuous_are(
        A0, b0[:, None], np.outer(c_e, c_e), np.array([[solution.g]])
    )
    L = b0 @ S / solution.g
    # Riccati solutions agree to rounding; 1e-8 relative leaves room for conditioning
    np.testing.assert_allclose(solution.L, L, rtol=1e-8)
    assert 1.0 / L[3] == pytest.approx(0.1, rel=1e-9)  # g was solved for tau_nms = 0.1 s
    # Kalman filter for the same (converged) noise intensities
    A = A0.copy()
    A[3, 3] = -1 / 0.1
    B = np.array([0.0, 0.0, 0.0, 1 / 0.1])
    C = np.vstack([c_e, c_e @ A])
    noise_in = np.zeros((4, 2))
    noise_in[2, 0] = w_b**2 * math.sqrt(4 * channel.variance / w_b)
    noise_in[:, 1] = B
    Q = noise_in @ np.diag([1.0, solution.V_u]) @ noise_in.T
    V = np.diag(solution.V_y)
    P = scipy.linalg.solve_continuous_are(A.T, C.T, Q, V)
    K = P @ C.T @ np.linalg.inv(V)
    np.testing.assert_allclose(solution.K, K, rtol=1e-8, atol=1e-10 * np.abs(K).max())
    # the fixed point: intensities are pi rho times the variances they produce
    variances = solution.variances
    np.testing.assert_allclose(
        solution.V_y, math.pi * 0.01 * np.array([variances["e"], variances["e_dot"]]), rtol=1e-10
    )
    assert solution.V_u == pytest.approx(math.pi * 0.003 * variances["u_c"], rel=1e-10)
    assert 3 <= solution.iterations < 100


# ------------------------------------------------- 2./5. describing function, 60 and 100 Hz


@pytest.mark.parametrize("element", ["SI", "DI"])
def test_analytic_describing_function_matches_closed_loop_simulation(element):
    """Noise-free run, Fourier coefficients at the forcing lines over one whole period.

    The sampled pilot differs from the continuous one by second-order terms in omega dt
    (cubic read of the delayed display, perception linear between samples, centred
    command hold): at 100 Hz about 0.2 % and 0.1 deg up to 16 rad/s (measured), so 1 %
    and 0.5 deg hold with margin while a wrong delay (0.01 s shifts 9 deg at 16 rad/s)
    or a 2 % gain error fails.
    """
    pilot, measured = _measured(element, 0.01)
    analytic = pilot.frequency_response(measured.frequencies)
    ratio = measured.pilot / analytic
    np.testing.assert_array_less(np.abs(np.abs(ratio) - 1), 0.01)
    np.testing.assert_array_less(np.abs(np.degrees(np.angle(ratio))), 0.5)


def test_describing_function_is_the_same_at_60_and_100_hz():
    """1 % and 0.5 deg: the 60 Hz error is (100/60)^2 of the 100 Hz one, 0.6 % at 16 rad/s."""
    _, fast = _measured("SI", 0.01)
    _, slow = _measured("SI", 1 / 60)
    ratio = slow.pilot / fast.pilot
    np.testing.assert_array_less(np.abs(np.abs(ratio) - 1), 0.01)
    np.testing.assert_array_less(np.abs(np.degrees(np.angle(ratio))), 0.5)


def test_noisy_describing_function_scatters_within_its_remnant():
    """With remnant a line's relative error is about 1/sqrt(SNR) (the remnant's share of u
    at that line, SNR from the neighbouring bins); 3/sqrt(SNR) is a 3-sigma bound. The
    SNR of one period is low here (0.3-1.5 bounds), so the tight check is the noise-free one.
    """
    pilot, measured = _measured("SI", 0.01, seed=3, noise=True)
    analytic = pilot.frequency_response(measured.frequencies)
    error = np.abs(measured.pilot / analytic - 1)
    np.testing.assert_array_less(error, 3 / np.sqrt(measured.snr))


# --------------------------------------------------------------------- 3. crossover model


def _crossovers(forcing):
    return {
        element: solve_ocm(element, forcing).crossover()
        for element in ("gain", "SI", "DI", "1/(s(s+1))")
    }


def test_crossover_model_behaviour():
    """McRuer's ranges on a lab forcing (popovici2017, RMS frequency 0.85 rad/s).

    Measured: K/s crosses at 4.0 rad/s with 42 deg and a pilot gain flat within 2.6 dB
    over 0.5-5 rad/s; K/s^2 crosses at 2.9 rad/s with 34 deg and lead (pilot phase
    +43 deg at 0.5 rad/s).
    """
    values = _crossovers("popovici2017")
    omega_c, margin, delay = values["SI"]
    assert 2.0 <= omega_c <= 4.5
    assert 20.0 <= margin <= 70.0
    assert 0.1 <= delay <= 0.4  # effective delay of the crossover model
    omega = np.geomspace(0.5, 5.0, 30)
    gain_db = 20 * np.log10(np.abs(solve_ocm("SI", "popovici2017").frequency_response(omega)))
    assert np.ptp(gain_db) <= 6.0  # within +-3 dB of its mid value
    # K/s^2: the pilot generates lead, and crosses over lower
    phase = np.angle(solve_ocm("DI", "popovici2017").frequency_response(omega[omega <= 2]))
    assert np.all(np.degrees(phase) > 0.0)
    assert values["DI"][0] < omega_c
    assert 20.0 <= values["DI"][1] <= 70.0


def test_crossover_regression_on_a_wide_band_forcing():
    """vanderel-bw4: K 3.9 > K/s 2.8 > K/s^2 2.1 rad/s (the phase margins here are high)."""
    values = _crossovers("vanderel-bw4")
    assert values["gain"][0] > values["SI"][0] > values["DI"][0]


def test_remnant_spectrum_is_positive_and_falls_off():
    solution = solve_ocm("SI", "popovici2017")
    spectrum = solution.remnant_spectrum(np.array([0.5, 5.0, 50.0]))
    assert np.all(np.isfinite(spectrum)) and np.all(spectrum > 0)
    assert spectrum[2] < spectrum[1]  # the neuromuscular lag filters the noise


# ------------------------------------------------------------------- 4. reproducibility


def test_same_seed_same_run_and_different_seeds_differ():
    def run(seed):
        pilot = OptimalControlPilot()
        return simulate_ocm(pilot, "SI", SHORT, run_in=0.0, measurement_time=3.0, seed=seed).u

    first = run(7)
    np.testing.assert_array_equal(first, run(7))
    assert np.max(np.abs(first - run(8))) > 1e-3


def test_acts_through_gymnasium_with_rates_and_a_generator():
    env = gym.make(
        "ManualControl/CompensatoryTracking-v0",
        controlled_element="DI",
        measurement_time=2.0,
        include_rates=True,
    )
    pilot = OptimalControlPilot(tau_v=0.25, tau_nms=0.12)
    observation, _ = env.reset(seed=1)
    pilot.reset(np.random.default_rng(1), env=env)
    actions = []
    for _ in range(100):
        action = pilot.act(observation)
        assert action.shape == (1,)
        actions.append(action[0])
        observation, *_ = env.step(action)
    assert np.all(np.isfinite(actions)) and np.any(np.array(actions) != 0.0)
    assert pilot.solution.tau_nms == pytest.approx(0.12, rel=1e-9)


def test_to_dict_round_trip_and_given_g():
    pilot = OptimalControlPilot("DI", "popovici2017", tau_v=0.15, tau_nms=None, g=0.01, noise=False)
    again = OptimalControlPilot.from_dict(pilot.to_dict())
    assert again == pilot
    np.testing.assert_allclose(
        again.frequency_response([1.0, 3.0]), pilot.frequency_response([1.0, 3.0])
    )
    assert pilot.solution.g == 0.01
    assert OptimalControlPilot().tau_nms == 0.1


# ------------------------------------------------------------------------------ bad input


@pytest.mark.parametrize(
    ("arguments", "error", "message"),
    [
        ({"tau_v": -0.1}, ValueError, "tau_v must be >= 0, got -0.1"),
        ({"tau_nms": 0.0}, ValueError, "tau_nms must be > 0, got 0.0"),
        ({"rho_y": 0.0}, ValueError, "rho_y must be > 0, got 0.0"),
        ({"rho_u": -1.0}, ValueError, "rho_u must be > 0, got -1.0"),
        ({"g": -2.0, "tau_nms": None}, ValueError, "g must be > 0, got -2.0"),
        ({"g": 1.0, "tau_nms": 0.1}, ValueError, "give tau_nms (neuromuscular lag, s) or g"),
        ({"element": "bogus"}, ValueError, "element: controlled element must be one of"),
        ({"disturbance_at": "side"}, ValueError, "disturbance_at must be one of"),
        ({"noise": "no"}, TypeError, "noise must be True or False"),
        ({"delay": 0.2}, TypeError, "unexpected keyword argument 'delay'"),
    ],
)
def test_bad_arguments_raise_naming_argument_value_and_range(arguments, error, message):
    with pytest.raises(error, match=re.escape(message)):
        OptimalControlPilot(**arguments)


def test_act_before_reset_and_wrong_task_raise():
    with pytest.raises(RuntimeError, match=re.escape("call pilot.reset(seed, env=env)")):
        OptimalControlPilot().act(np.zeros(1))
    env = gym.make("ManualControl/PursuitTracking-v0", measurement_time=1.0)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="compensatory"):
        OptimalControlPilot().reset(0, env=env)
    with pytest.raises(ValueError, match="element must be constant"):
        solve_ocm("popovici2017-tv", "popovici2017")
    assert manualcontrol.envs  # registers the env ids
