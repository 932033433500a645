"""RL agents on the lane-keeping task, through the same training path as tracking."""

import json

import numpy as np

from manualcontrol.agents.training import TrainingConfig, load_agent, make_env, train
from manualcontrol.bench.cli import main


def test_ppo_trains_on_lane_keeping_and_reloads(tmp_path):
    config = TrainingConfig(
        task="lane-keeping",
        env_kwargs={"road": "random", "measurement_time": 5.0},
        algorithm="ppo",
        total_timesteps=128,
        n_envs=2,
        algorithm_kwargs={"n_steps": 64, "batch_size": 64, "n_epochs": 1},
        policy_kwargs={"net_arch": [16, 16]},
    )
    agent = train(config, tmp_path, report=None)
    env = make_env(config)
    observation, _ = env.reset(seed=0)
    assert observation.shape == (4,)
    action = agent.act(observation)
    assert action.shape == (1,) and np.isfinite(action).all()
    np.testing.assert_array_equal(load_agent(tmp_path).act(observation), action)


def test_the_train_command_takes_the_lane_keeping_task(tmp_path):
    code = main(
        [
            "train",
            "--task",
            "lane-keeping",
            "--env",
            "steering=angle",
            "--env",
            "measurement_time=3",
            "--algorithm",
            "ppo",
            "--steps",
            "64",
            "--algorithm-option",
            "n_steps=64",
            "--algorithm-option",
            "batch_size=32",
            "--out",
            str(tmp_path),
            "--quiet",
        ]
    )
    assert code == 0
    config = json.loads((tmp_path / "config.json").read_text())
    assert config["task"] == "lane-keeping" and config["env_kwargs"]["steering"] == "angle"
