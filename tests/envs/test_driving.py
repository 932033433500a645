"""Lane keeping: the car against independent equations, roads, the Gymnasium contract."""

import doctest
import math
import pickle
import re
import warnings

import gymnasium as gym
import numpy as np
import pytest
import scipy.signal
from gymnasium.utils.env_checker import check_env

import manualcontrol.envs  # noqa: F401  (registers the ids)
from manualcontrol.envs import driving
from manualcontrol.envs.driving import LaneKeeping, Road, RoadSegment, VehicleParameters

ID = "ManualControl/LaneKeeping-v0"
KNOWN_WARNINGS = (
    r".*we recommend using a symmetric and normalized space.*",
    r".*Box observation space (minimum|maximum) value is (-)?infinity.*",
)
# published mid-size car (the list), typed here independently of the module
C_F, C_R, MASS, I_Z, L_F, L_R, R_S = 51_845.0, 54_610.0, 1_834.9, 2_800.0, 1.249, 1.56, 14.5405
ETA_T, K_M, J_S, B_S, K_S = 0.245, 0.031, 0.05, 0.8, 1.0
SPEED = 64 / 3.6


def _warnings_as_errors():
    warnings.simplefilter("error")
    for message in KNOWN_WARNINGS:
        warnings.filterwarnings("ignore", message=message)


def _textbook_car(speed):
    """The single-track model with a steering column, in the textbook's axle form."""
    cf, cr = 2 * C_F, 2 * C_R  # axle stiffness
    v = speed
    A = np.zeros((6, 6))
    B = np.zeros((6, 2))  # torque, curvature
    A[0] = [
        -(cf + cr) / (MASS * v),
        (cr * L_R - cf * L_F) / (MASS * v) - v,
        0,
        0,
        cf / (MASS * R_S),
        0,
    ]
    A[1] = [
        (cr * L_R - cf * L_F) / (I_Z * v),
        -(cf * L_F**2 + cr * L_R**2) / (I_Z * v),
        0,
        0,
        cf * L_F / (I_Z * R_S),
        0,
    ]
    A[2, 1] = 1.0
    B[2, 1] = -v
    A[3, 0] = 1.0
    A[3, 2] = v
    A[4, 5] = 1.0
    # J delta'' = Gamma_d + Gamma_s - B delta' - k v delta,
    # Gamma_s = -K_m eta_t cf (delta/R_s - (v_y + l_f r)/v) / R_s
    g = K_M * ETA_T * cf / R_S
    A[5] = [g / (v * J_S), g * L_F / (v * J_S), 0, 0, (-g / R_S - K_S * v) / J_S, -B_S / J_S]
    B[5, 0] = 1.0 / J_S
    return A, B


def test_car_equals_the_textbook_model_discretised_by_scipy():
    road = Road(
        (RoadSegment.straight(20.0), *Road.bend(1 / 150, 60.0, 30.0), RoadSegment.straight(200.0))
    )
    env = LaneKeeping(road, measurement_time=10.0, loss_of_control=False)
    env.reset(seed=0)
    torque = 0.5 * np.sin(np.arange(env.episode_steps) * 0.01 * 2.0)
    y_env = []
    for u in torque:
        _, _, _, _, info = env.step([u])
        y_env.append(info["y_L"])
    A, B = _textbook_car(SPEED)
    system = scipy.signal.cont2discrete((A, B, np.eye(6), np.zeros((6, 2))), 0.01, method="zoh")
    kappa = road.curvature(SPEED * 0.01 * np.arange(env.episode_steps))
    _, _, x = scipy.signal.dlsim(system, np.column_stack([torque, kappa]))
    # y_L after each step; dlsim's state row k is before input k is applied
    expected = np.append(x[1:, 3], np.nan)[:-1]
    np.testing.assert_allclose(np.array(y_env)[:-1], expected, rtol=1e-9, atol=1e-12)


def test_steady_cornering_matches_the_understeer_gradient():
    env = LaneKeeping("straight", steering="angle", measurement_time=20.0, loss_of_control=False)
    env.reset(seed=0)
    wheel = 0.2  # rad at the steering wheel
    for _ in range(1500):
        _, _, _, _, info = env.step([wheel])
    length = L_F + L_R
    understeer = MASS * (L_R / (2 * C_F) - L_F / (2 * C_R)) / length
    yaw_rate = SPEED * (wheel / R_S) / (length + understeer * SPEED**2)
    assert info["a_y"] == pytest.approx(SPEED * yaw_rate, rel=1e-6)


