"""Lane keeping refuses bad input as the tracking envs do, and stops where the episode ends."""

import re
import types

import gymnasium as gym
import numpy as np
import pytest

import manualcontrol.envs  # noqa: F401  (registers the ids)
from manualcontrol.envs.driving import LaneKeeping

ID = "ManualControl/LaneKeeping-v0"
EXPECTED_ACTION = "action must be a real array of shape (1,) (float64)"


@pytest.fixture
def env():
    environment = gym.make(ID, measurement_time=1.0)
    environment.reset(seed=0)
    return environment


def _steps_taken(environment):
    return environment.unwrapped._k


# --------------------------------------------------------------------------- actions


@pytest.mark.parametrize(
    ("action", "error", "found"),
    [
        ("12.5", TypeError, "got '12.5'"),
        ("0.1", TypeError, "got '0.1'"),
        (b"0.1", TypeError, "got b'0.1'"),
        (np.array([5.0, -99.0]), ValueError, "got shape (2,)"),
        ([0.1, 0.2], ValueError, "got shape (2,)"),
        (np.array([[0.1]]), ValueError, "got shape (1, 1)"),
        (np.zeros(0), ValueError, "got shape (0,)"),
        # a bare number is refused as the tracking envs refuse it: the space is (1,)
        (0.1, ValueError, "got shape ()"),
        (np.float64(0.1), ValueError, "got shape ()"),
        (np.array(0.1), ValueError, "got shape ()"),
        (1 + 2j, TypeError, "got dtype complex128 ((1+2j))"),
        (np.array([1 + 2j]), TypeError, "got dtype complex128"),
        (True, TypeError, "got True"),
        (np.bool_(False), TypeError, "got np.False_"),
        (np.array([True]), TypeError, "got dtype bool"),
        (None, TypeError, "got None"),
        ({"torque": 1.0}, TypeError, "got dtype object"),
        (["0.1"], TypeError, "got dtype <U3"),
    ],
)
def test_wrong_actions_name_action_the_value_and_what_is_allowed(env, action, error, found):
    with pytest.raises(error, match=re.escape(EXPECTED_ACTION) + ".*" + re.escape(found)):
        env.step(action)
    assert _steps_taken(env) == 0  # refused before anything moved


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("container", [np.array, list])
def test_non_finite_actions_name_action_and_the_value(env, value, container):
    action = container([value])
    with pytest.raises(ValueError, match=re.escape(f"action must be finite, got {action!r}")):
        env.step(action)
    assert _steps_taken(env) == 0


@pytest.mark.parametrize(
    "action",
    [
        [0.5],
        (0.5,),
        np.array([0.5]),
        np.array([0.5], dtype=np.float32),
        np.array([1]),
        np.array([1], dtype=np.uint8),
    ],
)
def test_real_actions_of_shape_one_are_accepted(env, action):
    _, _, _, _, info = env.step(action)
    assert info["action"] == pytest.approx(float(np.asarray(action)[0]))
    recording = env.unwrapped.recording()
    assert recording["Gamma_d"][-1] == pytest.approx(float(np.asarray(action)[0]))


def test_out_of_bound_actions_are_still_clipped_not_refused(env):
    _, _, _, _, info = env.step(np.array([-1e6]))
    assert info["action"] == -20.0 and info["clipped_actions"] == 1


# --------------------------------------------------------------------- reset options


@pytest.mark.parametrize(
    ("options", "shown"),
    [([], "[]"), ("road_seed", "'road_seed'"), (3, "3"), (("road_seed", 1), "('road_seed', 1)")],
)
def test_reset_options_must_be_a_mapping_or_none(options, shown):
    environment = gym.make(ID, road="random", measurement_time=1.0)
    with pytest.raises(
        TypeError,
        match=re.escape("options must be a dict such as {'road_seed': 0}")
        + ".*"
        + re.escape(shown),
    ):
        environment.reset(options=options)


def test_unknown_reset_options_are_refused_by_name():
    environment = gym.make(ID, road="random", measurement_time=1.0)
    with pytest.raises(
        TypeError,
        match=re.escape("reset options got unknown key(s) 'realisation'; known: 'road_seed'"),
    ):
        environment.reset(options={"realisation": 0})


