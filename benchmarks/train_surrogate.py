"""The issue-7 training run: a surrogate operator on compensatory SI tracking.

The agent learns compensatory tracking of the Popovici-type forcing (a random
realisation per 30-s episode) on the 1.5/s dynamics through a 0.2 s action delay
whose queue it cannot see, with the bounded reward and loss-of-control
termination at |e| > 7.5. It is then evaluated over a full forcing period
(realisation 0): RMS error beside the typical precision pilot, open-loop
response, offline fit and DEKF identification of its equivalent precision
model (is the identified tau_v the imposed 0.2 s?).

The default recipe (PPO, 8 environments, 600k steps, about a minute on two CPU
cores) is the one that learned; SAC with the queue hidden did not within 200k
steps (see the issue-7 note). ``--observe-queue`` shows the agent the pending
actions, which lets it predict through the delay (it then identifies as a
pilot with almost no delay).

Run: .venv/bin/python benchmarks/train_surrogate.py --seeds 0 1 2 --out results/surrogate
"""

import argparse
import json
import time
from pathlib import Path

from manualcontrol.agents.evaluation import evaluate, write_report
from manualcontrol.agents.training import TrainingConfig, train

ALGORITHM_SETTINGS = {
    "ppo": {"algorithm_kwargs": {"n_steps": 512, "batch_size": 256}, "n_envs": 8},
    "sac": {"algorithm_kwargs": {"learning_starts": 1000}, "n_envs": 1},
}


def config_for(algorithm: str, steps: int, seed: int, observe_queue: bool) -> TrainingConfig:
    return TrainingConfig(
        task="compensatory",
        env_kwargs={
            "controlled_element": "SI",
            "forcing": "popovici2017",
            "realisation": None,
            "measurement_time": 30.0,
            "include_rates": True,
            "reward": "bounded",
            "loss_of_control": 7.5,
            "action_bound": 5.0,
        },
        wrappers=({"kind": "action_delay", "delay": 0.2, "observe_queue": observe_queue},),
        algorithm=algorithm,
        total_timesteps=steps,
        seed=seed,
        policy_kwargs={"net_arch": [64, 64]},
        checkpoint_every=100_000,
        **ALGORITHM_SETTINGS[algorithm],
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=600_000)
    parser.add_argument("--algorithm", choices=sorted(ALGORITHM_SETTINGS), default="ppo")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--observe-queue", action="store_true")
    parser.add_argument("--out", type=Path, default=Path("results/surrogate"))
    args = parser.parse_args()
    summaries = []
    for seed in args.seeds:
        folder = args.out / f"seed{seed}"
        config = config_for(args.algorithm, args.steps, seed, args.observe_queue)
        started = time.perf_counter()
        agent = train(config, folder, report_every=100_000)
        wall = time.perf_counter() - started
        evaluation = evaluate(agent, env_overrides={"realisation": 0})
        write_report(evaluation, folder / "evaluation")
        summary = {**evaluation.summary(), "seed": seed, "steps": args.steps, "wall_time_s": wall}
        (folder / "summary.json").write_text(json.dumps(summary, indent=2))
        summaries.append(summary)
        print(
            f"seed {seed}: {wall:.0f} s, RMS {summary['rms_error']:.3f} "
            f"({summary['rms_ratio']:.2f} x reference), "
            f"fit tau_v {summary['identified']['tau_v']:.3f} s "
            f"(VAF {summary['identification_vaf']:.1f} %), "
            f"DEKF tau_v {summary['dekf']['tau_v']:.3f} s, "
            f"crossover {summary['crossover_frequency']:.1f} rad/s, "
            f"phase margin {summary['phase_margin']:.0f} deg",
            flush=True,
        )
    (args.out / "summaries.json").write_text(json.dumps(summaries, indent=2))


if __name__ == "__main__":
    main()
