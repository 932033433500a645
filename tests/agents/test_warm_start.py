"""A typical pilot's start: PPO's policy begins as the typical pilot's equaliser."""

import dataclasses
import functools
import json
import warnings

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO

from manualcontrol.agents.recipes import RECIPE_ELEMENTS, human_problem, recipe
from manualcontrol.agents.training import (
    PPO_DEFAULT_LEARNING_RATE,
    TrainingConfig,
    WarmStartWarning,
    clone_typical_pilot,
    make_env,
    policy_spec,
    train,
    typical_pilot_law,
    warm_start_warning,
)
from manualcontrol.estimators.analysis.human_likeness import reference_pilot


def short(config, seconds=10.0):
    """The same problem with shorter episodes (still over the critic's 5-s cut)."""
    kwargs = {**config.env_kwargs, "measurement_time": seconds}
    return dataclasses.replace(config, env_kwargs=kwargs)


def states_of(config, law, seed):
    """Observations the law visits through the configuration's wrappers (another seed)."""
    env = make_env(config)
    observation, _ = env.reset(seed=seed)
    seen, done = [], False
    while not done:
        seen.append(observation)
        observation, _, terminated, truncated, _ = env.step(law(observation))
        done = terminated or truncated
    env.close()
    return np.array(seen)


def policy_mean(policy, states):
    """The policy's mean action on states (a copy: the policy reuses its distribution)."""
    with torch.no_grad():
        distribution = policy.get_distribution(torch.as_tensor(states, dtype=torch.float32))
        return distribution.distribution.mean.numpy().copy()


@pytest.mark.parametrize("element", ["1/s^2", "1/(s(s+1))"])
def test_the_cloned_policy_acts_as_the_typical_pilots_equaliser(element):
    # one frame: the fit to a history is the next test's (a short fit to the recipes' 20
    # frames needs more states and steps than this test can afford)
    config = short(
        dataclasses.replace(human_problem(element, warm_start="typical-pilot"), history_length=1)
    )
    law = typical_pilot_law(config)
    typical = reference_pilot(element)
    # the law is the precision model's equaliser K_p e + K_v e_dot on the display
    np.testing.assert_allclose(
        law(np.array([0.1, -0.2])), [typical["K_p"] * 0.1 - typical["K_v"] * 0.2]
    )
    env = make_env(config)
    policy, kwargs = policy_spec(config, env)
    model = PPO(policy, env, seed=0, policy_kwargs={**kwargs, "net_arch": [64, 64]})
    held_out = states_of(config, law, seed=99)
    before = policy_mean(model.policy, held_out)
    fit = clone_typical_pilot(model.policy, config, episodes=4, iterations=1500)
    assert fit["residual_rms"] < 0.05 * fit["law_rms"]
    # the critic learned the law's returns: a random one misses even their mean level
    assert fit["value_explained"] > 0.0
    target = law(held_out)
    error = np.sqrt(np.mean((policy_mean(model.policy, held_out) - target) ** 2))
    untrained = np.sqrt(np.mean((before - target) ** 2))
    # on states of an episode it was not fitted on: within 10 % of the law's RMS, where
    # the random policy missed it by about all of it
    rms = np.sqrt(np.mean(target**2))
    assert error < 0.1 * rms < untrained


def test_a_start_with_a_history_acts_on_the_newest_frame():
    """With a memory, the start is still the law: on the newest (e, e_dot) of the window."""
    # the critic's information (appended after the history) is not what is tested here
    single = dataclasses.replace(
        short(human_problem("1/s", warm_start="typical-pilot")),
        critic_information=False,
        history_length=1,
    )
    config = dataclasses.replace(single, history_length=4)
    law = typical_pilot_law(config)
    frame = make_env(single).observation_space.shape[0]
    assert make_env(config).observation_space.shape == (4 * frame,)
    held_out = states_of(config, law, seed=99)
    # newest first: the law's action is the one it takes on the newest frame alone
    np.testing.assert_array_equal(law(held_out), law(held_out[:, :frame]))
    assert not np.array_equal(law(held_out), law(held_out[:, frame : 2 * frame]))
    model = PPO("MlpPolicy", make_env(config), seed=0, policy_kwargs={"net_arch": [64, 64]})
    fit = clone_typical_pilot(model.policy, config, episodes=4, iterations=1500)
    assert fit["residual_rms"] < 0.05 * fit["law_rms"]
    target = law(held_out)
    error = np.sqrt(np.mean((policy_mean(model.policy, held_out) - target) ** 2))
    assert error < 0.1 * np.sqrt(np.mean(target**2))


