"""The Gymnasium tracking environments: contracts, determinism, pilots acting, rendering."""

import doctest
import pickle
import re
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import manualcontrol.envs  # noqa: F401  (registers the ids)
from manualcontrol.envs import tracking
from manualcontrol.envs.schedules import Sigmoid
from manualcontrol.envs.tracking import CompensatoryTracking, PreviewTracking, PursuitTracking
from manualcontrol.pilots import Pilot, simulate

TASKS = ("Compensatory", "Pursuit", "Preview")
ELEMENTS = ("SI", "DI", "popovici2017-tv")
SHORT = dict(run_in=1.0, measurement_time=5.0)
# Known and intended: the stick range is physical (default +-10), not normalised to
# [-1, 1]; the displayed signals are unbounded (an unstable element diverges).
KNOWN_WARNINGS = (
    r".*we recommend using a symmetric and normalized space.*",
    r".*Box observation space (minimum|maximum) value is (-)?infinity.*",
)


def _warnings_as_errors():
    warnings.simplefilter("error")
    for message in KNOWN_WARNINGS:
        warnings.filterwarnings("ignore", message=message)


def make(task, **kwargs):
    return gym.make(f"ManualControl/{task}Tracking-v0", **{**SHORT, **kwargs})


@pytest.mark.parametrize("task", TASKS)
@pytest.mark.parametrize("element", ELEMENTS)
def test_check_env_passes(task, element):
    env = make(task, controlled_element=element).unwrapped
    with warnings.catch_warnings():
        _warnings_as_errors()
        check_env(env, skip_render_check=True)


@pytest.mark.parametrize("task", TASKS)
def test_check_env_with_rendering_and_extras(task):
    env = make(task, include_rates=True, include_previous_action=True, render_mode="rgb_array")
    with warnings.catch_warnings():
        _warnings_as_errors()
        check_env(env.unwrapped)


@pytest.mark.parametrize("task", TASKS)
def test_same_seed_same_rollout(task):
    def rollout(seed):
        env = make(task, realisation=None)
        observations = [env.reset(seed=seed)[0]]
        actions = np.random.default_rng(0).uniform(-2, 2, (200, 1))
        for action in actions:
            observations.append(env.step(action)[0])
        return np.array(observations), env.unwrapped.forcing.realisation

    first, _ = rollout(3)
    again, _ = rollout(3)
    np.testing.assert_array_equal(first, again)
    realisations = {rollout(seed)[1] for seed in range(8)}
    assert len(realisations) > 1  # realisation=None draws per episode


@pytest.mark.parametrize(
    ("task", "kwargs", "size"),
    [
        ("Compensatory", {}, 1),
        ("Compensatory", {"include_rates": True, "include_previous_action": True}, 3),
        ("Pursuit", {}, 2),
        ("Pursuit", {"include_rates": True}, 4),
        ("Preview", {"available_preview": 0.5}, 52),
        (
            "Preview",
            {"available_preview": 0.5, "include_rates": True, "include_previous_action": True},
            55,
        ),
    ],
)
def test_observation_contract(task, kwargs, size):
    env = make(task, **kwargs)
    observation, info = env.reset(seed=0)
    assert env.observation_space.shape == (size,)
    assert observation.dtype == np.float64 and observation.shape == (size,)
    assert env.action_space.shape == (1,) and env.action_space.dtype == np.float64
    base = env.unwrapped
    if task == "Compensatory":
        assert observation[0] == info["e"] == info["ft"] - info["y"]
    elif task == "Pursuit":
        np.testing.assert_array_equal(observation[:2], [info["ft"], info["y"]])
    else:
        window = base.preview_window
        target = base.forcing.target
        times = info["t"] + np.arange(window) * base.dt
        np.testing.assert_allclose(observation[:window], target(times), atol=1e-12)
        assert observation[window] == info["y"]


