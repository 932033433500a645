"""Human-limitation wrappers: what reaches the stick, what the agent observes."""

import re
import warnings

import gymnasium as gym
import numpy as np
import pytest
import scipy.signal
from gymnasium.utils.env_checker import check_env

import manualcontrol.envs  # noqa: F401
from manualcontrol.agents.wrappers import (
    ActionDelay,
    EfferenceCopy,
    EffortCost,
    MotorNoise,
    NeuromuscularFilter,
    ObservationNoise,
    apply_wrappers,
)

KWARGS = dict(run_in=0.0, measurement_time=5.0)


def base(task="Compensatory", **kwargs):
    return gym.make(f"ManualControl/{task}Tracking-v0", **{**KWARGS, **kwargs})


def applied_sticks(env, commands):
    env.reset(seed=0)
    for command in commands:
        env.step(np.array([command]))
    return env.unwrapped.recording().u


@pytest.mark.parametrize(("delay", "shift"), [(0.0, 0), (0.2, 20), (0.05, 5)])
def test_whole_sample_delays_shift_the_commands_exactly(delay, shift):
    commands = np.random.default_rng(0).uniform(-1, 1, 100)
    sticks = applied_sticks(ActionDelay(base(), delay), commands)
    np.testing.assert_array_equal(sticks[shift:], commands[: 100 - shift])
    np.testing.assert_array_equal(sticks[:shift], 0.0)


def test_fractional_delay_applies_the_mean_of_the_delayed_staircase():
    commands = np.random.default_rng(1).uniform(-1, 1, 100)
    sticks = applied_sticks(ActionDelay(base(), 0.123), commands)  # 12.3 samples
    expected = 0.7 * commands[88 - 12] + 0.3 * commands[88 - 13]
    assert sticks[88] == pytest.approx(expected, rel=1e-12)


def test_delay_observation_carries_the_queued_commands():
    env = ActionDelay(base(), 0.03)  # 3 samples queued
    observation, _ = env.reset(seed=0)
    assert observation.shape == (4,) and env.observation_space.shape == (4,)
    for command in (0.1, 0.2, 0.3):
        observation, *_ = env.step(np.array([command]))
    np.testing.assert_array_equal(observation[1:], [0.3, 0.2, 0.1])  # newest first


def test_hidden_queue_keeps_the_observation_and_the_delay():
    env = ActionDelay(base(), 0.03, observe_queue=False)
    observation, _ = env.reset(seed=0)
    assert observation.shape == (1,) and env.observation_space.shape == (1,)
    sticks = applied_sticks(env, [0.1, 0.2, 0.3, 0.4])
    np.testing.assert_array_equal(sticks, [0.0, 0.0, 0.0, 0.1])


def test_neuromuscular_filter_is_the_exact_zoh_discretisation():
    omega, zeta, dt = 10.5, 0.35, 0.01
    commands = np.random.default_rng(2).uniform(-1, 1, 200)
    sticks = applied_sticks(NeuromuscularFilter(base(), omega, zeta), commands)
    continuous = scipy.signal.tf2ss([omega**2], [1.0, 2 * zeta * omega, omega**2])
    phi, gamma, c, d, _ = scipy.signal.cont2discrete(continuous, dt)
    _, reference, _ = scipy.signal.dlsim((phi, gamma, c, d, dt), commands)
    np.testing.assert_allclose(sticks, reference[:, 0], atol=1e-12)


def test_neuromuscular_observation_is_stick_position_and_rate():
    env = NeuromuscularFilter(base(), 8.0, 0.5)
    env.reset(seed=0)
    for _ in range(30):
        observation, _, _, _, info = env.step(np.array([1.0]))
    position, rate = observation[-2:]
    assert 0.0 < position < 1.2 and rate > 0.0
    # the next stick applied is the position observed now
    _, _, _, _, info = env.step(np.array([1.0]))
    assert info["u"] == pytest.approx(position, rel=1e-12)


