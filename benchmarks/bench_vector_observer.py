"""Env-steps per second with an online DEKF: one env stepped at a time, and N in one call.

All in one process, CPU time of this process (other load on the machine counts
little), medians of REPEATS runs after one warm-up run, side by side:

- single, pilot: ``CompensatoryTracking-v0`` (DI) with an ``EstimatorObserver`` and a
  causal DEKF, a cybernetic pilot acting: the single-env online loop of
  ``bench_online.py`` (the observer's thin form, ``estimates_in_info="none"``);
- single, law: the same with the pilot replaced by the linear law below, so that the
  actor costs what it costs in the batched rows;
- vector, law: ``gymnasium.make_vec(..., num_envs=N)`` with a ``VectorEstimatorObserver``
  (``"none"``; ``"arrays"`` beside it) and the law acting for all copies in numpy;
- vector env alone, law: the batched env without an observer;
- the DEKF's own cost per sample inside ``estimate()`` of a recorded episode, the
  floor any online path pays per env-step.

The law is the DI typical pilot's equaliser on the displayed error and its rate,
``u = K_p (e + T_L e_dot)`` (no cybernetic pilot acts on a batch); its rate is the
environment's displayed rate (``include_rates=True``).

Run: .venv/bin/python benchmarks/bench_vector_observer.py [--envs N] [--steps N] [--repeats N]
"""

import argparse
import statistics
import time

import gymnasium as gym

import manualcontrol.envs  # noqa: F401
from manualcontrol.estimators import DEKF
from manualcontrol.estimators.observer import EstimatorObserver
from manualcontrol.estimators.vector_observer import VectorEstimatorObserver
from manualcontrol.pilots import Pilot

ENV_ID = "ManualControl/CompensatoryTracking-v0"
DI = dict(K_p=0.24, K_v=0.36, omega_nms=8.0, zeta_nms=0.45, tau_v=0.3)
SETTINGS = dict(model="precision", ce="DI", initial_variance="causal", initial={"K_p": 0.24})
K_P, LEAD = 0.24, 1.5  # K_v / K_p of DI above


def env_kwargs(steps):
    return dict(controlled_element="DI", run_in=0.0, measurement_time=steps * 0.01)


def law(observation):
    """``K_p (e + T_L e_dot)`` on (..., [e, e_dot]) observations."""
    return K_P * (observation[..., :1] + LEAD * observation[..., 1:2])


def run_single(steps, pilot):
    env = EstimatorObserver(
        gym.make(ENV_ID, include_rates=True, **env_kwargs(steps)),
        DEKF(**SETTINGS),
        estimates_in_info="none",
    )
    actor = Pilot("precision", DI) if pilot else None

    def once():
        observation, _ = env.reset(seed=0)
        if actor is not None:
            actor.reset(seed=1, env=env)
        start = time.process_time()
        for _ in range(steps):
            action = actor.act(observation[:1]) if actor is not None else law(observation)
            observation, *_ = env.step(action)
        return time.process_time() - start

    return once


def run_vector(steps, n, form):
    env = gym.make_vec(ENV_ID, num_envs=n, include_rates=True, **env_kwargs(steps))
    if form is not None:
        env = VectorEstimatorObserver(env, DEKF(**SETTINGS), estimates_in_info=form)

    def once():
        observations, _ = env.reset(seed=0)
        start = time.process_time()
        for _ in range(steps):
            observations, *_ = env.step(law(observations))
        return time.process_time() - start

    return once


def dekf_per_sample(steps):
    env = gym.make(ENV_ID, include_rates=True, **env_kwargs(steps))
    observation, _ = env.reset(seed=0)
    for _ in range(steps):
        observation, *_ = env.step(law(observation))
    recording = env.unwrapped.recording(include_run_in=True)
    estimator = DEKF(**SETTINGS)

    def once():
        start = time.process_time()
        estimator.estimate(recording)
        return time.process_time() - start

    return once, len(recording)


def median_of(once, repeats):
    once()  # warm-up: compile or load the kernels
    return statistics.median(once() for _ in range(repeats))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, default=256)
    parser.add_argument("--steps", type=int, default=2_000)
    parser.add_argument("--single-steps", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    n, steps, single_steps = args.envs, args.steps, args.single_steps
    rows = {}
    rows["single, pilot"] = single_steps / median_of(run_single(single_steps, True), args.repeats)
    rows["single, law"] = single_steps / median_of(run_single(single_steps, False), args.repeats)
    for form in ("none", "arrays"):
        rows[f"vector N={n}, law, observer {form}"] = (
            n * steps / median_of(run_vector(steps, n, form), args.repeats)
        )
    rows[f"vector N={n} env alone, law"] = (
        n * steps / median_of(run_vector(steps, n, None), args.repeats)
    )
    once, samples = dekf_per_sample(single_steps)
    rows["DEKF inside estimate(), samples/s"] = samples / median_of(once, args.repeats)
    reference = rows["single, pilot"]
    print(f"env-steps per CPU second, medians of {args.repeats} (ratio to 'single, pilot')")
    for name, rate in rows.items():
        print(f"  {name:40s} {rate:12,.0f}   {rate / reference:6.2f}x   {1e6 / rate:7.2f} us")


if __name__ == "__main__":
    main()
