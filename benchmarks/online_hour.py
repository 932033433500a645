"""One hour online with remnant: do the estimates stay put, and does health say when not?

A cybernetic pilot with 20 % remnant flies an environment for an hour at
100 Hz while an :class:`~manualcontrol.estimators.observer.EstimatorObserver` runs an
online estimator (causal start, initial values about 20 % off the truth). Reported per
estimator and parameter: the fraction of the samples the estimate sat at a limit (the
issue asks at most 5 % where the truth lies well inside the limits), the mean and
spread of the estimate over the last ten minutes against the truth, and whether the
filter's health reported divergence (a filter pinned at a limit for 90 % of 30 s says
so).

"At a limit" is read from the estimates themselves (within 1e-6 of the limits' span),
"pinned" from the filter's health report.

Tasks: compensatory single integrator (1.5/s, precision pilot K_p 1.3, tau_v 0.26,
omega_nms 10.5, zeta_nms 0.35) and preview single integrator (the thesis's SI preview
pilot, tau_f 0.6 s, anticipation 0.9 s), both with vanderel-bw4 forcing (realisation
drawn per episode reset: one hour is one episode) and Levison remnant 10 rad/s at the
output feedback, 20 % of the control power.

Run: ``.venv/bin/python benchmarks/online_hour.py [--minutes 60] [--estimators dekf,rml]``.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

import manualcontrol.envs  # noqa: F401  (registers the environments)
from manualcontrol.estimators import make_estimator
from manualcontrol.estimators.observer import EstimatorObserver
from manualcontrol.pilots import Pilot
from manualcontrol.pilots.remnant import LevisonRemnant

REMNANT = LevisonRemnant(omega_r=10.0, injection="feedback", P_r=0.2)
PRECISION = {"K_p": 1.3, "K_v": 0.0, "tau_v": 0.26, "omega_nms": 10.5, "zeta_nms": 0.35}
PREVIEW = {**PRECISION, "K_f": 1.0, "omega_f": 3.3, "tau_f": 0.6}
CASES = {
    "compensatory-SI": (
        "Compensatory",
        Pilot("precision", PRECISION, remnant=REMNANT),
        {
            "model": "precision",
            "ce": "SI",
            "preset": "vertregt2020",
            "initial_variance": "causal",
            "initial": {"K_p": 1.05, "tau_v": 0.31, "omega_nms": 9.0, "zeta_nms": 0.42},
        },
    ),
    "preview-SI": (
        "Preview",
        Pilot("preview", PREVIEW, remnant=REMNANT),
        {
            "model": "preview",
            "ce": "SI",
            "anticipation_time": 0.9,
            "preset": "vertregt2020-remnant",
            "initial_variance": "causal",
            "initial": {
                "K_f": 0.8,
                "omega_f": 3.3,
                "K_p": 1.05,
                "tau_v": 0.3,
                "omega_nms": 9.0,
                "zeta_nms": 0.42,
                "tau_f": 0.5,
            },
        },
    ),
}


def fly(case: str, estimator_name: str, minutes: float, seed: int) -> dict:
    """One episode of ``minutes``; the estimates of every step and the final health."""
    task, pilot, settings = CASES[case]
    inner = gym.make(
        f"ManualControl/{task}Tracking-v0",
        controlled_element="SI",
        forcing="vanderel-bw4",
        run_in=0.0,
        measurement_time=60.0 * minutes,
    )
    estimator = make_estimator({"name": estimator_name, **settings})
    env = EstimatorObserver(inner, estimator)
    observation, _ = env.reset(seed=seed)
    pilot.reset(seed=seed, env=env)
    names = estimator.resolved.estimated
    limits = estimator.resolved.limits
    means, pinned, diverged, done = [], [], [], False
    started = time.perf_counter()
    while not done:
        observation, _, terminated, truncated, info = env.step(pilot.act(observation))
        estimates = info["estimates"]
        means.append([estimates["mean"][name] for name in names])
        pinned.append([name in estimates["health"]["pinned"] for name in names])
        diverged.append(estimates["health"]["diverged"])
        done = terminated or truncated
    return {
        "names": names,
        "limits": {name: limits.get(name) for name in names},
        "means": np.array(means),
        "pinned": np.array(pinned),
        "diverged": np.array(diverged),
        "seconds": time.perf_counter() - started,
        "truth": pilot.parameters,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--estimators", default="dekf,joint-ukf,rml")
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    for case in args.cases.split(","):
        for name in args.estimators.split(","):
            run = fly(case, name, args.minutes, args.seed)
            last = slice(-60_000, None)  # the last ten minutes at 100 Hz
            print(
                f"{case} {name}: {len(run['means'])} steps in {run['seconds']:.0f} s; "
                f"diverged flagged on {run['diverged'].mean() * 100:.1f} % of the steps"
            )
            for j, parameter in enumerate(run["names"]):
                truth = float(run["truth"][parameter](0.0))
                trace = run["means"][:, j]
                low, high = run["limits"][parameter] or (-np.inf, np.inf)
                span = 1e-6 * (high - low) if np.isfinite(high - low) else 0.0
                at_limit = np.mean((trace <= low + span) | (trace >= high - span)) * 100
                flagged = run["pinned"][:, j].mean() * 100
                print(
                    f"    {parameter:10s} truth {truth:6.3f}  limits {run['limits'][parameter]}  "
                    f"at a limit {at_limit:5.1f} % (health says pinned {flagged:5.1f} %)  "
                    f"last 10 min {trace[last].mean():6.3f} "
                    f"+- {trace[last].std():.3f}  whole run [{trace.min():.3f}, {trace.max():.3f}]"
                )


if __name__ == "__main__":
    main()
