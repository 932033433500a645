"""Tracking episodes end for good: a step after termination or truncation raises.

The lane-keeping environment is the model (``tests/envs/test_driving_inputs.py``): the
error says why and when the episode ended and tells the caller to reset, the recording
ends with the episode's last step, and reset starts a new episode. Also: the shared
argument checks show the value of a wrongly shaped action and an env's own example of
its reset options.
"""

import re

import gymnasium as gym
import numpy as np
import pytest

import manualcontrol.envs  # noqa: F401  (registers the ids)
from manualcontrol.envs._validation import check_action, check_options
from manualcontrol.envs.postview import PostviewTracking
from manualcontrol.envs.tracking import CompensatoryTracking, PursuitTracking
from manualcontrol.envs.tracking_vector import CompensatoryTrackingVector


def _run_to_the_end(env, stick=0.1):
    steps = 0
    while True:
        _, _, terminated, truncated, info = env.step(np.array([stick]))
        steps += 1
        if terminated or truncated:
            return steps, terminated, truncated, info


def _terminated_message(info, limit):
    return (
        f"the episode is over (terminated at t = {info['t']:g} s: |e| = {abs(info['e']):g} "
        f"> loss_of_control = {limit:g}); call reset()"
    )


@pytest.mark.parametrize("run_in", [0.0, 0.5])
def test_step_after_loss_of_control_raises_and_the_recording_stops(run_in):
    env = CompensatoryTracking("SI", measurement_time=20.0, run_in=run_in, loss_of_control=4.0)
    env.reset(seed=0)
    steps, terminated, truncated, info = _run_to_the_end(env, stick=2.0)
    assert terminated and not truncated and abs(info["e"]) > 4.0
    assert env.n_run_in < steps < env.episode_steps
    before = env.recording(include_run_in=True)
    message = _terminated_message(info, 4.0)
    # the end is reported before the action is looked at, whatever it is
    for action in (np.array([0.0]), [0.0], "bad", np.zeros(3)):
        with pytest.raises(RuntimeError, match=re.escape(message)):
            env.step(action)
    after = env.recording(include_run_in=True)
    assert len(after) == len(before) == steps  # one sample per action taken
    np.testing.assert_array_equal(after.u, before.u)
    assert after.t[-1] == pytest.approx(info["t"] - env.dt)
    assert len(env.recording()) == steps - env.n_run_in
    # the sample whose error exceeded the limit is the observation after the last step
    assert np.all(np.abs(after.e) <= 4.0)
    # reset starts a new episode that steps again
    env.reset(seed=0)
    _, _, terminated, truncated, _ = env.step(np.array([0.0]))
    assert not terminated and not truncated
    assert len(env.recording(include_run_in=True)) == 1


def test_step_after_loss_of_control_raises_through_gym_make():
    env = gym.make(
        "ManualControl/CompensatoryTracking-v0",
        controlled_element="critical-task",
        run_in=0.0,
        measurement_time=60.0,
    )
    env.reset(seed=0)
    limit = env.unwrapped.loss_of_control  # the critical task's default limit
    steps, terminated, _, info = _run_to_the_end(env)
    assert terminated
    with pytest.raises(RuntimeError, match=re.escape(_terminated_message(info, limit))):
        env.unwrapped.step(np.array([0.0]))
    assert len(env.unwrapped.recording()) == steps


@pytest.mark.parametrize("env_type", [CompensatoryTracking, PursuitTracking, PostviewTracking])
def test_step_after_truncation_raises_in_the_lane_keeping_form(env_type):
    env = env_type(run_in=0.0, measurement_time=0.5)
    env.reset(seed=0)
    flags = [env.step(np.array([0.0]))[3] for _ in range(50)]
    assert flags[-1] and not any(flags[:-1])
    message = "the episode is over (truncated after 50 steps, at t = 0.5 s); call reset()"
    with pytest.raises(RuntimeError, match=re.escape(message)):
        env.step(np.array([0.0]))
    assert len(env.recording()) == 50


def test_truncation_message_counts_the_run_in_steps_and_shows_measurement_time():
    env = CompensatoryTracking("SI", run_in=0.2, measurement_time=0.3)
    env.reset(seed=0)
    _run_to_the_end(env, stick=0.0)
    message = "the episode is over (truncated after 50 steps, at t = 0.3 s); call reset()"
    with pytest.raises(RuntimeError, match=re.escape(message)):
        env.step(np.array([0.0]))


