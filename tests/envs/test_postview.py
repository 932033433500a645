"""The gap-postview environment, and the critical task with band-limited noise in the envs.

Every comparison with simulate() is exact to 1e-12 (measured 0): the environment and the
sampled simulation read the same forcing at the same times with the same rules.
"""

import doctest
import pickle
import re
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import manualcontrol.envs  # noqa: F401  (registers the ids)
from manualcontrol.envs import postview
from manualcontrol.envs.schedules import BandLimitedRandomWalk, Ramp
from manualcontrol.envs.signals import forcing_preset
from manualcontrol.pilots import Pilot, simulate

KNOWN_WARNINGS = (
    r".*we recommend using a symmetric and normalized space.*",
    r".*Box observation space (minimum|maximum) value is (-)?infinity.*",
)
GAP = BandLimitedRandomWalk(0.4, 0.8 * 0.1 / 600, 0.3, 60.0, 11)
DT = 1 / 36


def make(**kwargs):
    options = {"dt": DT, "measurement_time": 10.0, "gap": GAP, **kwargs}
    return gym.make("ManualControl/PostviewTracking-v0", **options)


def run(env, pilot, seed=0):
    observation, _ = env.reset(seed=seed)
    pilot.reset(seed=seed, env=env)
    done = False
    while not done:
        observation, _, terminated, truncated, _ = env.step(pilot.act(observation))
        done = terminated or truncated
    return env.unwrapped.recording()


