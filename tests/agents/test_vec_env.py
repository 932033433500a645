"""The training's vectorised environment against stable-baselines3's own."""

import dataclasses

import numpy as np
import pytest
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import DummyVecEnv

from manualcontrol.agents._vec_env import FreshInfoVecEnv
from manualcontrol.agents.recipes import recipe
from manualcontrol.agents.training import make_env


def _same(a, b, where="info"):
    assert type(a) is type(b), where
    if isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for key in a:
            if where.endswith("['episode']") and key == "t":
                continue  # the Monitor's wall-clock time since it started
            _same(a[key], b[key], f"{where}[{key!r}]")
    elif isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b, err_msg=where)
    else:
        assert a == b or (a != a and b != b), where


@pytest.mark.parametrize("name", ["si", "lane-angle"])
def test_it_steps_as_stable_baselines3s_and_no_info_changes_after_it_is_returned(name):
    config = recipe(name, seed=3)
    short = {**config.env_kwargs, "measurement_time": 1.0}
    config = dataclasses.replace(config, env_kwargs=short, n_envs=3)

    def build(cls):
        return make_vec_env(lambda: make_env(config), n_envs=3, seed=3, vec_env_cls=cls)

    ours, theirs = build(FreshInfoVecEnv), build(DummyVecEnv)
    rng = np.random.default_rng(0)
    kept, copies, resets = [], [], 0
    try:
        np.testing.assert_array_equal(ours.reset(), theirs.reset())
        # past the end of the first episodes: the resets inside step are compared too
        while resets < 3:
            actions = rng.uniform(-0.5, 0.5, (3, *ours.action_space.shape)).astype(np.float32)
            ours.step_async(actions)
            theirs.step_async(actions)
            obs, rewards, dones, infos = ours.step_wait()
            obs_b, rewards_b, dones_b, infos_b = theirs.step_wait()
            np.testing.assert_array_equal(obs, obs_b)
            np.testing.assert_array_equal(rewards, rewards_b)
            np.testing.assert_array_equal(dones, dones_b)
            resets += int(dones.sum())
            kept.append(infos)
            copies.append(infos_b)
    finally:
        ours.close()
        theirs.close()
    assert any("terminal_observation" in info for infos in kept for info in infos)
    # the dicts handed back were not changed by the steps after them: each still equals
    # the deep copy stable-baselines3 made when it was returned
    for step, (infos, infos_b) in enumerate(zip(kept, copies, strict=True)):
        for info, info_b in zip(infos, infos_b, strict=True):
            _same(info, info_b, f"step {step}")
