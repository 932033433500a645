"""Training recipes: surrogate operators that train in minutes on two cores.

:func:`human_problem` is the :class:`~manualcontrol.agents.training.TrainingConfig` of
compensatory tracking of any element posed as the human's problem; a recipe is such a
configuration that this project has trained and measured and whose agents fly a loop:
today ``"si"`` (``1/s``). ``benchmarks/train_recipes.py`` trains the problem on each
element with several seeds and measures each agent's human-likeness; the figures,
including those of the elements whose agents do not yet fly a loop (``1/s^2``,
``1/(s(s+1))``), are in ``docs/surrogates.md``. ``manualcontrol train --recipe NAME`` and
:func:`recipe` give a recipe; ``seed`` and ``total_timesteps`` may be changed,
everything else is the recipe.

The human's problem, as the optimal control model poses it:

* a perceptual delay of 0.2 s whose queue the agent cannot see (it must act through
  it as a human does, not read its own pending commands);
* the neuromuscular system of the precision model (``omega_nms`` 12 rad/s,
  ``zeta_nms`` 0.5) between command and stick;
* motor noise, Levison-filtered with the 10-rad/s break the thesis measured for
  humans on 1/s, half the stick's power: the remnant, drawn by the wrapper, so it stays
  on in evaluation and varies from trial to trial;
* observation noise at the OCM's ``rho`` of 3e-5 (-45 dB; the OCM's -20 dB stops PPO
  from learning a loop within the recipe's budget: no crossover at ``rho`` 1e-3);
* an effort cost on the stick's rate with the OCM's own weight
  (:func:`optimal_control_effort_weight`): without it the optimum is a high-gain loop
  at the edge of stability (crossover 9 rad/s, 3 deg of phase margin);
* the bounded reward with loss-of-control termination (a positive reward, so ending
  an episode never pays while the policy is poor), random realisations of the
  van der El et al. forcing (target and disturbance, 30-s episodes).

PPO with eight environments, a 64-64 network, 1.2 million steps.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from manualcontrol.agents.training import TrainingConfig
from manualcontrol.envs._validation import check_choice, check_int

__all__ = ["RECIPE_ELEMENTS", "human_problem", "optimal_control_effort_weight", "recipe"]

_HUMAN_LIMITATIONS: tuple[Mapping[str, Any], ...] = (
    {"kind": "action_delay", "delay": 0.2, "observe_queue": False},
    {"kind": "neuromuscular", "omega_nms": 12.0, "zeta_nms": 0.5},
    {"kind": "motor_noise", "power_ratio": 0.5, "omega_r": 10.0},
)
_FORCING = "vanderel-bw4"
_ACTION_BOUND = 5.0
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


def human_problem(
    element: str, *, seed: int = 0, total_timesteps: int = 1_200_000
) -> TrainingConfig:
    """Compensatory tracking of ``element`` posed as the human's problem (module docstring)."""
    check_int("seed", seed, minimum=0)
    check_int("total_timesteps", total_timesteps, minimum=1)
    return TrainingConfig(seed=seed, **{**_tracking(element), "total_timesteps": total_timesteps})


def _tracking(element: str) -> dict[str, Any]:
    return {
        "task": "compensatory",
        "env_kwargs": {
            "controlled_element": element,
            "forcing": _FORCING,
            "realisation": None,
            "measurement_time": 30.0,
            "include_rates": True,
            "reward": "bounded",
            "loss_of_control": 7.5,
            "action_bound": _ACTION_BOUND,
        },
        "wrappers": _HUMAN_LIMITATIONS,
        "observation_noise_ratio": 3e-5,
        "effort_rate_weight": optimal_control_effort_weight(element, _FORCING, _ACTION_BOUND),
        "algorithm": "ppo",
        "total_timesteps": 1_200_000,
        "n_envs": 8,
        "algorithm_kwargs": _PPO,
        "policy_kwargs": {"net_arch": [64, 64]},
    }


#: Every recipe by name: the element whose human problem it trains.
RECIPE_ELEMENTS: dict[str, str] = {"si": "1/s"}


def recipe(name: str, *, seed: int = 0, total_timesteps: int | None = None) -> TrainingConfig:
    """The training configuration of recipe ``name`` (:data:`RECIPE_ELEMENTS`) with ``seed``."""
    check_choice("recipe", name, tuple(RECIPE_ELEMENTS))
    return human_problem(
        RECIPE_ELEMENTS[name],
        seed=seed,
        total_timesteps=1_200_000 if total_timesteps is None else total_timesteps,
    )
