"""A critic that sees the loop's hidden state, for an actor that sees only the display.

PPO weighs each action by an advantage, the return that followed it less the critic's
estimate of the return from its state. In tracking, most of that return is decided by
what the operator cannot see: where the target goes next, the element's state, the
commands still travelling through the delay, the noise's state. A critic that reads
only the display explains little of the return (about 40 % of the typical pilot's
returns on the human's problem), so the advantages are mostly the forcing's future,
and the gradient that would move the policy towards its optimum is lost in it (the
objective is flat near the optimum: a gain a third away costs about 1 % of the return).

An asymmetric actor-critic (Pinto et al. 2018, "Asymmetric actor critic for
image-based robot learning") gives the critic what the simulator knows and keeps the
actor to what the operator perceives. The critic is a device of training only, like
the exploration noise: the policy that acts, and is evaluated and identified, reads
exactly the observation it reads without it. :class:`CriticInformation` appends the
hidden state to the observation; :class:`InformedCriticPolicy` zeroes it for the actor.
(This module loads torch: :func:`~manualcontrol.agents.training.make_env` imports it
only for a configuration with ``critic_information``.)
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch
from numpy.typing import NDArray
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import FlattenExtractor
from torch import nn

from manualcontrol.agents.wrappers import (
    ActionDelay,
    EffortCost,
    MotorNoise,
    NeuromuscularFilter,
    ObservationNoise,
)
from manualcontrol.envs._validation import check_bool
from manualcontrol.envs.tracking import TrackingEnv

FloatArray = NDArray[np.float64]

__all__ = ["CriticInformation", "InformedCriticPolicy", "critic_horizon", "forcing_spacing"]


def critic_horizon(gamma: float, dt: float) -> float:
    """How far ahead the critic reads the forcing: two discount horizons, ``2 dt/(1 - gamma)``.

    A reward ``n`` samples ahead weighs ``gamma^n`` in the return, so beyond two horizons
    the forcing adds at most ``e^-2`` (14 %) of its weight to the value.
    """
    return 2.0 * dt / (1.0 - gamma)


def forcing_spacing(env: gym.Env) -> float:
    """How finely the critic samples the forcing ahead: a tenth of its fastest period.

    At least one sample of ``env``; the realisations of a forcing share its frequencies.
    """
    pair = env.unwrapped.forcing
    fastest = max(
        float(np.max(signal.frequencies))
        for signal in (pair.target, pair.disturbance)
        if signal is not None
    )
    return max(float(env.unwrapped.dt), 0.1 * 2.0 * np.pi / fastest)


#: The wrappers whose hidden state the critic reads (``hidden_size``, ``hidden_state()``).
_HIDDEN_KINDS = (ActionDelay, ObservationNoise, MotorNoise, EffortCost, NeuromuscularFilter)


def _chain(env: gym.Env) -> list[gym.Env]:
    layers = []
    while isinstance(env, gym.Wrapper):
        layers.append(env)
        env = env.env
    return layers


class CriticInformation(gym.Wrapper):
    """Appends the tracking loop's hidden state to the observation, for a critic to read.

    After the wrapped observation (what the agent perceives, ``actor_inputs`` numbers)
    come, in this order:

    * the target and the disturbance over the next ``horizon`` seconds, every
      ``spacing`` seconds from now (zero past the episode's forcing), less the element's
      present output for the target;
    * the element's state, and the error without observation noise;
    * the commands in each :class:`~manualcontrol.agents.wrappers.ActionDelay` queue
      that the agent is not shown;
    * the state of each noise filter
      (:class:`~manualcontrol.agents.wrappers.ObservationNoise`,
      :class:`~manualcontrol.agents.wrappers.MotorNoise`) and the last stick of each
      :class:`~manualcontrol.agents.wrappers.EffortCost`;
    * the fraction of the episode elapsed (the return ends with it).

    It reads them through the public views the simulation offers for this:
    :meth:`~manualcontrol.envs.tracking.TrackingEnv.forcing_samples` and
    :meth:`~manualcontrol.envs.tracking.TrackingEnv.loop_state` of the environment,
    ``hidden_state()`` of each wrapper (:mod:`manualcontrol.agents.wrappers`, Hidden
    state), the wrappers' kinds in the order above.

    The motor noise's scaling by the stick's recent variance is left out: it changes
    over seconds, not within the critic's horizon. Tracking tasks only (the driving
    task's road is not a forcing signal).

    Parameters
    ----------
    env
        A compensatory, pursuit or preview tracking environment, possibly wrapped.
    horizon
        Seconds of forcing ahead, ``> 0`` (:func:`critic_horizon`).
    spacing
        Seconds between the forcing samples, ``> 0`` (:func:`forcing_spacing`).
    """

    def __init__(self, env: gym.Env, horizon: float, spacing: float) -> None:
        super().__init__(env)
        base = env.unwrapped
        if not isinstance(base, TrackingEnv):
            raise ValueError(
                f"critic information reads a tracking task's forcing: got {type(base).__name__}"
            )
        for name, value in (("horizon", horizon), ("spacing", spacing)):
            if not np.isfinite(value) or value <= 0.0:
                raise ValueError(f"{name} must be a positive number of seconds, got {value!r}")
        dt = float(base.dt)
        step = max(1, round(spacing / dt))
        self._stride = step
        self._offsets = np.arange(0, round(horizon / dt) + 1, step, dtype=np.int64)
        layers = _chain(env)
        # grouped by kind in this order, each kind outermost first: the order the
        # critic's inputs have had since its first trained agents
        self._hidden = [
            layer
            for kind in _HIDDEN_KINDS
            for layer in layers
            if isinstance(layer, kind) and layer.hidden_size > 0
        ]
        self.actor_inputs = int(np.prod(env.observation_space.shape))
        size = (
            2 * len(self._offsets)
            + base.element_order
            + 1
            + sum(layer.hidden_size for layer in self._hidden)
            + 1
        )
        space = env.observation_space
        self.observation_space = gym.spaces.Box(
            np.concatenate([np.ravel(space.low), np.full(size, -np.inf)]),
            np.concatenate([np.ravel(space.high), np.full(size, np.inf)]),
            dtype=space.dtype,
        )

    def _pad_forcing(self) -> None:
        # the episode's forcing with zeros past its end: each step then reads a strided
        # slice (the forcing samples exist only once the episode is reset)
        target, disturbance = self.env.unwrapped.forcing_samples()
        reach = int(self._offsets[-1]) + 1
        self._ahead = np.zeros((2, len(target) + reach))
        self._ahead[0, : len(target)] = target
        self._ahead[1, : len(disturbance)] = disturbance
        self._target_length = len(target)

    def _observe(self, observation: FloatArray) -> FloatArray:
        base = self.env.unwrapped
        k = base.sample_index
        loop = base.loop_state()
        out = np.empty(self.observation_space.shape[0])
        i = self.actor_inputs
        out[:i] = np.ravel(observation)
        n = len(self._offsets)
        window = slice(k, k + int(self._offsets[-1]) + 1, self._stride)
        out[i : i + n] = self._ahead[0, window]
        # the output is subtracted where there is a target: zero stays zero past the end
        inside = min(n, -(-(self._target_length - k) // self._stride))
        out[i : i + inside] -= loop.output
        out[i + n : i + 2 * n] = self._ahead[1, window]
        i += 2 * n
        order = len(loop.element_state)
        out[i : i + order] = loop.element_state
        out[i + order] = loop.error
        i += order + 1
        for layer in self._hidden:
            out[i : i + layer.hidden_size] = layer.hidden_state()
            i += layer.hidden_size
        out[i] = k / base.episode_steps
        return out

    def reset(self, **kwargs: Any) -> tuple[FloatArray, dict[str, Any]]:  # noqa: D102
        observation, info = self.env.reset(**kwargs)
        self._pad_forcing()
        return self._observe(observation), info

    def step(self, action: Any) -> tuple[FloatArray, float, bool, bool, dict[str, Any]]:  # noqa: D102
        observation, reward, terminated, truncated, info = self.env.step(action)
        return self._observe(observation), reward, terminated, truncated, info


class ActorInputs(FlattenExtractor):
    """Flattens the observation and zeroes all but its first ``actor_inputs`` numbers."""

    def __init__(self, observation_space: gym.spaces.Box, actor_inputs: int) -> None:
        super().__init__(observation_space)
        mask = torch.zeros(self.features_dim)
        mask[:actor_inputs] = 1.0
        self.register_buffer("mask", mask)

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        return super().forward(observations) * self.mask


class _WithLinearPath(nn.Module):
    """An MLP extractor whose actor latent also carries the actor's features themselves.

    ``forward_actor`` returns ``[mlp(features), features]``, so the action head (a linear
    layer on the latent) is a network plus a linear map of the observation.
    """

    def __init__(self, extractor: nn.Module, features_dim: int) -> None:
        super().__init__()
        self.extractor = extractor
        self.latent_dim_pi = extractor.latent_dim_pi + features_dim
        self.latent_dim_vf = extractor.latent_dim_vf

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.forward_actor(features), self.forward_critic(features)

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        return torch.cat((self.extractor.forward_actor(features), features), dim=-1)

    def forward_critic(self, features: torch.Tensor) -> torch.Tensor:
        return self.extractor.forward_critic(features)


class InformedCriticPolicy(ActorCriticPolicy):
    """PPO's actor-critic whose actor reads only the first ``actor_inputs`` numbers.

    The critic reads the whole observation (:class:`CriticInformation`); the actor's
    features extractor zeroes the rest, so the action depends on the operator's
    observation alone (its weights on the zeroes get no gradient).

    With ``linear_path=True`` the mean action is the network's plus a linear map of the
    actor's inputs (:class:`_WithLinearPath`; the action head reads both). A linear law,
    such as the typical pilot's equaliser a warm start begins from, is then the policy
    exactly, the network's part zero
    (:func:`~manualcontrol.agents.training.clone_typical_pilot`). Why: on a pure gain
    that law is a lag, ``c_k = a c_(k-1) + (1 - a) K_p e_k`` with ``a`` 0.997, whose step
    is 0.3 % of its command; where the limb's state follows the commands, a network fitted
    to the law errs by more than that step, and the cloned loop leaves the law's.
    """

    def __init__(
        self,
        observation_space: gym.spaces.Box,
        *args: Any,
        actor_inputs: int,
        linear_path: bool = False,
        **kwargs: Any,
    ) -> None:
        kwargs["share_features_extractor"] = False
        self.actor_inputs = actor_inputs
        self.linear_path = check_bool("linear_path", linear_path)
        super().__init__(observation_space, *args, **kwargs)
        self.pi_features_extractor = ActorInputs(observation_space, actor_inputs)
        self.features_extractor = self.pi_features_extractor

    def _build_mlp_extractor(self) -> None:
        super()._build_mlp_extractor()
        if self.linear_path:
            self.mlp_extractor = _WithLinearPath(self.mlp_extractor, self.features_dim)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(actor_inputs=self.actor_inputs, linear_path=self.linear_path)
        return data
