"""Training recipes: the configurations `manualcontrol train --recipe` gives."""

import json

import gymnasium as gym
import numpy as np
import pytest

import manualcontrol.envs  # noqa: F401
from manualcontrol.agents.recipes import (
    human_problem,
    optimal_control_effort_weight,
    recipe,
)
from manualcontrol.agents.training import make_env
from manualcontrol.agents.wrappers import ObservationScale
from manualcontrol.bench.cli import main


@pytest.mark.parametrize("element", ["1/s", "1/s^2", "1/(s(s+1))"])
def test_the_human_problem_builds_its_environment_with_the_human_limitations(element):
    config = human_problem(element, seed=3)
    assert config.seed == 3 and config.algorithm == "ppo"
    kinds = [spec["kind"] for spec in config.limitations]
    # every recipe acts through a perceptual delay the agent cannot see
    assert kinds[0] == "action_delay" or "action_delay" in kinds
    delay = next(spec for spec in config.limitations if spec["kind"] == "action_delay")
    assert delay["delay"] == 0.2 and delay["observe_queue"] is False
    assert "effort_cost" in kinds and "motor_noise" in kinds and "observation_noise" in kinds
    env = make_env(config)
    observation, _ = env.reset(seed=0)
    assert env.observation_space.contains(observation)
    env.close()


def test_a_recipe_takes_a_seed_and_a_length_and_rejects_unknown_names():
    assert recipe("si", total_timesteps=1000).total_timesteps == 1000
    assert recipe("si", seed=4) == human_problem("1/s", seed=4)
    with pytest.raises(ValueError, match="recipe must be one of"):
        recipe("hover")


def test_observation_scale_divides_each_value_and_checks_its_length():
    env = gym.make("ManualControl/PursuitTracking-v0", measurement_time=1.0)
    scaled = ObservationScale(env, [2.0, 4.0])
    observation, _ = scaled.reset(seed=0)
    raw, _ = env.reset(seed=0)
    np.testing.assert_array_equal(observation, raw / np.array([2.0, 4.0]))
    np.testing.assert_array_equal(
        scaled.observation_space.high, env.observation_space.high / [2, 4]
    )
    with pytest.raises(ValueError, match=r"scale must be one number or 2 \(one per observed"):
        ObservationScale(env, [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="scale must be finite and > 0"):
        ObservationScale(env, 0.0)


def test_the_train_command_refuses_flags_a_recipe_sets(tmp_path, capsys):
    code = main(["train", "--recipe", "si", "--delay", "0.1", "--out", str(tmp_path / "a")])
    err = capsys.readouterr().err
    assert code == 2 and "--recipe si sets the training itself; drop --delay" in err
    code = main(["train", "--recipe", "hover", "--out", str(tmp_path / "a")])
    assert code == 2 and "--recipe must be one of si, got 'hover'" in capsys.readouterr().err
    assert not (tmp_path / "a").exists()


def test_the_train_command_trains_a_recipe(tmp_path):
    out = tmp_path / "agent"
    code = main(
        ["train", "--recipe", "si", "--steps", "64", "--seed", "2", "--out", str(out), "--quiet"]
    )
    assert code == 0
    config = json.loads((out / "config.json").read_text())
    assert config["seed"] == 2 and config["total_timesteps"] == 64
    assert config["env_kwargs"]["controlled_element"] == "1/s"
    weight = optimal_control_effort_weight("1/s", "vanderel-bw4", 5.0)
    assert config["effort_rate_weight"] == pytest.approx(weight, rel=1e-12)


def test_the_optimal_control_effort_weight_poses_the_ocms_trade_off_in_reward_units():
    from manualcontrol.envs.signals import forcing_preset
    from manualcontrol.pilots import solve_ocm

    weight = optimal_control_effort_weight("1/s", "vanderel-bw4", 5.0)
    target = forcing_preset("vanderel-bw4", 0).target
    g = solve_ocm("1/s", "vanderel-bw4", tau_v=0.2, tau_nms=0.1).g
    assert weight == pytest.approx(g * 25.0 / target.variance, rel=1e-12)
    # the OCM's pilot with that g has the 0.1-s lag it was asked for
    assert solve_ocm("1/s", "vanderel-bw4", g=g).tau_nms == pytest.approx(0.1, rel=1e-6)
    # a double integrator needs more stick rate for the same error: a smaller weight
    assert optimal_control_effort_weight("1/s^2", "vanderel-bw4", 5.0) < weight / 3