def test_rates_and_previous_action_are_what_they_say():
    env = make("Pursuit", include_rates=True, include_previous_action=True)
    observation, _ = env.reset(seed=0)
    np.testing.assert_array_equal(observation[2:], [0.0, 0.0, 0.0])
    previous = observation
    observation, *_ = env.step(np.array([0.7]))
    np.testing.assert_allclose(observation[2:4], (observation[:2] - previous[:2]) / 0.01)
    assert observation[4] == 0.7


def test_actions_are_clipped_and_counted_and_non_finite_raise():
    env = make("Compensatory", action_bound=2.0)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([5.0]))
    assert info["u"] == 2.0 and info["clipped_actions"] == 1
    _, _, _, _, info = env.step(np.array([-1.0]))
    assert info["u"] == -1.0 and info["clipped_actions"] == 1
    with pytest.raises(ValueError, match=re.escape("action must be finite, got array([nan])")):
        env.unwrapped.step(np.array([np.nan]))


def test_reward_choices():
    for kind in tracking.REWARDS:
        env = make("Compensatory", reward=kind, effort_weight=0.5)
        env.reset(seed=0)
        _, reward, _, _, info = env.step(np.array([1.0]))
        variance = env.unwrapped.forcing.target.variance
        expected = {
            "squared_error": -(info["e"] ** 2) / variance,
            "absolute_error": -abs(info["e"]) / np.sqrt(variance),
            "squared_error_and_effort": -(info["e"] ** 2 + 0.5) / variance,
            "bounded": variance / (variance + info["e"] ** 2),
        }[kind]
        assert reward == pytest.approx(expected, rel=1e-12)


def test_loss_of_control_terminates_the_critical_task():
    env = make("Compensatory", controlled_element="critical-task", measurement_time=60.0)
    env.reset(seed=0)
    limit = env.unwrapped.loss_of_control
    steps = 0
    terminated = truncated = False
    while not (terminated or truncated):  # a small constant stick: the element runs away
        _, _, terminated, truncated, info = env.step(np.array([0.1]))
        steps += 1
    assert terminated and not truncated and abs(info["e"]) > limit
    assert steps < 6100


def test_truncation_at_the_end_of_the_run():
    env = make("Compensatory", run_in=0.0, measurement_time=0.5)
    env.reset(seed=0)
    flags = [env.step(np.array([0.0]))[3] for _ in range(50)]
    assert flags[-1] and not any(flags[:-1])
    with pytest.raises(RuntimeError, match="the episode is over"):
        env.unwrapped.step(np.array([0.0]))


@pytest.mark.parametrize(
    ("task", "model", "element", "parameters", "remnant"),
    [
        (
            "compensatory",
            "precision",
            "DI",
            {"K_p": 0.24, "K_v": 0.36, "tau_v": 0.3},
            "popovici2017",
        ),
        (
            "compensatory",
            "precision",
            "popovici2017-tv",
            {"K_p": Sigmoid(1.5, 1.0, 30.0, 5.0)},
            None,
        ),
        ("pursuit", "preview", "SI", {"tau_f": 0.0}, None),
        ("preview", "preview", "SI", {"tau_f": Sigmoid(0.6, 0.3, 30.0, 10.0)}, "vertregt2020-SI"),
        ("preview", "preview", "DI", {"K_p": 0.24, "K_v": 0.36, "omega_f": 1.0}, None),
    ],
)
def test_pilot_in_env_equals_simulate(task, model, element, parameters, remnant):
    kwargs = dict(run_in=10.0, measurement_time=40.0)
    pilot = Pilot(model, parameters, remnant=remnant)
    env = gym.make(
        f"ManualControl/{task.capitalize()}Tracking-v0", controlled_element=element, **kwargs
    )
    observation, _ = env.reset(seed=0)
    pilot.reset(seed=7, env=env)
    done = False
    while not done:
        observation, _, terminated, truncated, _ = env.step(pilot.act(observation))
        done = terminated or truncated
    from_env = env.unwrapped.recording()
    simulated = simulate(
        pilot, element, "vanderel-bw4", task=task, seed=7, loop="sampled", **kwargs
    )
    for name in ("t", "ft", "fd", "y", "e", "u"):
        np.testing.assert_allclose(from_env[name], simulated[name], rtol=0, atol=1e-9, err_msg=name)
    assert np.std(from_env.u) > 0.1  # the pilot really acted