def test_a_hidden_limb_moves_the_stick_alike_and_shows_its_state_only_as_hidden():
    commands = np.random.default_rng(5).uniform(-1, 1, 120)
    seen, unseen = (
        NeuromuscularFilter(base(), 8.0, 0.5),
        NeuromuscularFilter(base(), 8.0, 0.5, False),
    )
    assert seen.hidden_size == 0 and unseen.hidden_size == 2
    assert unseen.observation_space == unseen.env.observation_space
    first, _ = unseen.reset(seed=0)
    assert first.shape == seen.env.observation_space.shape
    seen.reset(seed=0)
    for command in commands:
        observed, *_ = seen.step(np.array([command]))
        hidden_observation, *_ = unseen.step(np.array([command]))
        np.testing.assert_array_equal(hidden_observation, observed[:-2])
        np.testing.assert_array_equal(unseen.hidden_state(), observed[-2:])
    np.testing.assert_array_equal(seen.unwrapped.recording().u, unseen.unwrapped.recording().u)
    with pytest.raises(TypeError, match=r"observe_state must be True or False, got 'no'"):
        NeuromuscularFilter(base(), observe_state="no")


def test_motor_noise_reaches_the_requested_power_ratio():
    env = MotorNoise(base(measurement_time=60.0), power_ratio=0.3, omega_r=3.0)
    env.reset(seed=3)
    commands = np.sin(np.arange(6000) * 0.01 * 2.0)
    noise = []
    for command in commands:
        *_, info = env.step(np.array([command]))
        noise.append(info["remnant"])
    noise = np.array(noise[1000:])  # after the 5 s variance window filled
    ratio = np.var(noise) / (np.var(noise) + np.var(commands[1000:]))
    assert ratio == pytest.approx(0.3, rel=0.15)  # a 50 s sample of coloured noise


def test_noise_wrappers_are_reproducible_per_seed():
    def run(seed):
        env = ObservationNoise(MotorNoise(base(), 0.3), std=0.05)
        observations = [env.reset(seed=seed)[0]]
        for _ in range(50):
            observations.append(env.step(np.array([0.5]))[0])
        return np.array(observations)

    np.testing.assert_array_equal(run(4), run(4))
    assert not np.array_equal(run(4), run(5))


def test_stacked_wrappers_pass_check_env():
    env = apply_wrappers(
        base("Preview", available_preview=0.3),
        [
            {"kind": "neuromuscular", "omega_nms": 10.0, "zeta_nms": 0.4},
            {"kind": "action_delay", "delay": 0.2},
            {"kind": "motor_noise", "power_ratio": 0.2},
            {"kind": "observation_noise", "std": 0.01},
        ],
    )
    assert env.observation_space.shape == (31 + 1 + 2 + 20,)
    with warnings.catch_warnings():
        # known: the physical stick range, unbounded signals, and checking a wrapped env
        # on purpose (the wrappers are what is under test)
        warnings.filterwarnings(
            "ignore", message=".*(normalized space|infinity|unwrapped version).*"
        )
        check_env(env, skip_render_check=True)


@pytest.mark.parametrize(
    ("build", "error", "message"),
    [
        (lambda: ActionDelay(base(), -0.1), ValueError, "delay must lie in [0, 2], got -0.1"),
        (
            lambda: NeuromuscularFilter(base(), omega_nms=0.0),
            ValueError,
            "omega_nms must be > 0, got 0.0",
        ),
        (
            lambda: MotorNoise(base(), power_ratio=1.0),
            ValueError,
            "power_ratio must lie in [0, 1), got 1.0",
        ),
        (lambda: ObservationNoise(base(), std=-1.0), ValueError, "std must be >= 0, got -1.0"),
        (
            lambda: apply_wrappers(base(), [{"kind": "fatigue"}]),
            ValueError,
            "wrapper kind must be one of",
        ),
        (lambda: ActionDelay(gym.make("CartPole-v1"), 0.1), TypeError, "has no sample time dt"),
    ],
)
def test_bad_wrapper_arguments(build, error, message):
    with pytest.raises(error, match=re.escape(message)):
        build()


def test_non_finite_commands_raise():
    env = ActionDelay(base(), 0.1)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action must be finite"):
        env.step(np.array([np.nan]))


def test_implausible_identifications_are_flagged():
    from manualcontrol.agents.evaluation import implausible

    flags = implausible("precision", {"fit K_p": -0.016, "fit zeta_nms": 83.6, "fit tau_v": 0.2})
    assert len(flags) == 2
    assert "fit K_p = -0.016" in flags[0] and "far outside the human range" in flags[0]
    assert "fit zeta_nms = 83.6" in flags[1]


