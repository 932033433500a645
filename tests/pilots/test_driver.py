"""The cybernetic driver: eq. 2 against its block diagram, its simulation, acting in the env."""

import re
import warnings

import gymnasium as gym
import numpy as np
import pytest
import scipy.integrate
import scipy.signal

import manualcontrol.envs  # noqa: F401
from manualcontrol.envs.driving import Road
from manualcontrol.envs.schedules import Ramp, Sine
from manualcontrol.pilots import HumanLimitWarning, LevisonRemnant
from manualcontrol.pilots.driver import CyberneticDriverModel, Driver, printed_driver_matrices
from manualcontrol.pilots.driving import resimulate_driver, simulate_driving

NOMINAL = {
    "K_p": 3.4,
    "K_c": 15.0,
    "T_I": 1.0,
    "T_L": 3.0,
    "tau_p": 0.04,
    "K_r": 1.0,
    "K_t": 12.0,
    "T_N": 0.1,
}
V_X = 18.0
INPUTS = ("theta_far", "theta_near", "delta_d", "Gamma_s")
OUTPUTS = ("Gamma_d", "delta_sw")


def _block_diagram(p, v_x):
    """Zhao Fig. 1 with a first-order Padé delay, as numpy polynomials (outputs x inputs)."""
    delay = (np.array([-p["tau_p"] / 2, 1.0]), np.array([p["tau_p"] / 2, 1.0]))
    nms = np.array([p["T_N"], 1.0])
    gain = p["K_r"] * v_x + p["K_t"]
    far = (p["K_p"] * delay[0], delay[1])
    near = (
        np.polymul(p["K_c"] / v_x * np.array([p["T_L"], 1.0]), delay[0]),
        np.polymul(np.array([p["T_I"], 1.0]), delay[1]),
    )
    return {
        ("delta_sw", "theta_far"): far,
        ("delta_sw", "theta_near"): near,
        ("delta_sw", "delta_d"): (np.array([0.0]), np.array([1.0])),
        ("delta_sw", "Gamma_s"): (np.array([0.0]), np.array([1.0])),
        ("Gamma_d", "theta_far"): (gain * far[0], np.polymul(far[1], nms)),
        ("Gamma_d", "theta_near"): (gain * near[0], np.polymul(near[1], nms)),
        ("Gamma_d", "delta_d"): (np.array([-p["K_t"]]), nms),
        ("Gamma_d", "Gamma_s"): (np.array([-1.0]), nms),
    }


def _response(num, den, omega):
    s = 1j * omega
    return np.polyval(num, s) / np.polyval(den, s)


@pytest.mark.parametrize(
    "values",
    [NOMINAL, {**NOMINAL, "K_p": 4.1, "K_c": 21.0, "T_L": 2.2, "tau_p": 0.07, "K_t": 8.0}],
)
def test_corrected_eq2_realises_the_block_diagram(values):
    system = CyberneticDriverModel().state_space(values, V_X)
    omega = np.logspace(-2, 2, 40)
    expected = _block_diagram(values, V_X)
    for i, output in enumerate(OUTPUTS):
        for j, name in enumerate(INPUTS):
            num, den = scipy.signal.ss2tf(system.A, system.B, system.C, system.D, input=j)
            ours = _response(num[i], den, omega)
            np.testing.assert_allclose(
                ours, _response(*expected[(output, name)], omega), rtol=1e-10, atol=1e-12
            )
            structure = CyberneticDriverModel().transfer_function(values, V_X, output, name)
            np.testing.assert_allclose(_response(*structure, omega), ours, rtol=1e-10, atol=1e-12)


def test_the_printed_entries_give_the_wrong_dc_gain():
    """Zhao eq. 2 as printed: Gamma_d/theta_near at DC is 41, the block diagram's is 25."""
    p = NOMINAL
    corrected = CyberneticDriverModel().state_space(p, V_X)
    printed = printed_driver_matrices(p, V_X)
    # the printed entries, typed from the paper
    assert printed.A[2, 0] == pytest.approx(-(1 * 18 + 12 * 15) / 0.1 / 18 * (1 - 3 / 1))
    assert printed.B[2, 1] == pytest.approx(-(1 * 18 + 12 * 15 * 3) / (18 * 1 * 0.1))

    def dc(system):
        return system.C @ np.linalg.solve(-system.A, system.B) + system.D

    assert dc(corrected)[0, 1] == pytest.approx((1 * 18 + 12) * 15 / 18)  # 25
    assert dc(printed)[0, 1] == pytest.approx(41.0)
    assert dc(corrected)[0, 0] == pytest.approx((1 * 18 + 12) * 3.4)  # unchanged entries agree
    assert dc(printed)[0, 0] == pytest.approx(dc(corrected)[0, 0])


