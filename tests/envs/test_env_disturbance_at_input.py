"""Tracking envs with the disturbance at the controlled element's input.

``disturbance_at="input"``: the element is driven by ``u + fd`` and shows ``y = C x``.
Tolerances: the env and ``simulate(loop="sampled")`` step the same sampled loop
apart, so they agree to rounding (1e-9, as with the disturbance at the output); the
element stepped by scipy from the env's own ``u + fd`` (both held over each sample)
agrees to rounding as well (1e-12); the batched env and single envs, 1e-12 as for
the output.
"""

import re

import gymnasium as gym
import numpy as np
import pytest
import scipy.signal

import manualcontrol.envs  # noqa: F401  (registers the ids)
from manualcontrol.envs.postview import PostviewTracking
from manualcontrol.envs.tracking import CompensatoryTracking
from manualcontrol.pilots import LevisonRemnant, Pilot, simulate


@pytest.mark.parametrize(
    ("task", "element", "pilot"),
    [
        # a written transfer function as the env keyword
        (
            "compensatory",
            "1/(s(s+1))",
            Pilot("precision", dict(K_p=1.2, K_v=0.6, tau_v=0.28, omega_nms=10.0, zeta_nms=0.4)),
        ),
        # time-varying: omega_b falls from 3 to 1 rad/s around 45 s
        ("compensatory", "popovici2017-tv", Pilot.typical("precision", "popovici2017")),
        # direct feedthrough: the element's previous input reaches the display
        ("compensatory", "gain", Pilot.typical("precision", "gain")),
        ("preview", "DI", Pilot.typical("preview", "DI")),
    ],
)
def test_pilot_in_env_equals_simulate(task, element, pilot):
    kwargs = dict(run_in=10.0, measurement_time=50.0)
    env = gym.make(
        f"ManualControl/{task.capitalize()}Tracking-v0",
        controlled_element=element,
        disturbance_at="input",
        **kwargs,
    )
    observation, _ = env.reset(seed=0)
    pilot.reset(seed=7, env=env)
    simulated = simulate(
        pilot,
        element,
        "vanderel-bw4",
        task=task,
        seed=7,
        loop="sampled",
        disturbance_at="input",
        **kwargs,
    )
    done = False
    while not done:
        observation, _, terminated, truncated, _ = env.step(pilot.act(observation))
        done = terminated or truncated
    from_env = env.unwrapped.recording()
    for name in ("t", "ft", "fd", "y", "e", "u"):
        np.testing.assert_allclose(from_env[name], simulated[name], rtol=0, atol=1e-9, err_msg=name)
    assert np.std(from_env.u) > 0.1  # the pilot really acted
    assert from_env.metadata["disturbance_at"] == simulated.metadata["disturbance_at"] == "input"


@pytest.mark.parametrize(
    "remnant",
    [
        LevisonRemnant(K_r=0.5, injection="input"),
        # a power ratio: the pilot's controller calibrates the gain on the same loop
        LevisonRemnant(injection="input", P_r=0.3),
    ],
)
def test_pilot_with_a_remnant_in_env_equals_simulate(remnant):
    values = dict(K_p=1.2, K_v=0.6, tau_v=0.28, omega_nms=10.0, zeta_nms=0.4)
    pilot = Pilot("precision", values, remnant=remnant)
    kwargs = dict(run_in=10.0, measurement_time=30.0)
    env = CompensatoryTracking("1/(s(s+1))", disturbance_at="input", **kwargs)
    observation, _ = env.reset(seed=0)
    pilot.reset(seed=7, env=env)
    for _ in range(env.episode_steps):
        observation = env.step(pilot.act(observation))[0]
    simulated = simulate(
        pilot, "1/(s(s+1))", seed=7, loop="sampled", disturbance_at="input", **kwargs
    )
    for name in ("y", "e", "u"):
        np.testing.assert_allclose(env.recording()[name], simulated[name], rtol=0, atol=1e-9)


def test_fixed_actions_drive_the_element_with_u_plus_fd():
    env = gym.make(
        "ManualControl/CompensatoryTracking-v0",
        controlled_element="1/s",
        disturbance_at="input",
        run_in=0.0,
        measurement_time=20.0,
    )
    observation, info = env.reset(seed=0)
    assert info["y"] == 0.0 and observation[0] == info["ft"]  # at rest, fd not yet felt
    actions = np.random.default_rng(3).uniform(-2.0, 2.0, 2000)
    for action in actions:
        env.step(np.array([action]))
    recording = env.unwrapped.recording(include_run_in=True)
    t = recording.t - recording.t[0]
    y = scipy.signal.lsim(([1.0], [1.0, 0.0]), recording.u + recording.fd, t, interp=False)[1]
    np.testing.assert_allclose(recording.y, y, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(recording.e, recording.ft - recording.y)
    assert np.std(recording.fd) > 0.1  # the disturbance is really there


@pytest.mark.parametrize("task", ["Compensatory", "Preview"])
@pytest.mark.parametrize("element", ["popovici2017-tv", "gain"])
def test_native_vector_env_equals_single_envs(task, element):
    kwargs = dict(
        controlled_element=element,
        disturbance_at="input",
        realisation=None,
        run_in=0.0,
        measurement_time=0.3,
    )
    env_id = f"ManualControl/{task}Tracking-v0"
    native = gym.make_vec(env_id, num_envs=3, **kwargs)
    sync = gym.make_vec(env_id, num_envs=3, vectorization_mode="sync", **kwargs)
    a, info_a = native.reset(seed=5)
    b, _ = sync.reset(seed=5)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(info_a["y"], 0.0)
    actions = np.random.default_rng(2).uniform(-3, 3, (75, 3, 1))  # two episodes and a bit
    for action in actions:
        step_a = native.step(action)
        step_b = sync.step(action)
        for got, want in zip(step_a[:4], step_b[:4], strict=True):
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def test_recordings_say_where_the_disturbance_entered():
    for kwargs, expected in (({}, "output"), ({"disturbance_at": "input"}, "input")):
        env = CompensatoryTracking(run_in=0.0, measurement_time=1.0, **kwargs)
        env.reset(seed=0)
        env.step(np.array([0.1]))
        assert env.recording().metadata["disturbance_at"] == expected
    postview = PostviewTracking(disturbance_at="input", measurement_time=1.0)
    postview.reset(seed=0)
    postview.step(np.array([0.1]))
    assert postview.recording().metadata["disturbance_at"] == "input"


@pytest.mark.parametrize(
    "build",
    [
        lambda: CompensatoryTracking(disturbance_at="inlet"),
        lambda: gym.make("ManualControl/PursuitTracking-v0", disturbance_at="inlet"),
        lambda: gym.make_vec(
            "ManualControl/PreviewTracking-v0", num_envs=2, disturbance_at="inlet"
        ),
        lambda: PostviewTracking(disturbance_at="inlet"),
    ],
)
def test_an_unknown_disturbance_point_is_refused(build):
    message = "disturbance_at must be one of 'output', 'input', got 'inlet'"
    with pytest.raises(ValueError, match=re.escape(message)):
        build()