def test_reset_accepts_none_an_empty_dict_and_any_mapping():
    environment = gym.make(ID, road="random", measurement_time=1.0)
    environment.reset(seed=0, options=None)
    environment.reset(seed=0, options={})
    environment.reset(options=types.MappingProxyType({"road_seed": 4}))
    first = environment.unwrapped.current_road
    environment.reset(options={"road_seed": 4})
    assert environment.unwrapped.current_road == first


def test_road_seed_is_checked():
    environment = gym.make(ID, road="random", measurement_time=1.0)
    with pytest.raises(TypeError, match=re.escape("road_seed must be an integer, got '4'")):
        environment.reset(options={"road_seed": "4"})
    with pytest.raises(ValueError, match=re.escape("road_seed must be >= 0, got -1")):
        environment.reset(options={"road_seed": -1})


# ---------------------------------------------------------------- before the first reset


@pytest.mark.parametrize("road", ["zhao2019", "random"])
def test_describe_before_reset_says_to_call_reset(road):
    environment = LaneKeeping(road, measurement_time=1.0)
    with pytest.raises(RuntimeError, match=re.escape("call reset() before describe()")):
        environment.describe()
    environment.reset(seed=0)
    described = environment.describe()
    assert described["road"] == environment.current_road.to_dict()
    assert described["clipped_actions"] == 0


def test_step_and_recording_before_reset_say_to_call_reset():
    environment = LaneKeeping(measurement_time=1.0)
    with pytest.raises(RuntimeError, match=re.escape("call reset() before step()")):
        environment.step([0.0])
    with pytest.raises(RuntimeError, match=re.escape("reset() and step() first")):
        environment.recording()


@pytest.mark.parametrize("switch", ["include_rates", "include_previous_action", "loss_of_control"])
def test_switches_refuse_non_bools(switch):
    with pytest.raises(TypeError, match=re.escape(f"{switch} must be True or False, got 'False'")):
        LaneKeeping(measurement_time=1.0, **{switch: "False"})
    with pytest.raises(TypeError, match=re.escape(f"{switch} must be True or False, got 1")):
        LaneKeeping(measurement_time=1.0, **{switch: 1})


# -------------------------------------------------------------------- after the end


def _drive_off_the_road(environment, action=3.0):
    steps = 0
    while True:
        _, _, terminated, truncated, info = environment.step([action])
        steps += 1
        if terminated or truncated:
            return steps, terminated, truncated, info


def test_step_after_a_lane_departure_raises_and_the_recording_ends_there():
    environment = gym.make(ID, road="straight", measurement_time=30.0)
    environment.reset(seed=0)
    steps, terminated, truncated, info = _drive_off_the_road(environment)
    assert terminated and not truncated and abs(info["y_L"]) > 0.85
    assert steps < 3000
    message = (
        f"the episode is over (terminated at t = {info['t']:g} s: the car left its lane, "
        f"|y_L| = {abs(info['y_L']):.3g} m > 0.85 m); call reset()"
    )
    for action in ([0.0], np.array([0.0]), "bad"):  # the end is reported before the action
        with pytest.raises(RuntimeError, match=re.escape(message)):
            environment.step(action)
    recording = environment.unwrapped.recording()
    # one sample per action taken: the last is the sample of the terminating step
    assert len(recording) == steps
    assert recording.t[-1] == pytest.approx(info["t"] - 0.01)
    np.testing.assert_array_equal(recording["Gamma_d"], 3.0)
    assert np.all(np.abs(recording["y_L"]) <= 0.85)  # the departure is the next observation
    # reset starts a new episode that steps again
    environment.reset(seed=0)
    _, _, terminated, truncated, _ = environment.step([0.0])
    assert not terminated and not truncated
    assert len(environment.unwrapped.recording()) == 1


def test_recording_after_termination_with_run_in():
    environment = gym.make(ID, road="straight", measurement_time=30.0, run_in=1.0)
    environment.reset(seed=0)
    steps, terminated, _, info = _drive_off_the_road(environment, 2.0)
    assert terminated and steps > 100  # ends after the run-in
    with pytest.raises(RuntimeError, match="the episode is over"):
        environment.step([0.0])
    unwrapped = environment.unwrapped
    assert len(unwrapped.recording()) == steps - 100
    assert len(unwrapped.recording(include_run_in=True)) == steps
    assert unwrapped.recording().t[-1] == pytest.approx(info["t"] - 0.01)