def test_frequency_response_has_the_exact_delay():
    model = CyberneticDriverModel()
    omega = np.array([0.5, 2.0, 8.0])
    exact = model.frequency_response(NOMINAL, V_X, omega, "delta_sw", "theta_far")
    np.testing.assert_allclose(exact, 3.4 * np.exp(-0.04j * omega), rtol=1e-12)


def _eq2_cases():
    """Table 2's values, each parameter at the ends of its flagged range, and random draws.

    The draws are log-uniform over six decades with random signs where a sign is valid,
    so that the operations round at many exponents; speeds include 64 km/h and 18 m/s.
    """
    model = CyberneticDriverModel()
    nominal = model.vector({})
    cases = [nominal]
    for i, spec in enumerate(model.parameters):
        for end in spec.human:
            p = nominal.copy()
            p[i] = end
            cases.append(p)
    rng = np.random.default_rng(2019)
    signed = np.array([not spec.positive and spec.valid[0] < 0 for spec in model.parameters])
    for _ in range(300):
        p = nominal * 10.0 ** rng.uniform(-3.0, 3.0, nominal.shape)
        cases.append(np.where(signed & (rng.random(nominal.shape) < 0.5), -p, p))
    return cases, (64.0 / 3.6, V_X, 0.7, 41.0)


def test_eq2_run_as_python_writes_the_compiled_kernels_bytes():
    """Eq. 2's one definition run as Python gives the bytes numba's compilation of it does.

    The Zhao filters' tuning reads eq. 2 from :meth:`CyberneticDriverModel.state_space`,
    which runs the definition as Python (so that an identification through their C port
    never imports numba); their kernels and the simulation call it compiled
    (``driver_matrices``). They are equal to the bit: the same IEEE-754 double
    operations on the same operands in the same order (no fastmath: LLVM neither
    reorders nor fuses a multiply and an add). Both start from NaN-filled arrays here,
    so the zeroing is compared as well, with and without the fifth (input remnant)
    column.
    """
    from manualcontrol.pilots._driver_kernels import driver_matrices
    from manualcontrol.pilots.driver import _eq2_matrices

    model = CyberneticDriverModel()
    cases, speeds = _eq2_cases()
    for p in cases:
        for v_x in speeds:
            for columns in (4, 5):
                shapes = ((3, 3), (3, columns), (2, 3), (2, columns))
                compiled = [np.full(shape, np.nan) for shape in shapes]
                numpy = [np.full(shape, np.nan) for shape in shapes]
                driver_matrices(p, v_x, *compiled)
                _eq2_matrices(p, v_x, *numpy)
                for name, ours, theirs in zip("ABCD", numpy, compiled, strict=True):
                    assert ours.tobytes() == theirs.tobytes(), (name, columns, p.tolist(), v_x)
            # the API itself, as the tuning calls it (four inputs)
            system = model.state_space(dict(zip(model.parameter_names, p, strict=True)), v_x)
            compiled = [np.zeros((3, 3)), np.zeros((3, 4)), np.zeros((2, 3)), np.zeros((2, 4))]
            driver_matrices(p, v_x, *compiled)
            ours = (system.A, system.B, system.C, system.D)
            for name, mine, theirs in zip("ABCD", ours, compiled, strict=True):
                assert mine.tobytes() == theirs.tobytes(), (name, p.tolist(), v_x)


# ----------------------------------------------------------------------- simulation