def test_the_start_on_a_gain_integrates_through_its_efference_copy():
    """The lag law, flown through the problem noise-free: the typical pilot's equaliser
    ``(K_p)/(T_I s + 1)`` held over each sample, so its commands obey the exact
    discrete lag on the error it saw (the newest frame) and its own last command."""
    config = short(human_problem("gain", warm_start="typical-pilot"))
    assert config.efference_copy
    typical = reference_pilot("gain")
    law = typical_pilot_law(config)
    env = make_env(config, noise=False)
    observation, _ = env.reset(seed=3)
    errors, commands = [], []
    for _ in range(300):
        action = law(observation)
        errors.append(observation[0])
        commands.append(action[0])
        observation, *_ = env.step(action)
        assert observation[env.actor_inputs - 1] == action[0]  # the copy the law reads
    env.close()
    held = np.exp(-0.01 / typical["T_I"])
    errors, commands = np.array(errors), np.array(commands)
    np.testing.assert_allclose(
        commands[1:], held * commands[:-1] + (1.0 - held) * typical["K_p"] * errors[1:], rtol=1e-12
    )


def test_a_policy_with_a_linear_path_starts_as_the_lag_law_itself():
    """On a pure gain the law's step is 0.3 % of its command: a policy with a linear path
    takes the law exactly (its network's part zero), at every state, seen or not, and
    acts through ``predict`` and the agent's short path alike; its critic is fitted."""
    from manualcontrol.agents.training import TrainedAgent

    config = short(human_problem("gain", warm_start="typical-pilot"))
    config = dataclasses.replace(
        config, policy_kwargs={**config.policy_kwargs, "linear_path": True}
    )
    law = typical_pilot_law(config)
    env = make_env(config)
    policy, kwargs = policy_spec(config, env)
    assert kwargs["linear_path"] is True
    model = PPO(policy, env, seed=0, policy_kwargs=kwargs)
    fit = clone_typical_pilot(model.policy, config, episodes=2, iterations=300)
    assert fit["residual_rms"] < 1e-5 * fit["law_rms"]
    assert fit["value_explained"] > 0.0
    held_out = states_of(config, law, seed=99)
    far = np.random.default_rng(1).normal(0.0, 0.3, held_out.shape)  # states it never saw
    for states in (held_out, far):
        np.testing.assert_allclose(policy_mean(model.policy, states), law(states), atol=1e-5)
    agent = TrainedAgent(config, model.policy)
    predicted = model.policy.predict(held_out[:50].astype(np.float32), deterministic=True)[0]
    acted = np.array([agent.act(state) for state in held_out[:50]])
    assert acted.tobytes() == predicted.astype(np.float64).reshape(50, 1).tobytes()


def test_training_from_the_typical_pilot_says_so_and_saves_the_start(tmp_path):
    lag = recipe("lag", total_timesteps=64)
    # one short update at the recipe's own learning rate (its history's frames need it)
    options = {**lag.algorithm_kwargs, "n_steps": 64, "batch_size": 64}
    config = dataclasses.replace(short(lag), algorithm_kwargs=options)
    assert config.warm_start == "typical-pilot"
    lines = []
    with warnings.catch_warnings():
        warnings.simplefilter("error", WarmStartWarning)  # the recipe's rate: no warning
        agent = train(config, tmp_path / "agent", report=lines.append, report_every=10**9)
    assert lines[0].startswith("warm start: the typical pilot's equaliser fitted on")
    saved = json.loads((tmp_path / "agent" / "config.json").read_text())
    assert saved["warm_start"] == "typical-pilot"
    # after one short PPO update the agent still acts about as the law does
    law = typical_pilot_law(config)
    states = states_of(config, law, seed=5)[::25]
    actions = np.array([agent.act(state)[0] for state in states])
    target = law(states)[:, 0]
    assert np.corrcoef(actions, target)[0, 1] > 0.9


def test_every_tracking_recipe_starts_from_the_typical_pilot():
    assert set(RECIPE_ELEMENTS) == {"gain", "si", "di", "lag"}
    for name, element in RECIPE_ELEMENTS.items():
        assert recipe(name, seed=2) == human_problem(element, seed=2, warm_start="typical-pilot")
    assert human_problem("1/s").warm_start == "none"  # the problem itself starts at random


