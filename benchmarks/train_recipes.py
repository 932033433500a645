"""Train every recipe with several seeds and measure each agent as humans are measured.

For each recipe of :mod:`manualcontrol.agents.recipes` and seed: the training time,
then :func:`~manualcontrol.agents.evaluation.evaluate` (the wrappers' noise on,
evaluation seed 0, one full forcing period) and its human-likeness figures and verdict.
``--jobs 2`` trains two agents at a time with one torch thread each (each then has one
of the two cores: its training time is an upper bound on the time with both).

Run: .venv/bin/python benchmarks/train_recipes.py [--recipes si di lag] [--seeds 0 1 2]
     [--jobs 2] [--out results/recipes]
"""

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path


def run_one(name: str, seed: int, out: str) -> dict:
    import torch

    torch.set_num_threads(1)
    from manualcontrol.agents.evaluation import evaluate
    from manualcontrol.agents.recipes import recipe
    from manualcontrol.agents.training import train

    config = recipe(name, seed=seed)
    start = time.perf_counter()
    agent = train(config, Path(out) / f"{name}-seed{seed}", report=None)
    row = {"recipe": name, "seed": seed, "train_s": round(time.perf_counter() - start)}
    human = evaluate(agent, seed=0).human
    row.update({k: round(float(v), 3) for k, v in human.figures().items()})
    row["outside"] = list(human.verdict.outside)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recipes", nargs="+", default=["si", "lag", "di"])
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