def _driver_reference(p, v_x, dt, inputs):
    """Gamma_d of the driver alone, exact delay, inputs held: method of steps (solve_ivp)."""
    n = inputs.shape[0]
    times = np.arange(n + 1) * dt
    lead = p["T_L"] / p["T_I"]
    c = p["K_c"] / v_x
    gain = p["K_r"] * v_x + p["K_t"]
    # the lag x_1 exactly: first order relaxation towards the held theta_near
    x1 = np.zeros(n + 1)
    a = np.exp(-dt / p["T_I"])
    for k in range(n):
        x1[k + 1] = a * x1[k] + (1 - a) * inputs[k, 1]

    def x1_at(t):
        k = np.clip(np.floor(t / dt).astype(int), 0, n - 1)
        return inputs[k, 1] + (x1[k] - inputs[k, 1]) * np.exp(-(t - k * dt) / p["T_I"])

    def visual(t):  # w(t): zero before the start
        if t < 0:
            return 0.0
        k = min(int(np.floor(t / dt + 1e-12)), n - 1)
        return p["K_p"] * inputs[k, 0] + c * (lead * inputs[k, 1] + (1 - lead) * x1_at(t))

    def rhs(t, y):
        k = min(int(np.floor(t / dt + 1e-12)), n - 1)
        return [
            (-y[0] + gain * visual(t - p["tau_p"]) - p["K_t"] * inputs[k, 2] - inputs[k, 3])
            / p["T_N"]
        ]

    out = [0.0]
    y = [0.0]
    for k in range(n):
        sol = scipy.integrate.solve_ivp(
            rhs, (times[k], times[k + 1]), y, rtol=1e-11, atol=1e-13, max_step=dt / 20
        )
        y = sol.y[:, -1]
        out.append(float(y[0]))
    return np.array(out[:n])


def test_exact_delay_step_against_a_fine_ode_integration():
    rng = np.random.default_rng(0)
    n = 300
    t = np.arange(n) * 0.01
    inputs = np.column_stack(
        [
            0.05 * np.sin(0.7 * t),
            0.02 * np.sin(2.3 * t + 1) + 0.002 * rng.standard_normal(n),
            0.1 * np.sin(0.9 * t),
            0.3 * np.cos(1.1 * t),
        ]
    )
    reference = _driver_reference(NOMINAL, V_X, 0.01, inputs)
    parameters = np.tile([NOMINAL[k] for k in CyberneticDriverModel().parameter_names], (n, 1))
    gamma, _ = resimulate_driver(parameters, inputs, V_X, 0.01)
    # the delayed smooth part is taken linear over each sample: error O(dt^2), measured
    # 1.4e-6 of the peak at 100 Hz; the tolerance leaves a factor 7
    scale = np.max(np.abs(reference))
    assert np.max(np.abs(gamma - reference)) < 1e-5 * scale


@pytest.mark.filterwarnings("ignore:Badly conditioned filter coefficients")
def test_pade_driver_equals_lsim_of_the_block_diagram():
    driver = Driver(delay_order=1)
    recording = simulate_driving(driver, measurement_time=40.0)
    inputs = np.column_stack([recording[n] for n in INPUTS])
    speed = recording.metadata["speed"]
    total = np.zeros(len(recording))
    for j, name in enumerate(INPUTS):
        num, den = _block_diagram(NOMINAL, speed)[("Gamma_d", name)]
        system = scipy.signal.cont2discrete((num, den), 0.01, method="zoh")
        total += scipy.signal.dlsim((system[0].ravel(), system[1], 0.01), inputs[:, j])[1][:, 0]
    np.testing.assert_allclose(
        recording["Gamma_d"], total, rtol=1e-8, atol=1e-9 * np.max(np.abs(total))
    )


