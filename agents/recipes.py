"""Training recipes: surrogate operators that train in minutes on two cores.

A recipe is a :class:`~manualcontrol.agents.training.TrainingConfig` for one task that
this project has trained and measured (``benchmarks/train_recipes.py`` trains every
recipe with several seeds and measures each agent's human-likeness; the figures are in
``docs/surrogates.md``). ``manualcontrol train --recipe NAME`` and :func:`recipe` give
it; ``seed`` and ``total_timesteps`` may be changed, everything else is the recipe.

Tracking recipes (``"si"``: ``1/s``, ``"di"``: ``1/s^2``, ``"lag"``: ``1/(s(s+1))``)
give the agent the human's problem as the optimal control model poses it:

* a perceptual delay of 0.2 s whose queue the agent cannot see (it must act through
  it as a human does, not read its own pending commands);
* the neuromuscular system of the precision model (``omega_nms`` 12 rad/s,
  ``zeta_nms`` 0.5) between command and stick;
* motor noise (Levison-filtered, a share of the stick's power): the remnant, drawn by
  the wrapper, so it stays on in evaluation and varies from trial to trial;
* an effort cost on the stick's rate: without it the optimum is a high-gain loop at
  the edge of stability (crossover 9 rad/s, 3 deg of phase margin), with it the
  trade-off between error and effort that makes humans cross over at a few rad/s;
* the bounded reward with loss-of-control termination (a positive reward, so ending
  an episode never pays while the policy is poor), random forcing realisations of 30 s.

PPO with eight environments and a 64-64 network. Lane-keeping recipes steer by angle or
torque, with the action bound and reward scale set to the task's size (a wheel angle
of tenths of a radian, an offset of a decimetre) and a discount whose horizon (a few
seconds at 100 Hz) covers the road ahead.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from manualcontrol.agents.training import TrainingConfig
from manualcontrol.envs._validation import check_choice, check_int

__all__ = ["RECIPES", "optimal_control_effort_weight", "recipe"]

_HUMAN_LIMITATIONS: tuple[Mapping[str, Any], ...] = (
    {"kind": "action_delay", "delay": 0.2, "observe_queue": False},
    {"kind": "neuromuscular", "omega_nms": 12.0, "zeta_nms": 0.5},
    {"kind": "motor_noise", "power_ratio": 0.3},
)
_PPO = {"n_steps": 512, "batch_size": 256}


def optimal_control_effort_weight(
    element: str, forcing: str, action_bound: float, tau_nms: float = 0.1
) -> float:
    """The effort weight that poses the optimal control model's trade-off in the reward.

    The OCM pilot minimises ``J = E{e^2 + g udot^2}``, its control-rate weight ``g``
    fixed by its neuromuscular lag ``tau_nms`` (0.1 s, Kleinman et al.'s value;
    :func:`~manualcontrol.pilots.solve_ocm`). The tracking reward costs ``e^2/var(f)``
    (the bounded reward to first order; ``f`` the target forcing, or the disturbance
    without one) and :class:`~manualcontrol.agents.wrappers.EffortCost` costs
    ``W (udot/U)^2``, so the same trade-off is ``W = g U^2 / var(f)``: the agent is
    asked the OCM's question on its own element, and the weight follows the element
    (a double integrator needs far more stick rate for the same error than 1/s).
    """
    from manualcontrol.envs.signals import forcing_preset
    from manualcontrol.pilots import solve_ocm

    pair = forcing_preset(forcing, 0)
    signal = pair.target if pair.target is not None else pair.disturbance
    g = solve_ocm(element, pair, tau_v=0.2, tau_nms=tau_nms).g
    return float(g * action_bound**2 / signal.variance)


def _tracking(element: str) -> dict[str, Any]:
    return {
        "task": "compensatory",
        "env_kwargs": {
            "controlled_element": element,
            "forcing": "popovici2017",
            "realisation": None,
            "measurement_time": 30.0,
            "include_rates": True,
            "reward": "bounded",
            "loss_of_control": 7.5,
            "action_bound": 5.0,
        },
        "wrappers": _HUMAN_LIMITATIONS,
        "effort_rate_weight": 0.05,
        "algorithm": "ppo",
        "total_timesteps": 600_000,
        "n_envs": 8,
        "algorithm_kwargs": _PPO,
        "policy_kwargs": {"net_arch": [64, 64]},
    }


def _lane_keeping(steering: str, bound: float) -> dict[str, Any]:
    return {
        "task": "lane-keeping",
        "env_kwargs": {
            "road": "random",
            "measurement_time": 30.0,
            "steering": steering,
            "action_bound": bound,
            "reward": "bounded",
            "reward_scale": 0.1,
            "include_rates": True,
        },
        "wrappers": ({"kind": "action_delay", "delay": 0.2, "observe_queue": False},),
        "algorithm": "ppo",
        "total_timesteps": 600_000,
        "n_envs": 8,
        "algorithm_kwargs": {**_PPO, "gamma": 0.995},
        "policy_kwargs": {"net_arch": [64, 64], "log_std_init": -2.5},
    }


#: Every recipe by name: what it trains, and the configuration's keywords.
RECIPES: dict[str, tuple[str, dict[str, Any]]] = {
    "si": ("compensatory tracking of 1/s", _tracking("1/s")),
    "di": ("compensatory tracking of 1/s^2", _tracking("1/s^2")),
    "lag": ("compensatory tracking of 1/(s(s+1))", _tracking("1/(s(s+1))")),
    "lane-angle": ("lane keeping, steering by wheel angle", _lane_keeping("angle", 0.5)),
}


def recipe(name: str, *, seed: int = 0, total_timesteps: int | None = None) -> TrainingConfig:
    """The training configuration of recipe ``name`` (:data:`RECIPES`) with ``seed``."""
    check_choice("recipe", name, tuple(RECIPES))
    check_int("seed", seed, minimum=0)
    keywords = dict(RECIPES[name][1])
    if total_timesteps is not None:
        keywords["total_timesteps"] = check_int("total_timesteps", total_timesteps, minimum=1)
    return TrainingConfig(seed=seed, **keywords)
