"""The issue-7 training run: a surrogate operator on compensatory SI tracking.

SAC (or PPO) learns compensatory tracking of the Popovici-type forcing (random
realisation per 30-s episode) on 1.5/s dynamics through a 0.2 s action delay; the
trained agent is then evaluated over a full forcing period (RMS error beside the
typical precision pilot, open-loop response, offline identification of its
equivalent precision model: is the identified tau_v the imposed 0.2 s?).

Run: .venv/bin/python benchmarks/train_surrogate.py --steps 150000 --out results/surrogate
"""

import argparse
import json
import time
from pathlib import Path

from manualcontrol.agents.evaluation import evaluate, write_report
from manualcontrol.agents.training import TrainingConfig, train


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=150_000)
    parser.add_argument("--algorithm", choices=("sac", "ppo"), default="sac")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("results/surrogate"))
    args = parser.parse_args()
    config = TrainingConfig(
        task="compensatory",
        env_kwargs={
            "controlled_element": "SI",
            "forcing": "popovici2017",
            "realisation": None,
            "measurement_time": 30.0,
            "include_rates": True,
        },
        wrappers=({"kind": "action_delay", "delay": 0.2},),
        algorithm=args.algorithm,
        total_timesteps=args.steps,
        seed=args.seed,
        policy_kwargs={"net_arch": [64, 64]},
        checkpoint_every=25_000,
    )
    started = time.perf_counter()
    agent = train(config, args.out, report_every=5_000)
    wall = time.perf_counter() - started
    evaluation = evaluate(agent, env_overrides={"realisation": 0})
    write_report(evaluation, args.out / "evaluation")
    summary = {**evaluation.summary(), "steps": args.steps, "wall_time_s": wall}
    (args.out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