def test_perception_angles_and_self_aligning_torque():
    model = driving.lane_keeping_model(VehicleParameters(), SPEED, "torque", 0.01)
    state = np.array([0.1, 0.05, 0.02, -0.3, 0.2, 0.0, 0, 0, 0, 0, 0, 0])
    out = np.zeros((1, 7))
    driving.perceive(model.packed, model.far_gain, state, 1 / 200, 1 / 300, out, 0)
    theta_far, theta_near, delta, torque, a_y, y_L, psi_L = out[0]
    assert theta_far == pytest.approx(15.0 / 300)
    lateral_error = -0.3 + 5.0 * 0.02 - (1 / 200) * 25.0 / 2  # the point 5 m ahead
    assert theta_near == pytest.approx(-lateral_error / 5.0)
    front = 2 * C_F * (0.2 / R_S - (0.1 + L_F * 0.05) / SPEED)
    rear = 2 * C_R * (-(0.1 - L_R * 0.05) / SPEED)
    assert torque == pytest.approx(-K_M * ETA_T * front / R_S)
    assert a_y == pytest.approx((front + rear) / MASS)
    assert (delta, y_L, psi_L) == (0.2, -0.3, 0.02)


# ------------------------------------------------------------------------------ roads


def test_road_curvature_segments_and_geometry():
    road = Road(
        (
            RoadSegment.straight(10.0),
            RoadSegment.clothoid(20.0, 0.0, 0.01),
            RoadSegment.arc(30.0, 0.01),
        )
    )
    np.testing.assert_allclose(
        road.curvature([0.0, 9.99, 20.0, 30.0, 45.0, 60.0, 80.0]),
        [0, 0, 0.005, 0.01, 0.01, 0.0, 0.0],
    )
    assert road.length == 60.0
    arc = Road((RoadSegment.arc(100.0, 0.01),))
    _, x, y, heading = arc.geometry(0.01)
    assert heading[-1] == pytest.approx(1.0)
    assert x[-1] == pytest.approx(math.sin(1.0) / 0.01, rel=1e-6)
    assert y[-1] == pytest.approx((1 - math.cos(1.0)) / 0.01, rel=1e-6)
    assert Road.from_dict(road.to_dict()) == road


def test_random_roads_are_seeded():
    first, again, other = Road.random(3, 2000.0), Road.random(3, 2000.0), Road.random(4, 2000.0)
    assert first == again and first != other
    assert first.length >= 2000.0
    radii = [1 / abs(s.start) for s in first.segments if s.kind == "arc"]
    assert min(radii) >= 200.0 and max(radii) <= 800.0


def test_the_suite_road_has_its_straight_and_lasts_220_s():
    road = driving.road_preset("zhao2019")
    assert road.length / driving.DEFAULT_SPEED == pytest.approx(220.05)
    s = np.arange(74.0, 89.0, 0.1) * driving.DEFAULT_SPEED
    assert np.all(road.curvature(s) == 0.0)


# ------------------------------------------------------------------------- the contract


@pytest.mark.parametrize(
    "kwargs",
    [
        {},
        {"steering": "angle"},
        {"road": "random", "include_rates": True, "include_previous_action": True},
    ],
)
def test_check_env_passes(kwargs):
    env = gym.make(ID, measurement_time=5.0, **kwargs).unwrapped
    with warnings.catch_warnings():
        _warnings_as_errors()
        check_env(env, skip_render_check=True)


def test_check_env_with_rendering():
    env = gym.make(ID, measurement_time=5.0, render_mode="rgb_array")
    with warnings.catch_warnings():
        _warnings_as_errors()
        check_env(env.unwrapped)
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (400, 600, 3) and frame.dtype == np.uint8
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 4  # grass, road, lines, car


def test_same_seed_same_rollout_and_random_roads_per_episode():
    def rollout(seed):
        env = gym.make(ID, road="random", measurement_time=5.0)
        observations = [env.reset(seed=seed)[0]]
        for action in np.random.default_rng(0).uniform(-1, 1, (100, 1)):
            observations.append(env.step(action)[0])
        return np.array(observations), env.unwrapped.current_road

    first, road = rollout(3)
    again, road_again = rollout(3)
    np.testing.assert_array_equal(first, again)
    assert road == road_again
    assert len({rollout(seed)[1] for seed in range(4)}) == 4
    env = gym.make(ID, road="random", measurement_time=5.0)
    env.reset(options={"road_seed": 7})
    assert env.unwrapped.current_road == Road.random(7, env.unwrapped.current_road.length)


def test_lane_departure_terminates_and_time_truncates():
    env = gym.make(ID, road="straight", measurement_time=30.0)
    env.reset(seed=0)
    steps = 0
    while True:
        _, reward, terminated, truncated, info = env.step([3.0])
        steps += 1
        if terminated or truncated:
            break
    assert terminated and not truncated and abs(info["y_L"]) > 0.85
    assert 0.0 < reward < 1.0
    env = gym.make(ID, road="straight", measurement_time=0.5)
    env.reset(seed=0)
    results = [env.step([0.0]) for _ in range(50)]
    assert results[-1][3] and not any(r[3] for r in results[:-1])
    assert results[-1][1] == 1.0  # bounded reward at zero offset