def test_step_after_a_skid_raises_and_names_the_skid():
    # a lane wide enough that the friction limit goes first
    environment = gym.make(
        ID, road="straight", steering="angle", measurement_time=10.0, lane_width=200.0
    )
    environment.reset(seed=0)
    steps, terminated, _, info = _drive_off_the_road(environment, 2.0)
    assert terminated and abs(info["a_y"]) > 0.8 * 9.81
    with pytest.raises(
        RuntimeError,
        match=re.escape(
            f"the episode is over (terminated at t = {info['t']:g} s: the car lost grip"
        ),
    ):
        environment.step([0.0])
    assert len(environment.unwrapped.recording()) == steps


def test_step_after_truncation_raises():
    environment = gym.make(ID, road="straight", measurement_time=0.5)
    environment.reset(seed=0)
    results = [environment.step([0.0]) for _ in range(50)]
    assert results[-1][3] and not any(r[2] for r in results)
    with pytest.raises(
        RuntimeError,
        match=re.escape(
            "the episode is over (truncated after 50 steps, at t = 0.5 s); call reset()"
        ),
    ):
        environment.step([0.0])
    assert len(environment.unwrapped.recording()) == 50


def test_without_loss_of_control_the_car_may_leave_the_lane():
    environment = gym.make(ID, road="straight", measurement_time=5.0, loss_of_control=False)
    environment.reset(seed=0)
    results = [environment.step([3.0]) for _ in range(500)]
    assert not any(r[2] for r in results) and results[-1][3]
    assert abs(results[-1][4]["y_L"]) > 0.85
    with pytest.raises(RuntimeError, match=re.escape("(truncated after 500 steps")):
        environment.step([0.0])


# ------------------------------------------------------------------------ vector env


def test_vector_envs_autoreset_through_lane_departures():
    """The sync copies are reset, not stepped, after they end: both agree throughout."""
    kwargs = {"road": "straight", "measurement_time": 3.0}
    native = gym.make_vec(ID, num_envs=3, **kwargs)
    sync = gym.make_vec(ID, num_envs=3, vectorization_mode="sync", **kwargs)
    a, _ = native.reset(seed=5)
    b, _ = sync.reset(seed=5)
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)
    actions = np.array([[3.0], [-2.5], [0.1]])  # two copies leave the lane, one is truncated
    ends = np.zeros(3, dtype=int)
    for _ in range(700):
        first = native.step(actions)
        second = sync.step(actions)
        for x, y in zip(first[:4], second[:4], strict=True):
            np.testing.assert_allclose(x, y, rtol=1e-10, atol=1e-13)
        ends += first[2] | first[3]
    assert np.all(ends >= 2)


def test_vector_env_checks_actions_and_options():
    vector = gym.make_vec(ID, num_envs=2, measurement_time=1.0)
    with pytest.raises(TypeError, match=re.escape("options must be a dict such as")):
        vector.reset(options=[])
    with pytest.raises(
        TypeError, match=re.escape("reset options got unknown key(s) 'realisation'")
    ):
        vector.reset(options={"realisation": 1})
    vector.reset(seed=0)
    with pytest.raises(ValueError, match=re.escape("actions must be a real array of shape (2, 1)")):
        vector.step(np.zeros((3, 1)))
    with pytest.raises(TypeError, match=re.escape("got dtype complex128")):
        vector.step(np.zeros((2, 1), dtype=complex))
    with pytest.raises(TypeError, match=re.escape("got '12.5'")):
        vector.step("12.5")
    with pytest.raises(TypeError, match=re.escape("got dtype bool")):
        vector.step(np.array([[True], [False]]))
    with pytest.raises(ValueError, match=re.escape("non-finite values for copies [1]")):
        vector.step(np.array([[0.0], [np.nan]]))
    vector.step(np.zeros(2))  # one action per copy, flat, is fine
    vector.step([[0.1], [0.2]])