def test_motor_noise_variance_is_numpys_to_the_bit():
    # MotorNoise's compiled window variance replaces np.var per step; it follows numpy's
    # pairwise summation so the noise scale (and every episode) is unchanged, bit for bit
    from manualcontrol.agents.wrappers import _population_variance

    rng = np.random.default_rng(0)
    for _ in range(400):
        count = int(rng.integers(2, 1200))
        values = rng.standard_normal(count) * 10.0 ** rng.uniform(-5, 5)
        values += rng.uniform(-1, 1) * 10.0 ** rng.uniform(-3, 3)
        assert _population_variance(values) == np.var(values), count


def test_hidden_state_is_what_the_agent_is_not_shown():
    rng = np.random.default_rng(3)
    hidden_delay = ActionDelay(base(), 0.05, observe_queue=False)
    shown_delay = ActionDelay(base(), 0.05)
    assert (hidden_delay.hidden_size, shown_delay.hidden_size) == (5, 0)
    noisy = ObservationNoise(base(include_rates=True), ratio=0.01, omega_r=10.0)
    assert noisy.hidden_size == 2
    motor = MotorNoise(base(), power_ratio=0.1)
    effort = EffortCost(base(), rate_weight=0.01)
    for env in (hidden_delay, motor, effort):
        env.reset(seed=0)
    _, info = noisy.reset(seed=0)
    error = info["e"]
    commands, previous_state = [], None
    for _ in range(60):
        command = rng.uniform(-1.0, 1.0, 1)
        commands.insert(0, float(command[0]))
        hidden_delay.step(command)
        np.testing.assert_array_equal(hidden_delay.hidden_state(), (commands + [0.0] * 5)[:5])
        # the noise on the display: the observation less the noise-free error and rate
        observation, _, _, _, info = noisy.step(command)
        clean = np.array([info["e"], (info["e"] - error) / 0.01])
        error = info["e"]
        np.testing.assert_allclose(noisy.hidden_state(), observation - clean, atol=1e-9)
        # the motor noise's next remnant is its filter's state scaled by a positive gain
        _, _, _, _, info = motor.step(command)
        if previous_state is not None:
            assert info["remnant"] / previous_state > 0.0
        previous_state = float(motor.hidden_state()[0])
        assert previous_state != 0.0  # a fresh normal draw in it
        # the effort cost's last stick is the stick the element received
        _, _, _, _, info = effort.step(command)
        assert effort.hidden_state()[0] == info["u"]
    with pytest.raises(ValueError, match="read-only"):
        hidden_delay.hidden_state()[0] = 0.0


def test_efference_copy_shows_the_last_command_as_the_stick_takes_it():
    env = EfferenceCopy(ActionDelay(base(action_bound=2.0), delay=0.2, observe_queue=False))
    inner = env.env.observation_space.shape[0]
    assert env.observation_space.shape == (inner + 1,)
    observation, _ = env.reset(seed=0)
    assert observation[-1] == 0.0  # the stick at rest before the episode
    for command, shown in ((0.5, 0.5), (-3.0, -2.0), (1.25, 1.25)):
        observation, *_ = env.step(np.array([command]))
        assert observation[-1] == shown  # clipped to the stick's bound
        # the commands still in the delay stay hidden: only the newest is added
        assert observation.shape == (inner + 1,)
    observation, _ = env.reset(seed=1)
    assert observation[-1] == 0.0
    check_env(EfferenceCopy(base()), skip_render_check=True)


def test_the_efference_copy_comes_outside_the_history_once():
    from manualcontrol.agents.training import TrainingConfig, make_env

    config = TrainingConfig(history_length=3, efference_copy=True, algorithm="ppo")
    assert [spec["kind"] for spec in config.limitations][-2:] == [
        "observation_history",
        "efference_copy",
    ]
    frame = make_env(TrainingConfig(algorithm="ppo")).observation_space.shape[0]
    assert make_env(config).observation_space.shape == (3 * frame + 1,)
    with pytest.raises(ValueError, match="efference_copy and a wrappers entry"):
        TrainingConfig(efference_copy=True, wrappers=({"kind": "efference_copy"},))
    with pytest.raises(TypeError, match="efference_copy must be True or False"):
        TrainingConfig(efference_copy="yes")