def test_pilot_must_be_reset_with_an_env():
    with pytest.raises(RuntimeError, match=re.escape("call pilot.reset(seed, env=env)")):
        Pilot("precision").act(np.zeros(1))


def test_recording_of_an_episode():
    env = make("Preview", run_in=1.0, measurement_time=2.0)
    env.reset(seed=0)
    for _ in range(300):
        env.step(np.array([0.3]))
    recording = env.unwrapped.recording()
    assert len(recording) == 200 and recording.t[0] == 0.0
    np.testing.assert_array_equal(recording.u, 0.3)
    np.testing.assert_allclose(recording.e, recording.ft - recording.y)
    assert len(env.unwrapped.recording(include_run_in=True)) == 300


@pytest.mark.parametrize("task", TASKS)
def test_pickle_round_trip_continues_identically(task):
    env = make(task).unwrapped
    env.reset(seed=1)
    env.step(np.array([0.5]))
    clone = pickle.loads(pickle.dumps(env))
    a = env.step(np.array([0.2]))
    b = clone.step(np.array([0.2]))
    np.testing.assert_array_equal(a[0], b[0])
    assert a[1] == b[1]


@pytest.mark.parametrize("task", TASKS)
def test_rendering_in_both_modes(task, tmp_path):
    env = make(task, render_mode="rgb_array")
    env.reset(seed=0)
    for _ in range(30):
        env.step(np.array([0.5]))
    frame = env.render()
    assert frame.shape == (400, 600, 3) and frame.dtype == np.uint8
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 2  # something is drawn
    human = make(task, render_mode="human")
    human.reset(seed=0)
    assert human.render() is None
    human.step(np.array([0.1]))
    human.close()


@pytest.mark.parametrize(
    ("kwargs", "error", "message"),
    [
        ({"controlled_element": "TI"}, ValueError, "controlled element must be one of"),
        ({"forcing": "white"}, ValueError, "forcing preset must be one of"),
        ({"reward": "hinge"}, ValueError, "reward must be one of 'squared_error'"),
        ({"dt": -0.01}, ValueError, "dt must be > 0, got -0.01"),
        (
            {"realisation": 99},
            ValueError,
            "realisation must lie in [0, 9] for this forcing, got 99",
        ),
        ({"action_bound": 0.0}, ValueError, "action_bound must be > 0, got 0.0"),
        (
            {"available_preview": 1.0},
            ValueError,
            "available_preview must be 0 (or omitted) in a compensatory task",
        ),
        (
            {"render_mode": "ansi"},
            ValueError,
            "render_mode must be one of 'human', 'rgb_array', got 'ansi'",
        ),
        ({"gain": 2.0}, TypeError, "unexpected keyword argument 'gain'"),
    ],
)
def test_bad_arguments_raise(kwargs, error, message):
    with pytest.raises(error, match=re.escape(message)):
        CompensatoryTracking(**kwargs)


def test_bad_reset_options_raise():
    env = PursuitTracking()
    with pytest.raises(TypeError, match=re.escape("reset options got unknown key(s) 'level'")):
        env.reset(options={"level": 3})
    with pytest.raises(ValueError, match=re.escape("realisation must lie in [0, 9]")):
        env.reset(options={"realisation": 10})
    env.reset(options={"realisation": 4})
    assert env.forcing.realisation == 4


def test_pilot_preview_beyond_the_display_raises():
    env = PreviewTracking(available_preview=0.5, **SHORT)
    env.reset(seed=0)
    with pytest.raises(
        ValueError, match=re.escape("tau_f must not exceed the available preview of 0.5 s")
    ):
        Pilot("preview").reset(seed=0, env=env)