def test_postview_with_loss_of_control_ends_there():
    env = PostviewTracking(
        controlled_element={"kind": "critical_task", "start": 0.0, "rate": 0.5},
        forcing="boer-kenyon1998-critical",
        dt=1 / 36,
        run_in=0.0,
        measurement_time=80.0,
        loss_of_control=0.2,
    )
    env.reset(seed=0)
    steps, terminated, truncated, info = _run_to_the_end(env, stick=0.1)
    assert terminated and not truncated and steps < env.episode_steps
    recorded = env.recording()
    with pytest.raises(RuntimeError, match=re.escape(_terminated_message(info, 0.2))):
        env.step(np.array([0.0]))
    after = env.recording()
    assert len(after) == len(recorded) == steps
    assert len(after.parameters["gap"]) == steps


def test_step_before_reset_still_asks_for_reset():
    env = CompensatoryTracking("SI", measurement_time=1.0)
    with pytest.raises(RuntimeError, match=re.escape("call reset() before step()")):
        env.step(np.array([0.0]))


def test_the_vector_env_still_autoresets_after_loss_of_control():
    vector = CompensatoryTrackingVector(
        num_envs=2, controlled_element="SI", measurement_time=20.0, loss_of_control=4.0
    )
    vector.reset(seed=0)
    for _ in range(vector.episode_steps):
        _, _, terminated, truncated, _ = vector.step(np.full((2, 1), 2.0))
        if terminated.any():
            break
    assert terminated.all() and not truncated.any()  # the same stick: both copies lost
    observation, reward, terminated, truncated, _ = vector.step(np.zeros((2, 1)))
    assert not terminated.any() and not truncated.any()
    np.testing.assert_array_equal(reward, 0.0)  # the reset step
    single = CompensatoryTracking("SI", measurement_time=20.0, loss_of_control=4.0)
    first, _ = single.reset(seed=0)
    np.testing.assert_allclose(observation[0], first)
    _, _, terminated, truncated, _ = vector.step(np.zeros((2, 1)))  # steps on as new
    assert not terminated.any() and not truncated.any()


# ------------------------------------------------------------------ shared checks


@pytest.mark.parametrize(
    ("action", "found"),
    [
        (0.1, "got shape () (0.1)"),
        (np.float64(0.1), "got shape () (0.1)"),
        (np.array(0.1), "got shape () (0.1)"),
        ([0.1, 0.2], "got shape (2,) ([0.1, 0.2])"),
        (np.array([5.0, -99.0]), "got shape (2,) ([5.0, -99.0])"),
        (np.array([[0.1]]), "got shape (1, 1) ([[0.1]])"),
        (np.zeros(0), "got shape (0,) ([])"),
        (np.arange(20.0), "got shape (20,) (20 values: 0.0, 1.0, 2.0, 3.0, ...)"),
    ],
)
def test_a_wrongly_shaped_action_shows_its_value(action, found):
    expected = "action must be a real array of shape (1,) (float64), " + found
    with pytest.raises(ValueError, match=re.escape(expected) + "$"):
        check_action("action", action, (1,))
    env = CompensatoryTracking("SI", measurement_time=1.0)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=re.escape(expected) + "$"):
        env.step(action)
    assert env._k == 0


def test_the_vector_env_shows_the_value_of_wrongly_shaped_actions():
    vector = CompensatoryTrackingVector(num_envs=2, controlled_element="SI", measurement_time=1.0)
    vector.reset(seed=0)
    expected = (
        "actions must be a real array of shape (2, 1) (float64), got shape (3,) ([0.1, 0.2, 0.3])"
    )
    with pytest.raises(ValueError, match=re.escape(expected)):
        vector.step(np.array([0.1, 0.2, 0.3]))


def test_check_options_gives_the_default_example_or_the_one_asked_for():
    with pytest.raises(
        TypeError,
        match=re.escape("options must be a dict such as {'realisation': 0} or None, got 3"),
    ):
        check_options(3, ("realisation",))
    with pytest.raises(
        TypeError,
        match=re.escape("options must be a dict such as {'road_seed': 0} or None, got [1]"),
    ):
        check_options([1], ("road_seed",), example={"road_seed": 0})
    assert check_options({"road_seed": 2}, ("road_seed",), example={"road_seed": 0}) == {
        "road_seed": 2
    }
    assert check_options(None, ("road_seed",), example={"road_seed": 0}) == {}
    with pytest.raises(TypeError, match="reset options got unknown key"):
        check_options({"realisation": 0}, ("road_seed",), example={"road_seed": 0})