def test_resimulation_with_the_true_traces_reproduces_the_driver():
    driver = Driver({"K_p": Ramp(3.4, 4.4, 5.0, 15.0), "tau_p": Sine(0.05, 0.012, 7.0)})
    recording = simulate_driving(driver, measurement_time=30.0)
    parameters = np.column_stack([recording.parameters[n] for n in driver.model.parameter_names])
    gamma, delta_sw = resimulate_driver(
        parameters,
        np.column_stack([recording[n] for n in INPUTS]),
        recording.metadata["speed"],
        0.01,
    )
    np.testing.assert_allclose(gamma, recording["Gamma_d"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(delta_sw, recording["delta_sw"], rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    ("steering", "driver"),
    [
        ("torque", Driver({"K_p": Ramp(3.4, 4.4, 2.0, 8.0), "K_c": Sine(15.0, 2.0, 5.0)})),
        ("torque", Driver(remnant=LevisonRemnant(injection="input", P_r=0.2))),
        ("torque", Driver(remnant=LevisonRemnant(injection="output", P_r=0.1), delay_order=1)),
        ("angle", Driver(remnant=LevisonRemnant(injection="output", P_r=0.1, omega_r=2.0))),
    ],
)
def test_driver_acting_in_the_env_equals_simulate_driving(steering, driver):
    env = gym.make(
        "ManualControl/LaneKeeping-v0", steering=steering, measurement_time=15.0, run_in=1.0
    )
    observation, _ = env.reset(seed=0)
    driver.reset(11, env=env)
    while True:
        observation, _, terminated, truncated, _ = env.step(driver.act(observation))
        if terminated or truncated:
            break
    acted = env.unwrapped.recording(include_run_in=True)
    simulated = simulate_driving(
        driver, steering=steering, measurement_time=15.0, run_in=1.0, seed=11, keep_run_in=True
    )
    action = "Gamma_d" if steering == "torque" else "delta_command"
    np.testing.assert_allclose(acted[action], simulated["u"], rtol=1e-12, atol=1e-12)
    for name in ("theta_far", "theta_near", "delta_d", "Gamma_s", "y_L"):
        np.testing.assert_allclose(acted[name], simulated[name], rtol=1e-12, atol=1e-12)


def test_remnant_power_ratio_and_its_share_of_the_action():
    driver = Driver(remnant=LevisonRemnant(injection="input", P_r=0.25))
    recording = simulate_driving(driver, measurement_time=60.0, seed=3)
    u, u_n = recording["u"], recording["u_n"]
    assert np.var(u_n) / np.var(u) == pytest.approx(0.25, rel=1e-9)
    assert recording.metadata["remnant_power_ratio"] == pytest.approx(0.25, rel=1e-9)
    # superposition: the drive minus its remnant part is the remnant-free drive
    clean = simulate_driving(Driver(), measurement_time=60.0)
    np.testing.assert_allclose(u - u_n, clean["u"], rtol=1e-9, atol=1e-9)


def test_sensor_noise_is_measurement_only():
    clean = simulate_driving(Driver(), measurement_time=60.0)
    noisy = simulate_driving(
        Driver(), measurement_time=60.0, seed=1, output_noise={"Gamma_d": 0.1, "delta_sw": 0.01}
    )
    np.testing.assert_array_equal(noisy["Gamma_d_true"], clean["Gamma_d"])
    np.testing.assert_array_equal(noisy["y_L"], clean["y_L"])
    assert np.std(noisy["Gamma_d"] - clean["Gamma_d"]) == pytest.approx(0.1, rel=0.05)
    assert np.std(noisy["delta_sw"] - clean["delta_sw"]) == pytest.approx(0.01, rel=0.05)


def test_the_driver_keeps_its_lane():
    stronger = Driver({"K_p": Ramp(3.4, 4.42, 40.0, 70.0), "K_c": Ramp(15.0, 19.5, 110.0, 140.0)})
    recording = simulate_driving(stronger)
    assert not recording.metadata["lane_departure"]
    assert recording.metadata["max_lateral_offset"] < 0.6
    for seed in range(3):
        drive = simulate_driving(Driver(), Road.random(seed, 2000.0), measurement_time=100.0)
        assert drive.metadata["max_lateral_offset"] < 0.5


@pytest.mark.parametrize(
    ("make", "error", "message"),
    [
        (
            lambda: Driver({"K_x": 1.0}),
            ValueError,
            "the cybernetic driver has no parameter(s) 'K_x'",
        ),
        (
            lambda: Driver({"T_N": 0.0}),
            ValueError,
            "driver parameter T_N must lie in (0, inf] s, got 0.0",
        ),
        (
            lambda: Driver({"tau_p": 0.0}, delay_order=1),
            ValueError,
            "driver parameter tau_p must lie in (0, inf] s",
        ),
        (
            lambda: Driver(delay_order=3),
            ValueError,
            "delay_order must be None (exact delay) or 1 (Zhao eq. 1), got 3",
        ),
        (
            lambda: Driver(remnant=LevisonRemnant(injection="feedback")),
            ValueError,
            "driver remnant injection must be one of 'output', 'input', got 'feedback'",
        ),
        (
            lambda: simulate_driving(Driver(), "random"),
            ValueError,
            "simulate_driving needs a fixed road",
        ),
        (
            lambda: simulate_driving(Driver(), output_noise={"y_L": 1.0}),
            ValueError,
            "output_noise keys must be",
        ),
        (lambda: simulate_driving(Driver(), reward="bounded"), TypeError, "does not use: 'reward'"),
    ],
)
def test_bad_input_is_named(make, error, message):
    with pytest.raises(error, match=re.escape(message)):
        make()


def test_implausible_values_warn():
    with pytest.warns(HumanLimitWarning, match="K_c = 80"):
        Driver({"K_c": 80.0})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Driver()


def test_driver_round_trips_as_a_dict():
    driver = Driver(
        {"K_p": Ramp(3.4, 4.0, 1.0, 2.0)}, LevisonRemnant(injection="input", P_r=0.1), None
    )
    assert Driver.from_dict(driver.to_dict()) == driver