def test_docstring_example_runs():
    results = doctest.testmod(tracking, optionflags=doctest.ELLIPSIS)
    assert results.attempted > 0 and results.failed == 0


# ------------------------------------------------------------------- vector


@pytest.mark.parametrize("task", TASKS)
@pytest.mark.parametrize("element", ["SI", "popovici2017-tv"])
def test_native_vector_env_equals_sync_vector_of_single_envs(task, element):
    kwargs = dict(controlled_element=element, realisation=None, run_in=0.0, measurement_time=0.3)
    env_id = f"ManualControl/{task}Tracking-v0"
    native = gym.make_vec(env_id, num_envs=4, **kwargs)
    assert type(native).__name__ == f"{task}TrackingVector"
    sync = gym.make_vec(env_id, num_envs=4, vectorization_mode="sync", **kwargs)
    assert native.observation_space == sync.observation_space
    assert native.action_space == sync.action_space
    a, _ = native.reset(seed=42)
    b, _ = sync.reset(seed=42)
    np.testing.assert_array_equal(a, b)
    actions = np.random.default_rng(1).uniform(-3, 3, (75, 4, 1))  # two episodes and a bit
    for action in actions:
        step_a = native.step(action)
        step_b = sync.step(action)
        for got, want in zip(step_a[:4], step_b[:4], strict=True):
            if element == "SI":  # a constant element: the same sums in the same order
                np.testing.assert_array_equal(got, want)
            else:  # a matrix product per copy, summed in another order
                np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def test_async_vector_env_runs():
    envs = gym.make_vec(
        "ManualControl/PreviewTracking-v0", num_envs=2, vectorization_mode="async", **SHORT
    )
    observations, _ = envs.reset(seed=0)
    observations, rewards, *_ = envs.step(np.zeros((2, 1)))
    assert observations.shape == (2, 102) and rewards.shape == (2,)
    envs.close()


def test_vector_env_rejects_non_finite_actions():
    envs = gym.make_vec("ManualControl/CompensatoryTracking-v0", num_envs=3, **SHORT)
    envs.reset(seed=0)
    with pytest.raises(
        ValueError, match=re.escape("actions must be finite, got non-finite values for copies [1]")
    ):
        envs.step(np.array([[0.0], [np.inf], [0.0]]))


def test_times_are_the_observation_times_and_read_only():
    env = make("Preview", run_in=1.0, measurement_time=2.0)
    _, info = env.reset(seed=0)
    times = env.unwrapped.times
    assert times[0] == info["t"] == -1.0
    for k in range(1, 50):
        _, _, _, _, info = env.step(np.array([0.1]))
        assert info["t"] == times[k]
    with pytest.raises(ValueError, match="read-only"):
        times[0] = 0.0


def test_loop_state_and_forcing_samples_are_the_episode_as_flown():
    # 1/s (A = 0, B = C = 1): the exact step integrates the held stick, so the element's
    # state is dt times the sum of the sticks so far, independent of the env's algebra
    env = CompensatoryTracking(
        controlled_element="1/s", forcing="popovici2017", measurement_time=2.0
    )
    with pytest.raises(RuntimeError, match="reset"):
        env.loop_state()
    with pytest.raises(RuntimeError, match="reset"):
        env.forcing_samples()
    assert env.sample_index == -1
    assert env.element_order == 1
    _, info = env.reset(seed=0)
    target, disturbance = env.forcing_samples()
    sticks = np.random.default_rng(1).uniform(-1.0, 1.0, 150)
    for k, stick in enumerate(sticks, start=1):
        _, _, _, _, info = env.step(np.array([stick]))
        loop = env.loop_state()
        assert env.sample_index == k
        assert loop.output == info["y"]
        assert loop.error == info["e"]
        assert target[k] == info["ft"]
        assert loop.element_state[0] == pytest.approx(0.01 * sticks[:k].sum(), abs=1e-12)
    np.testing.assert_array_equal(disturbance, 0.0)  # a target-only forcing
    with pytest.raises(ValueError, match="read-only"):
        target[0] = 1.0