def test_rewards_and_observation_extras():
    env = gym.make(
        ID,
        road="straight",
        measurement_time=2.0,
        reward="squared_offset_and_effort",
        effort_weight=0.5,
        include_rates=True,
        include_previous_action=True,
    )
    observation, _ = env.reset(seed=0)
    assert observation.shape == (9,) and np.all(observation[4:] == 0.0)
    previous = observation
    observation, reward, _, _, info = env.step([2.0])
    np.testing.assert_allclose(observation[4:8], (observation[:4] - previous[:4]) / 0.01)
    assert observation[8] == 2.0
    assert reward == pytest.approx(-((info["y_L"] / 0.25) ** 2) - 0.5 * (2.0 / 20.0) ** 2)


def test_actions_are_clipped_counted_and_checked():
    env = gym.make(ID, measurement_time=1.0)
    env.reset(seed=0)
    _, _, _, _, info = env.step([50.0])
    assert info["action"] == 20.0 and info["clipped_actions"] == 1
    with pytest.raises(ValueError, match=re.escape("action must be finite, got array([nan])")):
        env.step(np.array([np.nan]))


def test_recording_holds_the_episode():
    env = gym.make(ID, measurement_time=3.0, run_in=1.0)
    env.reset(seed=0)
    for _ in range(400):
        env.step([0.3])
    recording = env.unwrapped.recording()
    assert len(recording) == 300 and recording.t[0] == pytest.approx(0.0)
    assert set(driving.OBSERVATION_NAMES) <= set(recording.signal_names)
    np.testing.assert_array_equal(recording["Gamma_d"], 0.3)
    assert recording.metadata["road"]["name"] == "zhao2019"


def test_pickle_round_trip():
    env = LaneKeeping(measurement_time=2.0)
    env.reset(seed=0)
    env.step([0.1])
    copy = pickle.loads(pickle.dumps(env))
    np.testing.assert_array_equal(copy.step([0.2])[0], env.step([0.2])[0])


@pytest.mark.parametrize(
    ("kwargs", "error", "message"),
    [
        ({"road": "bumpy"}, ValueError, "road must be one of 'zhao2019', 'straight', got 'bumpy'"),
        (
            {"steering": "wheel"},
            ValueError,
            "steering must be one of 'torque', 'angle', got 'wheel'",
        ),
        ({"speed": -1.0}, ValueError, "speed must be > 0, got -1.0"),
        (
            {"lane_width": 1.5},
            ValueError,
            "lane_width must exceed the vehicle width 1.8 m, got 1.5",
        ),
        (
            {"road": "straight", "measurement_time": 400.0},
            ValueError,
            "measurement_time must fit the road: 5000.0 m at 17.7778 m/s last 281.25 s",
        ),
        ({"reward": "speed"}, ValueError, "reward must be one of"),
        ({"vehicle": {"mass": -3.0}}, ValueError, "mass must be > 0, got -3.0"),
        ({"vehicle": {"wheels": 4}}, TypeError, "vehicle got unknown key(s) 'wheels'"),
    ],
)
def test_bad_arguments_are_named(kwargs, error, message):
    with pytest.raises(error, match=re.escape(message)):
        LaneKeeping(**kwargs)


def test_bad_reset_options_are_named():
    env = LaneKeeping(measurement_time=1.0)
    with pytest.raises(ValueError, match="road_seed applies to road='random' only"):
        env.reset(options={"road_seed": 1})
    with pytest.raises(TypeError, match=re.escape("reset options got unknown key(s) 'seed'")):
        env.reset(options={"seed": 1})


@pytest.mark.parametrize(
    "kwargs",
    [{}, {"road": "random", "include_rates": True, "include_previous_action": True}],
)
def test_native_vector_env_equals_sync_copies(kwargs):
    kwargs = {"measurement_time": 0.6, **kwargs}
    native = gym.make_vec(ID, num_envs=3, **kwargs)
    sync = gym.make_vec(ID, num_envs=3, vectorization_mode="sync", **kwargs)
    a, _ = native.reset(seed=5)
    b, _ = sync.reset(seed=5)
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)
    rng = np.random.default_rng(1)
    for _ in range(150):  # through two next-step autoresets
        actions = rng.uniform(-5, 5, (3, 1))
        first = native.step(actions)
        second = sync.step(actions)
        for x, y in zip(first[:4], second[:4], strict=True):
            np.testing.assert_allclose(x, y, rtol=1e-10, atol=1e-13)
        np.testing.assert_allclose(first[4]["y_L"], second[4]["y_L"], rtol=1e-10, atol=1e-13)


def test_module_doctest():
    results = doctest.testmod(driving, optionflags=doctest.ELLIPSIS)
    assert results.attempted >= 1 and results.failed == 0
