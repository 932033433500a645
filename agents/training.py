"""Training surrogate human operators with stable-baselines3 on the tasks of ``envs``.

:func:`train` runs PPO or SAC on any of the tracking environments or lane keeping, wrapped with
the human limitations of :mod:`~manualcontrol.agents.wrappers`, and writes to its
output folder:

``config.json``
    the full :class:`TrainingConfig` (everything needed to rebuild the agent);
``policy.pt``
    the policy weights (a plain tensor dictionary);
``model.zip``
    stable-baselines3's own save (optimiser state included), for resuming;
``checkpoints/``
    weights every ``checkpoint_every`` steps, when asked;
``selection.json``, ``policy_final.pt``
    with ``select_every``: each validation's step and score, the step whose weights
    ``policy.pt`` holds, and the final weights beside them.

The human's problem
-------------------
Besides the wrappers listed in ``wrappers`` (any of :data:`~manualcontrol.agents.wrappers.
WRAPPERS`, their parameters numbers or schedules), three fields pose the optimal control
model's problem directly, each off at its default: ``observation_noise_ratio`` (noise
on the display scaled to each signal's variance, the OCM's -20 dB is 0.01),
``effort_rate_weight`` (a cost on the stick's rate in the reward) and
``history_length`` (the last observations side by side, a memory a feed-forward
policy adapts with), and ``efference_copy`` gives the policy its own last command.
:attr:`TrainingConfig.limitations` lists the whole stack.

A typical pilot's start
-----------------------
``warm_start="typical-pilot"`` starts PPO from a policy whose mean action is the
typical precision pilot's equaliser on the element, ``u = K_p e + K_v e_dot``
(:func:`~manualcontrol.estimators.analysis.human_likeness.reference_pilot`; the
delay and neuromuscular system are the wrappers'; on a pure gain its lag, read through
the efference copy: :func:`typical_pilot_law`), fitted by least squares on the
states that law visits through the agent's own wrappers, and from a critic fitted to
that law's returns (:func:`clone_typical_pilot`). On the double integrator and
``1/(s(s+1))`` PPO from random weights finds no loop in millions of steps (a stick
that waits out a low-gain drift scores better early than one that learns the lead);
started from a human's loop, it keeps one and reshapes it.

An informed critic
------------------
``critic_information=True`` (PPO on a tracking task) gives the critic the loop's
hidden state besides the display: the forcing ahead, the element's state, the commands
in the delay, the noise filters' states (:mod:`~manualcontrol.agents.critic`, an
asymmetric actor-critic). The actor still reads only the display, so the trained
policy is an operator's. Without it the advantages that weigh PPO's updates are mostly
the forcing's future, which no display-only critic can predict; on the human's
problem, where the return is flat near its optimum, that noise outweighs the gradient
(``agents/recipes.py`` gives the figures).

Keeping the best weights
------------------------
PPO's policy does not improve monotonically: between two updates it can lose what it
did well in states it rarely visits (a lane-keeping agent whose weights after 1.3
million steps keep five evaluation roads of five keeps none with its weights after
two million; ``docs/surrogates.md``). ``select_every`` flies the policy's mean action
every so many steps on ``select_episodes`` validation episodes of the training
environment, seeded from ``select_seed`` up (:data:`VALIDATION_SEED` by default: seeds
no training run or evaluation starts from), and keeps the weights with the highest
mean undiscounted return, the quantity training maximises; the weights training starts
from (a warm start's typical pilot) and the final weights are validated too. This is
model selection on held-out episodes, early stopping's rule, and it changes nothing
about the training run itself: the same seed trains the same weights with or without
it. On a machine with more than one core the validations are flown in a second process
while training goes on (:mod:`~manualcontrol.agents._validation_worker`), with the
scores, and so the kept weights, the training process would have found.

Evaluation
----------
A trained agent acts with its policy's mean action: stable-baselines3's exploration
noise is a device of training, never a human's remnant. What varies from trial to
trial is the wrappers' noise (observation and motor noise), drawn per episode from the
environment's seed, so evaluating with different seeds gives different noise
realisations. This noise stays on by default; ``TrainingConfig.deterministic=True``
asks for noise-free evaluation runs (:func:`make_env` with ``noise=False``), the
policy's deterministic response alone.

Security: ``model.zip`` holds Python pickles; loading one runs code from whoever wrote
it. :func:`load_agent` therefore reads only ``config.json`` and ``policy.pt`` (with
``torch.load(weights_only=True)``) unless you pass ``trust_pickle=True`` for files you
made yourself.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import pickle
import subprocess
import sys
import time
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

import manualcontrol.envs  # noqa: F401  (registers the tracking ids)
from manualcontrol.agents.wrappers import NOISE_LEVELS, apply_wrappers, spec_to_json
from manualcontrol.envs._files import atomic_write
from manualcontrol.envs._validation import (
    check_bool,
    check_choice,
    check_int,
    check_positive,
    reject_unknown,
)
from manualcontrol.envs.schedules import Schedule

__all__ = [
    "ALGORITHMS",
    "PPO_DEFAULT_LEARNING_RATE",
    "TASK_IDS",
    "VALIDATION_SEED",
    "WARM_STARTS",
    "TrainedAgent",
    "TrainingConfig",
    "TypicalPilotAgent",
    "WarmStartWarning",
    "clone_typical_pilot",
    "load_agent",
    "make_env",
    "policy_spec",
    "train",
    "validation_score",
    "warm_start_warning",
]

FloatArray = NDArray[np.float64]

ALGORITHMS: tuple[str, ...] = ("ppo", "sac")
#: The first seed of the validation episodes (``select_every``): training resets its
#: environments from its own seed up, lane-keeping evaluation drives roads from 1000.
VALIDATION_SEED = 500_000
#: How a training's policy starts (:attr:`TrainingConfig.warm_start`).
WARM_STARTS: tuple[str, ...] = ("none", "typical-pilot")
#: Wrappers that change what the policy observes: a cloned law reads the display itself.
_OBSERVATION_WRAPPERS = ("observation_history", "observation_scale", "efference_copy")
TASK_IDS: dict[str, str] = {
    "compensatory": "ManualControl/CompensatoryTracking-v0",
    "pursuit": "ManualControl/PursuitTracking-v0",
    "preview": "ManualControl/PreviewTracking-v0",
    "lane-keeping": "ManualControl/LaneKeeping-v0",
}


@dataclass(frozen=True)
class TrainingConfig:
    """Everything that defines a training run; saved beside the trained agent.

    Parameters
    ----------
    task
        ``"compensatory"``, ``"pursuit"``, ``"preview"`` or ``"lane-keeping"``.
    env_kwargs
        Keywords of the environment (tracking: ``controlled_element``, ``forcing``,
        ``realisation``, ``measurement_time``, ...; lane keeping: ``road``, ``steering``,
        ``measurement_time``, ...).
    wrappers
        Human limitations, innermost first: ``({"kind": "action_delay", "delay": 0.2},)``;
        an argument may be a schedule (kept as its dict, ``{"kind": "ramp", ...}``).
    algorithm
        ``"ppo"`` or ``"sac"``.
    total_timesteps, n_envs, seed
        Training length (environment steps over all copies), parallel copies, seed.
    algorithm_kwargs, policy_kwargs
        Passed to the stable-baselines3 algorithm and its policy.
    checkpoint_every
        Save the weights every so many steps (None: no checkpoints).
    select_every, select_episodes
        Validate the policy every ``select_every`` steps on ``select_episodes``
        episodes and keep the best weights (the module docstring; None, default: keep
        the final weights).
    select_seed
        The validation episodes' first seed (:data:`VALIDATION_SEED`, default): they
        are reset with ``select_seed``, ``select_seed + 1``, ... Move it where other
        episodes from that seed up measure the kept agent, so that the weights are not
        chosen on the episodes that then judge them.
    observation_noise_ratio
        Observation noise on the display, as the OCM's noise-to-signal ratio ``rho`` of
        each observed signal (noise intensity ``pi rho`` times its variance;
        :class:`~manualcontrol.agents.wrappers.ObservationNoise`, innermost); 0
        (default): none; the OCM's -20 dB is 0.01. A number or a schedule.
    effort_rate_weight
        Weight of the stick-rate cost in the reward, s^2
        (:class:`~manualcontrol.agents.wrappers.EffortCost`); 0 (default): none. A
        number or a schedule.
    history_length
        Observations the policy sees side by side, ``history_length * dt`` seconds
        (:class:`~manualcontrol.agents.wrappers.ObservationHistory`, outermost but for
        the efference copy); 1 (default): the current one only.
    efference_copy
        The policy also reads its own last command
        (:class:`~manualcontrol.agents.wrappers.EfferenceCopy`, outermost, outside the
        history so that the commands still in the delay stay hidden): the memory a
        feed-forward policy needs to integrate, McRuer's lag equalisation on a pure
        gain. False (default): the display alone.
    deterministic
        Evaluate without the wrappers' noise (False, default: the noise stays on and
        makes the trial-to-trial variability; see the module docstring).
    critic_information
        PPO's critic also reads the tracking loop's hidden state (the forcing ahead,
        the element's state, the delayed commands, the noise's state; see
        :mod:`~manualcontrol.agents.critic`), the actor still only the display; False
        (default): both read the display. A device of training: it changes what the
        advantages weigh, not what the policy sees.
    warm_start
        ``"none"`` (default: the algorithm's random initial policy) or
        ``"typical-pilot"`` (:data:`WARM_STARTS`; the module docstring): compensatory
        tracking with ``include_rates=True`` of an element with a typical pilot, the
        observation ``(e, e_dot)`` as the display shows it (with ``history_length``,
        the law reads the newest frame and the policy starts from it with a memory).
        With a history, lower the learning rate: Adam's first steps move each input
        weight by about the learning rate, and the frames of a history, a sample
        apart, are nearly equal, so one step moves the action up to
        ``history_length`` times as far as from one frame (with the recipes' PPO, 20
        frames at its 3e-4 lost the typical pilot's loop in the first update; at
        1e-4 each update moved the policy as far as one frame's at 3e-4).

    Each limitation is given once: a field above that is on and a ``wrappers`` entry of
    the same kind raise. Schedules are saved in ``config.json`` as their dicts
    (:meth:`~manualcontrol.envs.schedules.Schedule.to_dict`); an older ``config.json``
    without these fields loads with them off, as it was trained.
    """

    task: str = "compensatory"
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)
    wrappers: tuple[Mapping[str, Any], ...] = ()
    algorithm: str = "sac"
    total_timesteps: int = 100_000
    n_envs: int = 1
    seed: int = 0
    algorithm_kwargs: Mapping[str, Any] = field(default_factory=dict)
    policy_kwargs: Mapping[str, Any] = field(default_factory=dict)
    checkpoint_every: int | None = None
    select_every: int | None = None
    select_episodes: int = 20
    select_seed: int = VALIDATION_SEED
    observation_noise_ratio: float | Schedule = 0.0
    effort_rate_weight: float | Schedule = 0.0
    history_length: int = 1
    efference_copy: bool = False
    deterministic: bool = False
    critic_information: bool = False
    warm_start: str = "none"

    def __post_init__(self) -> None:
        check_choice("task", self.task, tuple(TASK_IDS))
        check_choice("algorithm", self.algorithm, ALGORITHMS)
        check_int("total_timesteps", self.total_timesteps, minimum=1)
        check_int("n_envs", self.n_envs, minimum=1)
        check_int("seed", self.seed, minimum=0)
        if self.checkpoint_every is not None:
            check_int("checkpoint_every", self.checkpoint_every, minimum=1)
        if self.select_every is not None:
            check_int("select_every", self.select_every, minimum=1)
        check_int("select_episodes", self.select_episodes, minimum=1)
        check_int("select_seed", self.select_seed, minimum=0)
        object.__setattr__(
            self, "history_length", check_int("history_length", self.history_length, minimum=1)
        )
        object.__setattr__(
            self, "efference_copy", check_bool("efference_copy", self.efference_copy)
        )
        object.__setattr__(self, "deterministic", check_bool("deterministic", self.deterministic))
        object.__setattr__(
            self, "critic_information", check_bool("critic_information", self.critic_information)
        )
        if self.critic_information and self.algorithm != "ppo":
            raise ValueError(
                f"critic_information gives a state-value critic the loop's hidden state: "
                f"algorithm must be 'ppo', got {self.algorithm!r}"
            )
        if self.critic_information and self.task == "lane-keeping":
            raise ValueError(
                "critic_information reads a tracking task's forcing: task must be "
                "'compensatory', 'pursuit' or 'preview', got 'lane-keeping'"
            )
        for name in _SCHEDULED_FIELDS:
            object.__setattr__(self, name, _field_schedule(name, getattr(self, name)))
        for name in ("env_kwargs", "algorithm_kwargs", "policy_kwargs"):
            object.__setattr__(self, name, dict(getattr(self, name)))
        try:
            # the wrappers' specifications as config.json holds them (schedules as dicts)
            wrappers = json.loads(json.dumps([spec_to_json(spec) for spec in self.wrappers]))
            object.__setattr__(self, "wrappers", tuple(wrappers))
            self.to_dict()  # a JSON round trip
        except TypeError as error:
            raise TypeError(f"training configuration must be JSON-serialisable: {error}") from None
        for name, kind in _SCHEDULED_FIELDS.items():
            given = [spec for spec in self.wrappers if spec.get("kind") == kind]
            if given and _is_on(getattr(self, name)):
                raise ValueError(
                    f"{name} and a wrappers entry of kind {kind!r} ({given[0]}) both set "
                    f"{kind.replace('_', ' ')}: give it once"
                )
        if self.history_length > 1 and any(
            spec.get("kind") == "observation_history" for spec in self.wrappers
        ):
            raise ValueError(
                "history_length and a wrappers entry of kind 'observation_history' both set "
                "the observation history: give it once"
            )
        if self.efference_copy and any(
            spec.get("kind") == "efference_copy" for spec in self.wrappers
        ):
            raise ValueError(
                "efference_copy and a wrappers entry of kind 'efference_copy' both set "
                "the efference copy: give it once"
            )
        check_choice("warm_start", self.warm_start, WARM_STARTS)
        if self.warm_start == "typical-pilot":
            _check_typical_pilot_start(self)
        # fail now, not after hours: the environment and wrappers must build
        make_env(self).close()

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (lists, dicts, numbers, strings); schedules as their dicts."""
        data = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        data["wrappers"] = [spec_to_json(spec) for spec in self.wrappers]
        for name in _SCHEDULED_FIELDS:
            value = data[name]
            data[name] = value.to_dict() if isinstance(value, Schedule) else value
        return json.loads(json.dumps(data))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> TrainingConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise, missing ones take the defaults.

        A ``config.json`` written before a field existed lacks it; its default
        (a limitation off, evaluation with noise) is how that agent was trained.
        """
        reject_unknown("TrainingConfig", data, [f.name for f in dataclasses.fields(cls)])
        data = dict(data)
        data["wrappers"] = tuple(data.get("wrappers", ()))
        return cls(**data)

    @property
    def limitations(self) -> tuple[dict[str, Any], ...]:
        """Every wrapper :func:`make_env` applies, innermost first, as JSON-able specs.

        Observation noise (``observation_noise_ratio``) directly on the display, then
        ``wrappers``, then the effort cost, then the observation history (it stacks
        everything the agent sees), then the efference copy outermost (its last
        command alone, not stacked).
        """
        specs: list[dict[str, Any]] = []
        if _is_on(self.observation_noise_ratio):
            specs.append({"kind": "observation_noise", "ratio": self.observation_noise_ratio})
        specs += [dict(spec) for spec in self.wrappers]
        if _is_on(self.effort_rate_weight):
            specs.append({"kind": "effort_cost", "rate_weight": self.effort_rate_weight})
        if self.history_length > 1:
            specs.append({"kind": "observation_history", "length": self.history_length})
        if self.efference_copy:
            specs.append({"kind": "efference_copy"})
        return tuple(spec_to_json(spec) for spec in specs)

    def without_limitations(self) -> TrainingConfig:
        """The same task with no wrapper at all (for a reference pilot, say)."""
        return dataclasses.replace(
            self,
            wrappers=(),
            observation_noise_ratio=0.0,
            effort_rate_weight=0.0,
            history_length=1,
            efference_copy=False,
        )


#: The scheduled fields and the wrapper kind each one adds.
_SCHEDULED_FIELDS: dict[str, str] = {
    "observation_noise_ratio": "observation_noise",
    "effort_rate_weight": "effort_cost",
}


def _field_schedule(name: str, value: Any) -> float | Schedule:
    """A scheduled field as a float or a schedule (its dict read back), or a clear error."""
    if isinstance(value, Schedule):
        return value
    if isinstance(value, Mapping):
        try:
            return Schedule.from_dict(value)
        except (TypeError, ValueError) as error:
            raise type(error)(f"{name}: {error}") from None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"{name} must be a real number or a schedule, got {value!r}")
    return check_positive(name, value, allow_zero=True)


def _is_on(value: float | Schedule) -> bool:
    return isinstance(value, Schedule) or value != 0.0


def _silenced(spec: Mapping[str, Any]) -> dict[str, Any]:
    """A noise wrapper's specification with its noise level set to zero."""
    spec = dict(spec)
    levels = NOISE_LEVELS.get(spec.get("kind", ""), ())
    for name in [name for name in levels if spec.get(name) is not None] or levels[:1]:
        spec[name] = 0.0
    return spec


def _check_typical_pilot_start(config: TrainingConfig) -> None:
    """Raise unless the typical pilot's equaliser can be read off the observation."""
    from manualcontrol.estimators.analysis.human_likeness import reference_pilot

    where = "warm_start='typical-pilot'"
    if config.algorithm != "ppo":
        raise ValueError(
            f"{where} fits a Gaussian policy's mean (PPO's): algorithm must be 'ppo', got "
            f"{config.algorithm!r}"
        )
    if config.task != "compensatory":
        raise ValueError(
            f"{where} clones the precision pilot on the error display: task must be "
            f"'compensatory', got {config.task!r}"
        )
    if not config.env_kwargs.get("include_rates", False):
        raise ValueError(
            f"{where} reads e and e_dot from the observation: give env_kwargs include_rates=True"
        )
    kinds = [
        spec.get("kind") for spec in config.wrappers if spec.get("kind") in _OBSERVATION_WRAPPERS
    ]
    if kinds:
        # history_length stacks the frames outermost, newest first, so the law reads the
        # newest (e, e_dot) where one frame has them; a history or a scaling among the
        # wrappers can sit anywhere and change what those entries hold
        raise ValueError(
            f"{where} reads (e, e_dot) as the display shows them: no observation history, "
            f"scaling or efference copy among the wrappers (give history_length and "
            f"efference_copy instead), got wrappers {kinds}"
        )
    element = config.env_kwargs.get("controlled_element", "SI")
    values = reference_pilot(element)
    if values is None:
        raise ValueError(
            f"{where}: element {element!r} has no typical pilot (K, K/s, K/s^2 and K/(s(s+b)) have)"
        )
    if "T_I" in values and not config.efference_copy:
        raise ValueError(
            f"{where}: the typical pilot on element {element!r} lags its command "
            f"(T_I {values['T_I']:g} s), which a policy can only do reading its last "
            "command: give efference_copy=True"
        )


def typical_pilot_law(config: TrainingConfig) -> Callable[[FloatArray], FloatArray]:
    """The typical precision pilot's equaliser on ``(..., [e, e_dot])``, clipped to the stick.

    With ``history_length`` > 1 the observation is the frames newest first
    (:class:`~manualcontrol.agents.wrappers.ObservationHistory`): the law reads the newest.
    Where the typical pilot lags (``T_I``, a pure gain), the law is its equaliser
    ``(K_p + K_v s)/(T_I s + 1)`` stepped by its exact response over one sample to the
    error it sees now, ``c_k = a c_{k-1} + (1 - a)(K_p e_k + K_v e_dot_k)``,
    ``a = exp(-dt/T_I)`` (answering the newest error at once, as the gain does on the
    other elements), its last command ``c_{k-1}`` the efference copy, the actor's last
    input.
    """
    from manualcontrol.estimators.analysis.human_likeness import reference_pilot

    values = reference_pilot(config.env_kwargs.get("controlled_element", "SI"))
    env = make_env(config)
    bound = env.unwrapped.action_bound
    dt = float(env.unwrapped.dt)
    # the actor's inputs come first where the critic's follow them (CriticInformation)
    copy_at = getattr(env, "actor_inputs", int(np.prod(env.observation_space.shape))) - 1
    env.close()
    K_p, K_v = values["K_p"], values["K_v"]
    held = math.exp(-dt / values["T_I"]) if "T_I" in values else 0.0

    def law(observation: FloatArray) -> FloatArray:
        observation = np.asarray(observation, dtype=np.float64)
        action = K_p * observation[..., 0:1] + K_v * observation[..., 1:2]
        if held:
            last = observation[..., copy_at : copy_at + 1]
            action = held * last + (1.0 - held) * action
        return np.clip(action, -bound, bound)

    return law


class TypicalPilotAgent:
    """The typical pilot's equaliser acting as an agent: what a warm start begins from.

    Flown through the configuration's wrappers and evaluated as a trained agent is
    (:func:`~manualcontrol.agents.evaluation.evaluate`), it measures what the problem
    alone makes of the typical pilot's loop. ``reset``/``act`` as :class:`TrainedAgent`.
    """

    path: Path | None = None

    def __init__(self, config: TrainingConfig) -> None:
        self.config = config
        self._law = typical_pilot_law(config)

    def reset(self, seed: int | None = None, *, env: gym.Env | None = None) -> None:
        """Nothing to reset: the law reads all it needs from the observation."""
        del seed, env

    def act(self, observation: FloatArray) -> FloatArray:
        """The law's action for one observation, shape ``(1,)``."""
        return self._law(np.asarray(observation, dtype=np.float64)).reshape(1)


def clone_typical_pilot(
    policy: Any, config: TrainingConfig, *, episodes: int = 20, iterations: int = 3000
) -> dict[str, float]:
    """Fit ``policy`` to the typical pilot's equaliser and its critic to the law's returns.

    The states are those the law visits through the configuration's own wrappers (its
    observation noise, delay, neuromuscular system and motor noise), ``episodes``
    episodes seeded from ``config.seed``. The fit is ``iterations`` Adam steps of 256
    states on the squared difference of the policy's mean and the law's action (the
    exploration's spread is left as the policy has it) plus the squared difference of
    the value estimate and the law's discounted return from the state (the algorithm's
    ``gamma``), divided by the returns' variance so that both terms weigh alike. The
    critic is fitted because PPO's first updates weigh the actions by advantages from
    it: a random critic's advantages are noise, and its first updates undo the start.
    States within five horizons ``1/(1 - gamma)`` of an episode's truncation are left
    out of the value fit (their returns are cut short). A policy with a linear path
    (:class:`~manualcontrol.agents.critic.InformedCriticPolicy` ``linear_path``) takes
    the law exactly instead, its network's part zero, and only its critic is fitted.
    Returns the states used, the law's RMS action on them and the fit's RMS residual.
    """
    import torch

    gamma = _discount(config)
    tail = math.ceil(5.0 / (1.0 - gamma))
    law = typical_pilot_law(config)
    env = make_env(config)
    observations: list[FloatArray] = []
    returns: list[FloatArray] = []
    valued: list[NDArray[np.bool_]] = []
    try:
        for episode in range(episodes):
            observation, _ = env.reset(seed=10_000 * config.seed + episode)
            rewards, done, terminated = [], False, False
            while not done:
                observations.append(np.asarray(observation, dtype=np.float64))
                observation, reward, terminated, truncated, _ = env.step(law(observation))
                rewards.append(float(reward))
                done = terminated or truncated
            discounted = np.zeros(len(rewards))
            following = 0.0
            for k in range(len(rewards) - 1, -1, -1):
                following = rewards[k] + gamma * following
                discounted[k] = following
            exact = np.ones(len(rewards), dtype=np.bool_)
            if not terminated:
                exact[max(0, len(rewards) - tail) :] = False
            returns.append(discounted)
            valued.append(exact)
    finally:
        env.close()
    value_at = np.flatnonzero(np.concatenate(valued))
    if len(value_at) == 0:
        raise ValueError(
            f"warm_start='typical-pilot' fits the critic on returns the episode does not cut "
            f"short: episodes must last over {tail} steps (5 horizons 1/(1 - gamma) at "
            f"gamma {gamma:g}), the longest here lasted {max(map(len, valued))}"
        )
    states = np.array(observations)
    targets = law(states)
    x = torch.as_tensor(states, dtype=torch.float32)
    y = torch.as_tensor(targets, dtype=torch.float32)
    value_target = torch.as_tensor(np.concatenate(returns), dtype=torch.float32)
    value_scale = float(np.var(np.concatenate(returns)[value_at])) or 1.0
    # the returns' level in the value head's bias first: Adam's steps of 1e-3 would take
    # tens of thousands of iterations to climb to it
    with torch.no_grad():
        policy.value_net.bias.fill_(float(np.mean(np.concatenate(returns)[value_at])))
    rng = np.random.default_rng(config.seed)
    linear = getattr(policy, "linear_path", False)
    if linear:  # the law is the policy's linear path, the network's part zero
        _set_linear_law(policy, law, states.shape[1])
        parameters = [*policy.mlp_extractor.extractor.value_net.parameters()]
        parameters += [*policy.value_net.parameters()]
    else:
        parameters = list(policy.parameters())
    optimiser = torch.optim.Adam(parameters, lr=1e-3)
    for _ in range(iterations):
        batch = torch.as_tensor(rng.integers(0, len(states), 256))
        if linear:
            actor_loss = torch.zeros(())
        else:
            mean = policy.get_distribution(x[batch]).distribution.mean
            actor_loss = torch.mean((mean - y[batch]) ** 2)
        at = torch.as_tensor(rng.choice(value_at, 256))
        value = policy.predict_values(x[at]).squeeze(-1)
        critic_loss = torch.mean((value - value_target[at]) ** 2) / value_scale
        loss = actor_loss + critic_loss
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    with torch.no_grad():
        residual = policy.get_distribution(x).distribution.mean - y
        at = torch.as_tensor(value_at)
        value_residual = policy.predict_values(x[at]).squeeze(-1) - value_target[at]
    return {
        "states": float(len(states)),
        "law_rms": float(np.sqrt(np.mean(targets**2))),
        "residual_rms": float(torch.sqrt(torch.mean(residual**2))),
        "value_explained": float(1.0 - torch.mean(value_residual**2) / value_scale),
    }


def _set_linear_law(
    policy: Any, law: Callable[[FloatArray], FloatArray], observation_size: int
) -> None:
    """Make ``policy``'s mean action the linear ``law``: its linear path, the network's zero.

    The law's coefficient on each observed number is its action for that number alone
    (a small one, so that the stick's clip stays out of it); the law has no constant.
    """
    import torch

    step = 1e-3
    probes = step * np.eye(observation_size)
    coefficients = np.asarray(law(probes), dtype=np.float64).reshape(observation_size, -1).T / step
    head = policy.action_net
    network = policy.mlp_extractor.extractor.latent_dim_pi
    with torch.no_grad():
        head.weight.zero_()
        head.bias.zero_()
        head.weight[:, network : network + observation_size] = torch.as_tensor(
            coefficients, dtype=head.weight.dtype
        )


def make_env(config: TrainingConfig, *, noise: bool = True, **overrides: Any) -> gym.Env:
    """The environment of a configuration, wrapped with all its limitations.

    The wrappers are :attr:`TrainingConfig.limitations`; ``overrides`` update
    ``env_kwargs``. ``noise=False`` sets every noise wrapper's level to zero: the noise-free runs of
    ``deterministic`` evaluation (the wrappers stay, so the observation is the same).
    With ``critic_information``, :class:`~manualcontrol.agents.critic.CriticInformation`
    comes outermost: the agent's observation first, the critic's after it.
    """
    env = gym.make(TASK_IDS[config.task], **{**config.env_kwargs, **overrides})
    specs = config.limitations
    if not noise:
        specs = tuple(_silenced(spec) for spec in specs)
    try:
        env = apply_wrappers(env, specs)
        if config.critic_information:
            from manualcontrol.agents.critic import (
                CriticInformation,
                critic_horizon,
                forcing_spacing,
            )

            horizon = critic_horizon(_discount(config), float(env.unwrapped.dt))
            env = CriticInformation(env, horizon=horizon, spacing=forcing_spacing(env))
        return env
    except Exception:
        env.close()
        raise


class _NoStepInfo(gym.Wrapper):
    """Passes on no step ``info``: the training's environments, whose infos nothing reads.

    stable-baselines3's vector env deep-copies every environment's info at every step,
    and a tracking environment's (its signals, the element's parameters, each wrapper's
    figures) cost about a tenth of a rollout's time to copy. The algorithm reads only
    what is added outside this wrapper (the ``Monitor``'s episode return, the vector
    env's terminal observation and truncation flag), so the training is the same, bit
    for bit. Evaluation and validation build their own environments, with the info.
    """

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, _ = self.env.step(action)
        return observation, reward, terminated, truncated, {}


def _discount(config: TrainingConfig) -> float:
    """The algorithm's ``gamma``: the configuration's, or stable-baselines3's default 0.99."""
    return float(config.algorithm_kwargs.get("gamma", 0.99))


def policy_spec(config: TrainingConfig, env: Any) -> tuple[Any, dict[str, Any]]:
    """The stable-baselines3 policy and its keywords for a configuration on ``env``.

    ``"MlpPolicy"`` and ``policy_kwargs``; with ``critic_information``,
    :class:`~manualcontrol.agents.critic.InformedCriticPolicy` told how many of the
    observation's numbers are the agent's (``env`` a wrapped env or a vector env).
    """
    kwargs = dict(config.policy_kwargs)
    if not config.critic_information:
        return "MlpPolicy", kwargs
    from manualcontrol.agents.critic import InformedCriticPolicy

    if isinstance(env, gym.Env):
        actor_inputs = env.get_wrapper_attr("actor_inputs")
    else:  # a stable-baselines3 vector env
        actor_inputs = env.get_attr("actor_inputs", [0])[0]
    return InformedCriticPolicy, {**kwargs, "actor_inputs": int(actor_inputs)}


def _algorithm_options(algorithm: str) -> list[str]:
    """The keyword options the algorithm's constructor takes from a user.

    Its public keywords, less those the training sets itself (the policy, the env, the
    seed, verbosity, the policy's keywords) and the private ones (``_init_setup_model``).
    """
    import inspect

    return [
        name
        for name in inspect.signature(_algorithm_class(algorithm)).parameters
        if not name.startswith("_")
        and name not in ("policy", "env", "self", "seed", "verbose", "policy_kwargs")
    ]


def _algorithm_class(name: str) -> type:
    from stable_baselines3 import PPO, SAC

    return {"ppo": PPO, "sac": SAC}[name]


@dataclass
class TrainedAgent:
    """A trained policy with its configuration; acts like a cybernetic pilot.

    ``reset(seed, env=env)`` / ``act(observation)`` mirror
    :class:`~manualcontrol.pilots.Pilot`, so evaluation drives both the same way.
    The policy always acts with its mean action; the variability of a human operator
    comes from the wrappers' noise (see the module docstring).
    """

    config: TrainingConfig
    policy: Any
    path: Path | None = None

    def reset(self, seed: int | None = None, *, env: gym.Env | None = None) -> None:
        """Nothing to reset: the policy is a memoryless map (the wrappers hold the state)."""
        del seed, env

    def act(self, observation: FloatArray) -> FloatArray:
        """The policy's mean action for one observation, shape ``(1,)``: :func:`_mean_action`."""
        return _mean_action(self.policy, observation)


def _mean_action(policy: Any, observation: FloatArray) -> FloatArray:
    """``policy.predict(observation, deterministic=True)`` for one observation, as float64.

    The same numbers, bit for bit (tested), by the same torch operations in the same
    order, at a fraction of the cost: an evaluation calls it at every sample, and
    ``predict`` spends most of a small network's call on what one observation does not
    need: switching every module to evaluation mode again, checking and reshaping the
    input, and building the action distribution only to read its mean. Here the mode
    is switched only when the policy is training, and PPO's Gaussian policy (the
    distribution's mean is its ``action_net`` output, as ``get_distribution`` computes
    it) skips the distribution; any other policy goes through its own ``_predict``, and
    one whose observation is not a single array (a dict, or an image ``predict`` may
    transpose), whose action space is not a box, or which overrides ``predict`` goes
    through ``predict`` itself. Then the action is clipped to the action space (or
    unscaled, for a squashing policy) as ``predict`` does. Where the mean is not a
    number, ``predict`` raises (the distribution checks it) and this returns NaN, which
    the environments refuse as an action.
    """
    import torch
    from stable_baselines3.common.distributions import DiagGaussianDistribution
    from stable_baselines3.common.policies import ActorCriticPolicy, BasePolicy
    from stable_baselines3.common.preprocessing import is_image_space

    kind = type(policy)
    if (
        not isinstance(policy.observation_space, gym.spaces.Box)  # no one-shaped tensor
        or is_image_space(policy.observation_space)  # predict may transpose it
        or not isinstance(policy.action_space, gym.spaces.Box)
        or kind.predict is not BasePolicy.predict
    ):
        action, _ = policy.predict(observation, deterministic=True)
        return np.asarray(action, dtype=np.float64).reshape(1)
    if policy.training:
        policy.set_training_mode(False)
    shape = (1, *policy.observation_space.shape)
    values = np.array(observation, dtype=np.float32).reshape(shape)  # a writable copy
    tensor = torch.as_tensor(values, device=policy.device)
    with torch.no_grad():
        if (
            isinstance(policy, ActorCriticPolicy)
            and type(policy.action_dist) is DiagGaussianDistribution
            and all(
                getattr(kind, name) is getattr(ActorCriticPolicy, name)
                for name in ("_predict", "get_distribution", "_get_action_dist_from_latent")
            )
        ):
            # ActorCriticPolicy.get_distribution's features and latent, then the mean
            features = super(ActorCriticPolicy, policy).extract_features(
                tensor, policy.pi_features_extractor
            )
            mean = policy.action_net(policy.mlp_extractor.forward_actor(features))
        else:
            mean = policy._predict(tensor, deterministic=True)
    action = mean.cpu().numpy().reshape((-1, *policy.action_space.shape))
    if policy.squash_output:
        action = policy.unscale_action(action)
    else:
        action = np.clip(action, policy.action_space.low, policy.action_space.high)
    return np.asarray(action, dtype=np.float64).reshape(1)


def _progress_callback(total: int, report: Callable[[str], None], every: int) -> Any:
    from stable_baselines3.common.callbacks import BaseCallback

    class Progress(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.started = time.perf_counter()
            self.next_report = every

        def _on_step(self) -> bool:
            if self.num_timesteps >= self.next_report:
                while self.next_report <= self.num_timesteps:
                    self.next_report += every
                episodes = [info["r"] / info["l"] for info in self.model.ep_info_buffer]
                mean = f"{np.mean(episodes):.4f}" if episodes else "n/a"
                elapsed = time.perf_counter() - self.started
                rate = self.num_timesteps / elapsed
                report(
                    f"{self.num_timesteps:>9,d}/{total:,d} steps  {rate:7.0f} steps/s  "
                    f"mean reward per step {mean}"
                )
            return True

    return Progress()


def _checkpoint_callback(every: int, folder: Path) -> Any:
    import torch
    from stable_baselines3.common.callbacks import BaseCallback

    class Checkpoint(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps % every < self.training_env.num_envs:
                path = folder / f"policy_{self.num_timesteps}.pt"
                atomic_write(path, lambda p: torch.save(self.model.policy.state_dict(), p))
            return True

    return Checkpoint()


def validation_score(policy: Any, config: TrainingConfig, episodes: int) -> float:
    """Mean undiscounted return of ``policy``'s mean action on validation episodes.

    ``episodes`` episodes of :func:`make_env` (the wrappers' noise on unless
    ``config.deterministic``), reset with seeds ``config.select_seed`` (by default
    :data:`VALIDATION_SEED`), ``config.select_seed + 1``, ...; all flown side by side,
    one policy call a step for every episode still running. An episode that terminates
    early (a lane departure, loss of control) keeps the return it had: with a positive
    reward, what it lost.
    """
    check_int("episodes", episodes, minimum=1)
    envs = [make_env(config, noise=not config.deterministic) for _ in range(episodes)]
    try:
        observations = [env.reset(seed=config.select_seed + i)[0] for i, env in enumerate(envs)]
        returns = np.zeros(episodes)
        running = list(range(episodes))
        while running:
            batch = np.asarray([observations[i] for i in running], dtype=np.float32)
            actions, _ = policy.predict(batch, deterministic=True)
            still = []
            for i, action in zip(running, actions, strict=True):
                observations[i], reward, terminated, truncated, _ = envs[i].step(action)
                returns[i] += float(reward)
                if not (terminated or truncated):
                    still.append(i)
            running = still
    finally:
        for env in envs:
            env.close()
    return float(np.mean(returns))


class _ValidationWorkerError(RuntimeError):
    """The validation worker stopped or could not fly a validation."""


class _BackgroundValidation:
    """The validation worker (:mod:`~manualcontrol.agents._validation_worker`) of one training.

    :meth:`submit` hands it a policy's weights and returns at once; :meth:`scores` ends
    the worker and returns each submission's score, in order, or raises
    :class:`_ValidationWorkerError` saying why it cannot.
    """

    #: How the worker is started (a test starts another command in its place).
    command: tuple[str, ...] = (sys.executable, "-m", "manualcontrol.agents._validation_worker")

    def __init__(self, config: TrainingConfig) -> None:
        self._config = config.to_dict()
        self._submitted = 0
        self._failure: str | None = None
        self._process = subprocess.Popen(
            list(self.command), stdin=subprocess.PIPE, stdout=subprocess.PIPE
        )

    def submit(self, state: Mapping[str, Any], episodes: int) -> None:
        self._submitted += 1
        if self._failure is not None:
            return  # judged in the training process once training ends
        weights = {name: value.detach().cpu().numpy().copy() for name, value in state.items()}
        try:
            pickle.dump((self._config, weights, episodes), self._process.stdin)
            self._process.stdin.flush()
        except OSError:
            self._failure = self._stopped(f"while validation {self._submitted} was handed over")

    def scores(self) -> list[float]:
        if self._failure is None:
            with contextlib.suppress(OSError):  # a worker gone: reading says how far it got
                pickle.dump(None, self._process.stdin)
                self._process.stdin.close()
        scores: list[float] = []
        while self._failure is None and len(scores) < self._submitted:
            try:
                kind, value = pickle.load(self._process.stdout)
            except (EOFError, OSError, pickle.UnpicklingError):
                self._failure = self._stopped(f"after {len(scores)} of {self._submitted} scores")
                break
            if kind == "error":
                self._failure = f"validation {len(scores) + 1} failed there: {value}"
                break
            scores.append(value)
        if self._failure is not None:
            raise _ValidationWorkerError(self._failure)
        self._process.wait()
        return scores

    def _stopped(self, when: str) -> str:
        try:
            code = self._process.wait(timeout=10)
        except subprocess.TimeoutExpired:  # alive but not answering as it should
            self._process.kill()
            code = self._process.wait()
        how = f"killed by signal {-code}" if code < 0 else f"exit code {code}"
        return f"the validation process stopped ({how}) {when}; its own error, if any, is above"

    def close(self) -> None:
        if self._process.poll() is None:
            self._process.kill()
            self._process.wait()
        for stream in (self._process.stdin, self._process.stdout):
            # a pipe to a worker that is gone cannot take the bytes still buffered for it
            with contextlib.suppress(OSError):
                stream.close()


def _validate_in_background(asked: bool | None) -> bool:
    if asked is not None:
        return check_bool("validate_in_background", asked)
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return cores > 1


def _selection_callback(config: TrainingConfig, background: _BackgroundValidation | None) -> Any:
    import copy

    from stable_baselines3.common.callbacks import BaseCallback

    every = config.select_every

    class Selection(BaseCallback):
        """Validates the policy every ``every`` steps and keeps the best weights.

        With ``background``, each validation's weights go to the worker and are judged
        when :meth:`finish` reads the scores; without, they are flown here and then.
        """

        def __init__(self) -> None:
            super().__init__()
            self.history: list[dict[str, Any]] = []
            self.best_state: dict[str, Any] | None = None
            self.best_score = -math.inf
            self.best_step = 0
            self._pending: list[tuple[int, bool, dict[str, Any]]] = []

        def validate(self, final: bool = False) -> None:
            step = int(self.num_timesteps)
            if background is None:
                score = validation_score(self.model.policy, config, config.select_episodes)
                self._judge(step, final, score, copy.deepcopy(self.model.policy.state_dict()))
                return
            state = copy.deepcopy(self.model.policy.state_dict())
            background.submit(state, config.select_episodes)
            self._pending.append((step, final, state))

        def finish(self) -> None:
            """Judge the validations still with the worker, in the order they were made.

            Where the worker failed, every validation's weights are flown here, as they
            would have been without it: the same scores, later.
            """
            if background is None:
                return
            try:
                scores = background.scores()
            except _ValidationWorkerError as error:
                warnings.warn(
                    f"{error}: the {len(self._pending)} validations are flown in the "
                    "training process instead",
                    RuntimeWarning,
                    stacklevel=2,
                )
                final_state = copy.deepcopy(self.model.policy.state_dict())
                scores = []
                for _, _, state in self._pending:
                    self.model.policy.load_state_dict(state)
                    scores.append(
                        validation_score(self.model.policy, config, config.select_episodes)
                    )
                self.model.policy.load_state_dict(final_state)
            for (step, final, state), score in zip(self._pending, scores, strict=True):
                self._judge(step, final, score, state)
            self._pending = []

        def _judge(self, step: int, final: bool, score: float, state: Mapping[str, Any]) -> None:
            # ``state`` is a copy of the weights validated, kept as it is if they win
            self.history.append({"step": step, "score": score, "final": final})
            # ties go to the later, longer-trained weights
            if score >= self.best_score:
                self.best_score, self.best_step = score, step
                self.best_state = state

        def _on_training_start(self) -> None:
            # the weights training starts from compete too: a warm start's (the typical
            # pilot's equaliser) can validate above every update's
            self.validate()

        def _on_step(self) -> bool:
            if self.num_timesteps % every < self.training_env.num_envs:
                self.validate()
            return True

        def summary(self) -> dict[str, Any]:
            return {
                "select_every": every,
                "select_episodes": config.select_episodes,
                "validation_seed": config.select_seed,
                "kept_step": self.best_step,
                "kept_score": self.best_score,
                "history": self.history,
            }

    return Selection()


class WarmStartWarning(UserWarning):
    """A warm start configured so that its first updates are likely to lose it."""


#: stable-baselines3's PPO learning rate, where none is given.
PPO_DEFAULT_LEARNING_RATE = 3e-4


def warm_start_warning(config: TrainingConfig) -> str | None:
    """Why ``config``'s warm start is likely lost in its first update, or None.

    A typical pilot's start with a history at PPO's default learning rate (or above):
    Adam's first steps move each input weight by about the learning rate, and the
    history's frames, a sample apart, are nearly equal, so one update moves the action
    up to ``history_length`` times as far as from one frame (the recipes' 20 frames at
    3e-4 lost the typical pilot's loop in the first update: ``history_length``).
    """
    if config.warm_start != "typical-pilot" or config.history_length == 1:
        return None
    rate = config.algorithm_kwargs.get("learning_rate", PPO_DEFAULT_LEARNING_RATE)
    if not isinstance(rate, (int, float)) or rate < PPO_DEFAULT_LEARNING_RATE:
        return None  # a schedule is the user's own design
    return (
        f"warm_start='typical-pilot' with history_length={config.history_length} at a "
        f"learning rate of {rate:g}: the frames move Adam's first steps together, and "
        f"the first update can lose the typical pilot's loop; give algorithm_kwargs "
        f"learning_rate below {PPO_DEFAULT_LEARNING_RATE:g} (the tracking recipes train "
        f"20 frames at 1e-4)"
    )


def train(
    config: TrainingConfig,
    output: str | Path,
    *,
    report: Callable[[str], None] | None = print,
    report_every: int = 10_000,
    validate_in_background: bool | None = None,
) -> TrainedAgent:
    """Train an agent and save it (see the module docstring) in ``output``.

    Torch computes on one thread while it trains (its thread count is restored after):
    a sum split over threads depends on how many there are, so without this the same
    seed trains different weights on machines with different numbers of cores; and the
    small networks of these agents gain nothing from more threads.

    ``validate_in_background`` (with ``select_every``, a model on the CPU): fly the
    validations in a second process while training goes on
    (:mod:`~manualcontrol.agents._validation_worker`), with the same scores and so the
    same kept weights; where the worker fails, the training process flies what it did
    not score (a :class:`RuntimeWarning` says why). None (default): where this process
    may run on more than one CPU; pass False where the other cores are busy already
    (one training per core).
    """
    import torch

    in_background = _validate_in_background(validate_in_background)
    background = config.select_every is not None and in_background
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _train(
            config, output, report=report, report_every=report_every, background=background
        )
    finally:
        torch.set_num_threads(threads)


def _train(
    config: TrainingConfig,
    output: Path | str,
    *,
    report: Callable[[str], None] | None,
    report_every: int,
    background: bool,
) -> TrainedAgent:
    import torch
    from stable_baselines3.common.callbacks import CallbackList
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.logger import Logger

    output = Path(output)
    warning = warm_start_warning(config)
    if warning is not None:
        warnings.warn(warning, WarmStartWarning, stacklevel=3)
    accepted = _algorithm_options(config.algorithm)
    unknown = sorted(set(config.algorithm_kwargs) - set(accepted))
    if unknown:
        raise ValueError(
            f"algorithm_kwargs: {config.algorithm.upper()} takes no option "
            f"{', '.join(map(repr, unknown))}; its options: {', '.join(accepted)}"
        )
    vec_env = make_vec_env(
        lambda: _NoStepInfo(make_env(config)), n_envs=config.n_envs, seed=config.seed
    )
    try:
        policy, policy_kwargs = policy_spec(config, vec_env)
        model = _algorithm_class(config.algorithm)(
            policy,
            vec_env,
            seed=config.seed,
            verbose=0,
            policy_kwargs=policy_kwargs,
            **dict(config.algorithm_kwargs),
        )
    except TypeError as error:
        vec_env.close()
        raise ValueError(
            f"algorithm_kwargs {dict(config.algorithm_kwargs)!r} or policy_kwargs "
            f"{dict(config.policy_kwargs)!r} not accepted by {config.algorithm.upper()}: "
            f"{error}"
        ) from error
    # the folder is written only once the algorithm has accepted the configuration
    output.mkdir(parents=True, exist_ok=True)
    atomic_write(
        output / "config.json", lambda p: p.write_text(json.dumps(config.to_dict(), indent=2))
    )
    if config.warm_start == "typical-pilot":
        fit = clone_typical_pilot(model.policy, config)
        if report is not None:
            report(
                f"warm start: the typical pilot's equaliser fitted on {fit['states']:,.0f} "
                f"states, residual RMS {fit['residual_rms']:.3g} of the law's "
                f"{fit['law_rms']:.3g}; the critic explains {fit['value_explained']:.0%} of "
                "the law's returns"
            )
    # stable-baselines3's default logger makes an empty folder in the system's temporary
    # directory at every learn(); this one writes nowhere (progress goes to ``report``)
    model.set_logger(Logger(folder=None, output_formats=[]))
    callbacks = []
    if report is not None:
        callbacks.append(_progress_callback(config.total_timesteps, report, report_every))
    if config.checkpoint_every is not None:
        folder = output / "checkpoints"
        folder.mkdir(exist_ok=True)
        callbacks.append(_checkpoint_callback(config.checkpoint_every, folder))
    selection = validations = None
    try:
        if config.select_every is not None:
            # a worker flies on the CPU: a model on another device validates here, where
            # its scores are computed on the device it trains on
            on_cpu = model.device.type == "cpu"
            validations = _BackgroundValidation(config) if background and on_cpu else None
            selection = _selection_callback(config, validations)
            callbacks.append(selection)
        model.learn(total_timesteps=config.total_timesteps, callback=CallbackList(callbacks))
        if selection is not None:
            final_state = {key: value.clone() for key, value in model.policy.state_dict().items()}
            atomic_write(output / "policy_final.pt", lambda p: torch.save(final_state, p))
            # the final weights compete too: they follow the last update, after every
            # validation that ran during training
            selection.num_timesteps = model.num_timesteps
            selection.validate(final=True)
            selection.finish()
    finally:
        if validations is not None:
            validations.close()
    if selection is not None:
        model.policy.load_state_dict(selection.best_state)
        summary = selection.summary()
        atomic_write(
            output / "selection.json", lambda p: p.write_text(json.dumps(summary, indent=2))
        )
        if report is not None:
            report(
                f"kept the weights of step {summary['kept_step']:,d}: mean validation return "
                f"{summary['kept_score']:.1f} over {config.select_episodes} episodes "
                f"(final weights {summary['history'][-1]['score']:.1f})"
            )
    atomic_write(output / "policy.pt", lambda p: torch.save(model.policy.state_dict(), p))
    atomic_write(output / "model.zip", lambda p: model.save(p))
    vec_env.close()
    return TrainedAgent(config, model.policy, output)


def load_agent(path: str | Path, *, trust_pickle: bool = False) -> TrainedAgent:
    """Load a trained agent from its folder.

    By default only ``config.json`` and the weights ``policy.pt`` are read (no pickle:
    ``torch.load(weights_only=True)``); the policy is rebuilt from the configuration.
    ``trust_pickle=True`` loads stable-baselines3's ``model.zip`` instead, which runs
    pickled code: only for files you trust.
    """
    import torch

    folder = Path(path)
    config_path = folder / "config.json"
    if not config_path.is_file():
        raise FileNotFoundError(f"{folder} has no config.json: not a trained agent folder")
    config = TrainingConfig.from_dict(json.loads(config_path.read_text()))
    algorithm = _algorithm_class(config.algorithm)
    if trust_pickle:
        model = algorithm.load(folder / "model.zip", device="cpu")
        return TrainedAgent(config, model.policy, folder)
    weights = folder / "policy.pt"
    if not weights.is_file():
        raise FileNotFoundError(f"{folder} has no policy.pt weights")
    policy = _rebuilt_policy(config)
    try:
        state = torch.load(weights, weights_only=True, map_location="cpu")
        policy.load_state_dict(state)
    except Exception as error:  # a truncated, corrupt or foreign file: torch says how
        raise ValueError(
            f"{weights} is not the weights of this agent's policy (corrupt, truncated, or "
            f"from another network: {type(error).__name__}: {error}); retrain it or "
            "restore the file"
        ) from None
    return TrainedAgent(config, policy, folder)


def _rebuilt_policy(config: TrainingConfig) -> Any:
    """A fresh policy of ``config``'s network, on the CPU, for weights to be loaded into."""
    algorithm = _algorithm_class(config.algorithm)
    env = make_env(config)
    try:
        # only the policy is needed: no replay memory for an off-policy algorithm
        extra = {"buffer_size": 1} if config.algorithm == "sac" else {}
        # state-dependent exploration changes the shape of the policy's log_std
        if "use_sde" in config.algorithm_kwargs:
            extra["use_sde"] = config.algorithm_kwargs["use_sde"]
        policy, policy_kwargs = policy_spec(config, env)
        policy_kwargs = {**policy_kwargs, "optimizer_class": _NoOptimizer}
        return algorithm(policy, env, policy_kwargs=policy_kwargs, device="cpu", **extra).policy
    finally:
        env.close()


class _NoOptimizer:
    """The optimizer of a policy rebuilt to act: it is never stepped, so it holds nothing.

    Why not the configured one: every torch optimizer imports torch's compiler stack
    (``torch._dynamo``) when it is built, a large part of loading a PPO agent, and a
    policy that only acts never uses it. Loading touches only the policy's weights
    (``state_dict`` holds no optimizer state), so the numbers are the same. (SAC still
    builds the optimizer of its entropy coefficient, outside the policy.)
    """

    def __init__(self, parameters: Any, **options: Any) -> None:
        del parameters, options
