"""A trained agent's action at each sample: predict's numbers, bit for bit, called cheaply.

Evaluation calls the policy once a sample; ``TrainedAgent.act`` computes the mean
action without ``predict``'s per-call overhead, so it must give exactly what
``policy.predict(observation, deterministic=True)`` gives, on every policy kind the
training builds: PPO's plain and informed-critic policies (the short path) and SAC
(through its own ``_predict``), inside and beyond the action bounds (the clip).
"""

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3 import PPO, SAC

import manualcontrol.envs  # noqa: F401
from manualcontrol.agents.critic import InformedCriticPolicy
from manualcontrol.agents.recipes import recipe
from manualcontrol.agents.training import TrainedAgent


def env():
    return gym.make("ManualControl/CompensatoryTracking-v0", measurement_time=2.0)


def policies():
    return {
        "ppo": PPO("MlpPolicy", env(), seed=1, policy_kwargs={"net_arch": [16]}).policy,
        "ppo informed critic": PPO(
            InformedCriticPolicy, env(), seed=2, policy_kwargs={"actor_inputs": 1}
        ).policy,
        "sac": SAC("MlpPolicy", env(), seed=3, policy_kwargs={"net_arch": [16]}).policy,
    }


@pytest.mark.parametrize("kind", ["ppo", "ppo informed critic", "sac"])
def test_the_agents_action_is_predicts_bit_for_bit(kind):
    policy = policies()[kind]
    if kind.startswith("ppo"):  # PPO's initial mean is about 0.01: make it reach the bounds
        with torch.no_grad():
            policy.action_net.weight.mul_(1e4)
    policy.set_training_mode(True)  # as a policy is while it trains
    agent = TrainedAgent(recipe("si"), policy)
    rng = np.random.default_rng(0)
    size = policy.observation_space.shape[0]
    observations = rng.normal(0.0, 30.0, size=(300, size))  # far out too: the clip
    acted = np.array([agent.act(observation) for observation in observations])
    predicted = np.array(
        [
            policy.predict(observation.astype(np.float32), deterministic=True)[0]
            for observation in observations
        ]
    )
    assert acted.dtype == np.float64 and acted.shape == (300, 1)
    assert acted.tobytes() == predicted.astype(np.float64).reshape(300, 1).tobytes()
    high = policy.action_space.high[0]
    assert np.any(np.abs(acted) == high) and np.any(np.abs(acted) < high)
    assert not policy.training


class DictDisplay(gym.ObservationWrapper):
    """The tracking display as a dict: a policy with no one-shaped tensor to read."""

    def __init__(self, env):
        super().__init__(env)
        self.observation_space = gym.spaces.Dict({"display": env.observation_space})

    def observation(self, observation):
        return {"display": observation}


@pytest.mark.parametrize("kind", ["a dict observation", "discrete actions"])
def test_a_policy_off_the_short_path_acts_through_predict(kind):
    if kind == "a dict observation":
        policy = PPO("MultiInputPolicy", DictDisplay(env()), seed=4).policy
        observation = {"display": np.array([0.3], dtype=np.float32)}
    else:
        policy = PPO("MlpPolicy", gym.make("CartPole-v1"), seed=5).policy
        observation = np.array([0.1, -0.2, 0.05, 0.3], dtype=np.float32)
    agent = TrainedAgent(recipe("si"), policy)
    expected, _ = policy.predict(observation, deterministic=True)
    acted = agent.act(observation)
    assert acted.dtype == np.float64 and acted.shape == (1,)
    assert acted.tobytes() == np.asarray(expected, dtype=np.float64).reshape(1).tobytes()


def test_a_policy_with_a_linear_path_saves_and_loads_as_itself(tmp_path):
    """stable-baselines3's own save and load keep the actor's inputs and the linear path."""
    policy = PPO(
        InformedCriticPolicy, env(), seed=4, policy_kwargs={"actor_inputs": 1, "linear_path": True}
    ).policy
    with torch.no_grad():
        policy.action_net.weight.normal_()
    policy.save(tmp_path / "policy.pt")
    loaded = InformedCriticPolicy.load(tmp_path / "policy.pt")
    assert loaded.linear_path and loaded.actor_inputs == 1
    observations = np.random.default_rng(2).normal(size=(20, policy.observation_space.shape[0]))
    for observation in observations.astype(np.float32):
        assert (
            loaded.predict(observation, deterministic=True)[0].tobytes()
            == policy.predict(observation, deterministic=True)[0].tobytes()
        )
    with pytest.raises(TypeError, match="linear_path must be"):
        PPO(InformedCriticPolicy, env(), policy_kwargs={"actor_inputs": 1, "linear_path": "no"})
