"""PilotController, the pilot acting through observations, against scipy.signal.

The controller is driven here with observation sequences chosen by the test (not by
the environment's dynamics), and its stick compared with independent discretisations
of the same transfer functions (numpy polynomials, ``scipy.signal.cont2discrete`` and
``dlsim``). Tolerances, and why:
- Padé delay, constant parameters: both are exact zero-order-hold discretisations of
  the same LTI pilot; 1e-10 of the signal's largest value (rounding and the
  conditioning of scipy's tf2ss of the Padé polynomials).
- Exact delay of a whole number of samples: the delayed perception is a held
  staircase shifted exactly, so the same 1e-10.
- Preview read at a fractional sample: bicubic interpolation of a 0.5 Hz sine at
  100 Hz, about 1e-9 of the amplitude; tolerance 1e-7.
"""

import re
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import scipy.signal

import manualcontrol.envs  # noqa: F401
from manualcontrol.envs.schedules import Step
from manualcontrol.pilots import LevisonRemnant, Pilot
from manualcontrol.pilots.controller import PilotController

sys.path.insert(0, str(Path(__file__).parent))
from closed_loop_reference import far_view_polynomials, pilot_polynomials

DT = 0.01
COMPENSATORY = dict(K_p=0.24, K_v=0.36, omega_nms=8.0, zeta_nms=0.45, tau_v=0.3)
PREVIEW = dict(K_f=0.9, omega_f=1.0, tau_f=0.5, **COMPENSATORY)


def _env(task, **kwargs):
    env = gym.make(
        f"ManualControl/{task}Tracking-v0",
        controlled_element="DI",
        run_in=1.0,
        measurement_time=4.0,
        **kwargs,
    )
    env.reset(seed=0)
    return env


def _zoh_response(num, den, inputs):
    system = scipy.signal.cont2discrete(scipy.signal.tf2ss(num, den), DT, method="zoh")
    return scipy.signal.dlsim((*system[:4], DT), inputs)[1][:, 0]


def _error_sequence(n):
    t = np.arange(n) * DT
    return 0.7 * np.sin(1.3 * t) + 0.4 * np.cos(4.1 * t + 0.3) + 0.2 * np.sin(9.0 * t)


def _act_all(controller, observations):
    return np.array([controller.act(observation)[0] for observation in observations])


def _close(ours, reference, tolerance):
    assert np.max(np.abs(ours - reference)) <= tolerance * np.max(np.abs(reference))


def test_pade_pilot_equals_the_zoh_transfer_function():
    env = _env("Compensatory")
    controller = PilotController(Pilot("precision", COMPENSATORY, delay_order=3), env)
    e = _error_sequence(controller.setup.n_samples)
    u = _act_all(controller, e[:, None])
    _close(u, _zoh_response(*pilot_polynomials(COMPENSATORY, 3), e), 1e-10)


def test_exact_delay_of_whole_samples_shifts_the_held_error():
    env = _env("Compensatory")
    controller = PilotController(Pilot("precision", COMPENSATORY), env)
    n = controller.setup.n_samples
    e = _error_sequence(n)
    u = _act_all(controller, e[:, None])
    shift = round(COMPENSATORY["tau_v"] / DT)
    delayed = np.concatenate([np.zeros(shift), e[:-shift]])
    without_delay = {**COMPENSATORY, "tau_v": 0.0}
    _close(u, _zoh_response(*pilot_polynomials(without_delay, 0), delayed), 1e-10)


def test_parameters_switch_at_their_sample():
    # K_p only scales C of the neuromuscular canonical form (K_v = 0): u[k] = K_p(t_k) z[k]
    gains = Step(0.5, 1.1, 2.0)
    parameters = {**COMPENSATORY, "K_v": 0.0, "K_p": gains}
    env = _env("Compensatory")
    controller = PilotController(Pilot("precision", parameters, delay_order=3), env)
    n = controller.setup.n_samples
    e = _error_sequence(n)
    u = _act_all(controller, e[:, None])
    unit = {**COMPENSATORY, "K_v": 0.0, "K_p": 1.0}
    z = _zoh_response(*pilot_polynomials(unit, 3), e)
    _close(u, gains(controller.setup.time) * z, 1e-10)