@pytest.mark.parametrize("extras", [False, True])
def test_check_env_passes_with_rendering(extras):
    env = make(include_rates=extras, include_previous_action=extras, render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for message in KNOWN_WARNINGS:
            warnings.filterwarnings("ignore", message=message)
        check_env(env.unwrapped)


def test_the_observation_is_the_visible_track_read_back_from_the_gap():
    env = make(realisation=2, gap=0.3)
    observation, info = env.reset(seed=0)
    for _ in range(50):
        observation, _, _, _, info = env.step(np.array([0.1]))
    track = forcing_preset("boer-kenyon1998-postview", 2).target
    t = info["t"]
    count = round(1.0 / DT) + 1
    assert observation.shape == (count + 2,)
    lags = np.minimum(0.3 + DT * np.arange(count), 1.0)
    np.testing.assert_allclose(observation[:count], track(t - lags), rtol=0, atol=1e-12)
    assert observation[count] == 0.3 and info["gap"] == 0.3
    assert observation[count + 1] == info["y"]
    # the current target is scored, not shown
    assert info["e"] == pytest.approx(track(t) - info["y"], abs=1e-12)


def test_a_pilot_acting_in_the_env_equals_simulate():
    pilot = Pilot("postview", {"K_v": 0.224, "tau_v": 0.05})
    from_env = run(make(measurement_time=20.0), pilot, seed=3)
    simulated = simulate(
        pilot,
        "gain",
        "boer-kenyon1998-postview",
        task="postview",
        gap=GAP,
        dt=DT,
        run_in=0.0,
        measurement_time=20.0,
        loop="sampled",
        seed=3,
    )
    for name in ("t", "ft", "y", "e", "u"):
        np.testing.assert_allclose(from_env[name], simulated[name], rtol=0, atol=1e-12)
    np.testing.assert_allclose(from_env.parameters["gap"], simulated.parameters["gap"], atol=0)
    assert np.std(from_env.u) > 0.5
    assert simulated.metadata["gap"] == GAP.to_dict()


def test_the_operator_extrapolates_the_visible_end_of_the_track():
    # u = K_p ft(t - gap) + K_v ft'(t - gap), the slope by the second-order backward
    # difference the display allows: within (dt^2/3) |ft'''| of the true slope
    pilot = Pilot("postview", {"K_p": 1.0, "K_v": 0.2, "tau_v": 0.0})
    recording = simulate(
        pilot,
        "gain",
        "boer-kenyon1998-postview",
        task="postview",
        gap=0.35,
        dt=DT,
        run_in=0.0,
        measurement_time=20.0,
        loop="sampled",
    )
    track = forcing_preset("boer-kenyon1998-postview", 0).target
    t = recording.t[40:]
    expected = track(t - 0.35) + 0.2 * track.derivative(t - 0.35)
    np.testing.assert_allclose(recording.u[40:], expected, rtol=0, atol=2e-3 * np.std(expected))


def test_the_critical_task_with_noise_ends_at_loss_of_control_like_simulate():
    pilot = Pilot(
        "gain-delay",
        {"K_p": Ramp(2.0, 1.5, 0.0, 36.0), "tau_v": Ramp(0.25, 0.15, 0.0, 36.0)},
    )
    element = {"kind": "critical_task", "start": 0.0, "rate": 0.11}
    options = dict(dt=DT, run_in=0.0, measurement_time=80.0)
    env = gym.make(
        "ManualControl/CompensatoryTracking-v0",
        controlled_element=element,
        forcing="boer-kenyon1998-critical",
        loss_of_control=0.2,
        **options,
    )
    from_env = run(env, pilot, seed=0)
    simulated = simulate(
        pilot,
        element,
        "boer-kenyon1998-critical",
        loss_of_control=0.2,
        loop="sampled",
        seed=0,
        **options,
    )
    assert len(from_env) == len(simulated) < round(80.0 / DT)
    assert simulated.metadata["terminated"] is True
    for name in ("t", "fd", "y", "e", "u"):
        np.testing.assert_allclose(from_env[name], simulated[name], rtol=0, atol=1e-12)
    assert 20.0 < simulated.t[-1] < 60.0  # the instability at loss: 0.11/s x that


def test_gap_and_postview_are_checked():
    with pytest.raises(ValueError, match=re.escape("gap must lie in [0, 1) s")):
        make(gap=1.2)
    with pytest.raises(ValueError, match=re.escape("postview must be > 0, got 0.0")):
        make(postview=0.0)
    with pytest.raises(ValueError, match=re.escape("postview must show at least 3 samples")):
        make(postview=0.04, gap=0.0)
    with pytest.raises(TypeError, match=re.escape("gap: a schedule or a real number is required")):
        make(gap="wide")
    with pytest.raises(ValueError, match="available_preview must be 0"):
        make(available_preview=1.0)
    with pytest.raises(ValueError, match="gap and postview belong to the postview task"):
        simulate(Pilot("gain-delay"), "gain", "boer-kenyon1998-critical", gap=0.3)
    with pytest.raises(ValueError, match="does not fit the 'postview' pilot model"):
        simulate(Pilot("postview"), "gain", "boer-kenyon1998-postview", task="pursuit")


def test_episodes_repeat_with_the_seed_and_pickle():
    env = make(realisation=None)
    first, _ = env.reset(seed=4)
    again, _ = env.reset(seed=4)
    np.testing.assert_array_equal(first, again)
    copy = pickle.loads(pickle.dumps(env.unwrapped))
    np.testing.assert_array_equal(copy.reset(seed=4)[0], first)


def test_renders_the_track_above_the_marker():
    env = make(render_mode="rgb_array", gap=0.5)
    env.reset(seed=0)
    env.step(np.array([0.0]))
    frame = env.render()
    assert frame.shape == (400, 600, 3)
    yellow = (frame[..., 0] > 200) & (frame[..., 1] > 150) & (frame[..., 2] < 100)
    rows = np.flatnonzero(yellow.any(axis=1))
    marker_row = int(0.85 * 400)
    # the track spans the top of the screen down to half the way (gap 0.5 of 1 s) and no further
    assert rows.min() < 0.2 * 400
    assert rows.max() < marker_row - 0.45 * (marker_row - 0.1 * 400)


def test_the_module_doctest():
    results = doctest.testmod(postview, optionflags=doctest.ELLIPSIS)
    assert results.attempted >= 3 and results.failed == 0
