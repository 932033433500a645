"""Train every recipe with several seeds and measure each agent as humans are measured.

For each recipe of :mod:`manualcontrol.agents.recipes` and seed: the training time,
then, for a tracking recipe, :func:`~manualcontrol.agents.evaluation.evaluate` (the
wrappers' noise on, evaluation seed 0, one full forcing period) and its human-likeness
figures and verdict; for a lane-keeping recipe, the RMS lateral offset on five random
roads (seeds 1000-1004, 60 s each, loss of control on) beside the cybernetic driver's
(Zhao et al.'s nominal values) on the same roads. ``--jobs 2`` trains two agents at a
time with one torch thread each (each then has one of the two cores: its training time
is an upper bound on the time with both).

Run: .venv/bin/python benchmarks/train_recipes.py [--recipes si di lag lane-angle]
     [--seeds 0 1 2] [--jobs 2] [--out results/recipes]
"""

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROADS = (1000, 1001, 1002, 1003, 1004)


def _lane_offsets(actor, make, seeds=ROADS):
    rms, lost = [], 0
    for seed in seeds:
        env = make()
        observation, _ = env.reset(seed=seed)
        actor.reset(seed=seed, env=env)
        offsets, done, terminated = [], False, False
        while not done:
            observation, _, terminated, truncated, info = env.step(actor.act(observation))
            offsets.append(info["y_L"])
            done = terminated or truncated
        env.close()
        rms.append(float(np.sqrt(np.mean(np.square(offsets)))))
        lost += bool(terminated)
    return rms, lost


def run_one(name: str, seed: int, out: str) -> dict:
    import gymnasium as gym
    import torch

    torch.set_num_threads(1)
    from manualcontrol.agents.evaluation import evaluate
    from manualcontrol.agents.recipes import recipe
    from manualcontrol.agents.training import make_env, train
    from manualcontrol.pilots.driver import Driver

    config = recipe(name, seed=seed)
    start = time.perf_counter()
    agent = train(config, Path(out) / f"{name}-seed{seed}", report=None)
    row = {"recipe": name, "seed": seed, "train_s": round(time.perf_counter() - start)}
    if config.task == "compensatory":
        human = evaluate(agent, seed=0).human
        row.update({k: round(float(v), 3) for k, v in human.figures().items()})
        row["outside"] = list(human.verdict.outside)
    else:
        rms, lost = _lane_offsets(agent, lambda: make_env(config, measurement_time=60.0))
        kwargs = {k: v for k, v in config.env_kwargs.items() if k not in ("action_bound",)}
        kwargs.update(steering="torque", measurement_time=60.0, include_rates=False)
        driver, _ = _lane_offsets(
            Driver(), lambda: gym.make("ManualControl/LaneKeeping-v0", **kwargs)
        )
        row.update(
            rms_offset=[round(v, 3) for v in rms],
            driver_rms_offset=[round(v, 3) for v in driver],
            ratio_to_driver=round(float(np.max(np.array(rms) / np.array(driver))), 2),
            roads_left=lost,
        )
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recipes", nargs="+", default=["si", "di", "lag", "lane-angle"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", default="results/recipes")
    args = parser.parse_args()
    jobs = [(name, seed) for name in args.recipes for seed in args.seeds]
    rows = []
    with ProcessPoolExecutor(args.jobs) as pool:
        futures = [pool.submit(run_one, name, seed, args.out) for name, seed in jobs]
        for future in futures:
            rows.append(future.result())
            print(json.dumps(rows[-1]), flush=True)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / "recipes.json").write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