def test_remnant_adds_the_filtered_seeded_noise():
    remnant = LevisonRemnant(K_r=0.3, omega_r=10.0, injection="output")
    env = _env("Compensatory")
    quiet = PilotController(Pilot("precision", COMPENSATORY, delay_order=3), env)
    noisy = PilotController(
        Pilot("precision", COMPENSATORY, remnant=remnant, delay_order=3), env, seed=11
    )
    n = quiet.setup.n_samples
    e = _error_sequence(n)[:, None]
    difference = []
    remnants = []
    for observation in e:
        difference.append(noisy.act(observation)[0] - quiet.act(observation)[0])
        remnants.append(noisy.last_remnant)
    noise = 0.3 * np.random.default_rng(11).standard_normal(n)
    expected = _zoh_response([1.0], [1.0, 10.0], noise)
    _close(np.array(difference), expected, 1e-10)
    _close(np.array(remnants), expected, 1e-12)
    again = PilotController(
        Pilot("precision", COMPENSATORY, remnant=remnant, delay_order=3), env, seed=11
    )
    first = PilotController(
        Pilot("precision", COMPENSATORY, remnant=remnant, delay_order=3), env, seed=11
    )
    np.testing.assert_array_equal(_act_all(again, e), _act_all(first, e))


@pytest.mark.parametrize("tau_f", [0.5, 0.505])
def test_preview_pilot_reads_its_point_in_the_window(tau_f):
    values = {**PREVIEW, "tau_f": tau_f}
    env = _env("Preview")
    controller = PilotController(Pilot("preview", values, delay_order=3), env)
    window = controller.setup.preview_window
    t = controller.setup.time
    target = lambda time: np.sin(np.pi * time) + 0.3 * np.cos(0.4 * np.pi * time)  # noqa: E731
    y = 0.5 * np.sin(2.0 * t)
    observations = np.column_stack([target(t[:, None] + np.arange(window) * DT), y])
    u = _act_all(controller, observations)
    pilot_num, pilot_den = pilot_polynomials(values, 3)
    far_num, far_den = far_view_polynomials(values)
    expected = _zoh_response(
        np.polymul(pilot_num, far_num), np.polymul(pilot_den, far_den), target(t + tau_f)
    ) - _zoh_response(pilot_num, pilot_den, y)
    _close(u, expected, 1e-10 if tau_f == 0.5 else 1e-7)


def test_the_episode_end_and_a_foreign_env_raise():
    env = _env("Compensatory")
    controller = PilotController(Pilot("precision", COMPENSATORY), env)
    _act_all(controller, np.zeros((controller.setup.n_samples, 1)))
    with pytest.raises(RuntimeError, match="the pilot's episode is over"):
        controller.act(np.zeros(1))
    with pytest.raises(TypeError, match=re.escape("it has no 'task'")):
        PilotController(Pilot("precision"), gym.make("CartPole-v1"))


def test_any_layout_of_observation_gives_the_same_stick():
    # after its first step the controller calls the compiled step directly, which reads
    # a contiguous float array; views with strides, lists and ints must be read alike
    values = {**PREVIEW, "tau_f": 0.505}
    env = _env("Preview")
    window = PilotController(Pilot("preview", values), env).setup.preview_window
    t = np.arange(500) * DT
    observations = np.column_stack(
        [np.sin(np.pi * (t[:, None] + np.arange(window) * DT)), 0.5 * np.sin(2.0 * t)]
    )
    plain = _act_all(PilotController(Pilot("preview", values), env), observations)
    strided = np.repeat(observations, 2, axis=1)[:, ::2]  # the same numbers, stride 2
    assert not strided[0].flags.c_contiguous
    # the first is contiguous, so the overload called directly afterwards is the C one
    mixed = [
        observations[k] if k % 3 == 0 else strided[k] if k % 3 == 1 else observations[k].tolist()
        for k in range(len(t))
    ]
    np.testing.assert_array_equal(
        _act_all(PilotController(Pilot("preview", values), env), mixed), plain
    )
    compensatory = PilotController(Pilot("precision", COMPENSATORY), _env("Compensatory"))
    e = np.round(10 * _error_sequence(300)).astype(np.int64)  # whole numbers, as ints
    again = PilotController(Pilot("precision", COMPENSATORY), _env("Compensatory"))
    np.testing.assert_array_equal(
        _act_all(compensatory, e[:, None]), _act_all(again, e[:, None].astype(float))
    )