def test_episodes_too_short_for_the_critics_returns_are_refused():
    config = short(human_problem("1/s^2", warm_start="typical-pilot"), seconds=4.0)
    model = PPO("MlpPolicy", make_env(config), seed=0)
    with pytest.raises(ValueError, match="episodes must last over 500 steps"):
        clone_typical_pilot(model.policy, config, episodes=1, iterations=1)


def test_a_start_the_observation_cannot_carry_is_refused():
    base = dataclasses.replace(human_problem("1/s^2"), history_length=1)
    with pytest.raises(ValueError, match="warm_start must be one of"):
        dataclasses.replace(base, warm_start="expert")
    for change, message in (
        ({"algorithm": "sac", "algorithm_kwargs": {}}, "algorithm must be 'ppo', got 'sac'"),
        (
            {"wrappers": (*base.wrappers, {"kind": "observation_history", "length": 3})},
            "give history_length and efference_copy instead",
        ),
        (
            {"env_kwargs": {**base.env_kwargs, "include_rates": False}},
            "give env_kwargs include_rates=True",
        ),
        (
            {"env_kwargs": {**base.env_kwargs, "controlled_element": "critical-task"}},
            "element 'critical-task' has no typical pilot",
        ),
        (
            {"env_kwargs": {**base.env_kwargs, "controlled_element": "gain"}},
            "lags its command .* give efference_copy=True",
        ),
    ):
        with pytest.raises(ValueError, match=message):
            dataclasses.replace(base, warm_start="typical-pilot", **change)
    with pytest.raises(ValueError, match="task must be 'compensatory', got 'lane-keeping'"):
        TrainingConfig(task="lane-keeping", algorithm="ppo", warm_start="typical-pilot")


def test_the_train_command_names_its_flags_when_a_start_cannot_be_made(tmp_path, capsys):
    from manualcontrol.bench.cli import main

    out = tmp_path / "agent"
    for flags, message in (
        ([], "--algorithm must be 'ppo', got 'sac'"),
        (["--algorithm", "ppo"], "give --env include_rates=true"),
        (
            [
                "--algorithm",
                "ppo",
                "--env",
                "include_rates=true",
                "--env",
                "controlled_element=gain",
            ],
            "can only do reading its last command: give --efference-copy",
        ),
    ):
        code = main(["train", "--warm-start", "typical-pilot", *flags, "--out", str(out)])
        assert code == 2 and message in capsys.readouterr().err
    assert not out.exists()


def test_a_start_with_a_history_at_ppos_default_learning_rate_is_warned_of():
    history = recipe("si")
    assert warm_start_warning(history) is None  # the recipe's third of the default
    default = {k: v for k, v in history.algorithm_kwargs.items() if k != "learning_rate"}
    at_default = dataclasses.replace(history, algorithm_kwargs=default)
    message = warm_start_warning(at_default)
    assert "history_length=20 at a learning rate of 0.0003" in message
    assert f"learning_rate below {PPO_DEFAULT_LEARNING_RATE:g}" in message
    faster = dataclasses.replace(history, algorithm_kwargs={**default, "learning_rate": 1e-3})
    assert "learning rate of 0.001" in warm_start_warning(faster)
    # one frame, or no start to lose: nothing to warn of
    assert warm_start_warning(dataclasses.replace(at_default, history_length=1)) is None
    assert warm_start_warning(dataclasses.replace(at_default, warm_start="none")) is None


def test_the_train_command_warns_of_a_history_at_ppos_default_rate_before_training(
    tmp_path, capsys, monkeypatch
):
    from manualcontrol.agents import training
    from manualcontrol.bench.cli import main

    # the warning is what is tested: the start fitted on two episodes and a hundred steps
    clone = functools.partial(training.clone_typical_pilot, episodes=2, iterations=100)
    monkeypatch.setattr(training, "clone_typical_pilot", clone)

    flags = [
        "train", "--warm-start", "typical-pilot", "--algorithm", "ppo", "--history", "5",
        "--env", "include_rates=true", "--env", "measurement_time=6", "--steps", "64",
        "--envs", "1", "--algorithm-option", "n_steps=64", "--algorithm-option",
        "batch_size=64", "--quiet",
    ]  # fmt: skip
    assert main([*flags, "--out", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    assert "manualcontrol train: warning: --warm-start typical-pilot with --history 5" in err
    assert "give --algorithm-option learning_rate=R, R below 0.0003" in err
    assert err.count("warning") == 1  # the library's own warning is not repeated
