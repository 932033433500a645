"""CPU time per run of a suite's simulations: each run alone against a batch's runs together.

For each batch of the chosen suites, its first ``--runs`` simulations (the suite's
order: realisation by realisation, each with its seeds) are simulated twice in this
process, alternately: one after the other with ``simulate`` (``runner.simulate_scenario``,
what the bench did for every run) and together with ``simulate_many`` (what the bench's
``run_scenario_groups`` does for a pool task). The medians of ``--repeats`` such pairs
are printed per run, with their ratio, and every recording is checked to be the same
bytes both ways.

Process CPU time, one BLAS thread (as the bench's workers run); the multisines'
remembered evaluations (``envs.signals``) are emptied before each timing, so both ways
evaluate the forcing afresh.

Run: .venv/bin/python benchmarks/bench_monte_carlo.py [--suite NAME ...] [--runs N] [--repeats N]
"""

import argparse
import statistics
import time

import numpy as np
from threadpoolctl import threadpool_limits

import manualcontrol.envs.signals as signals
from manualcontrol.bench import runner
from manualcontrol.bench.scenarios import load_suite


def _alone(scenarios):
    return [runner.simulate_scenario(scenario) for scenario in scenarios]


def _together(scenarios):
    groups = [[scenario] for scenario in scenarios]
    simulated = list(runner._simulations(groups))
    failed = [failure for _, failure, _ in simulated if failure is not None]
    if failed:
        raise failed[0][0]
    return [recording for recording, _, _ in simulated]


def _timed(simulate, scenarios):
    signals._EVALUATIONS.clear()
    start = time.process_time()
    recordings = simulate(scenarios)
    return time.process_time() - start, recordings


def _same(first, second):
    return all(
        a.metadata == b.metadata
        and all(np.asarray(a[k]).tobytes() == np.asarray(b[k]).tobytes() for k in a.signals)
        for a, b in zip(first, second, strict=True)
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--suite", action="append", help="suite name (repeatable)")
    parser.add_argument("--runs", type=int, default=40, help="simulations per batch")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    threadpool_limits(1)
    names = args.suite or ["vertregt2020-performance", "popovici2017"]
    print(f"CPU ms per simulated run, median of {args.repeats} (alone, together, ratio)")
    ratios = []
    for name in names:
        suite = load_suite(name)
        batches = {}
        for group in runner._groups(suite.scenarios()):
            batches.setdefault(group[0].batch, []).append(group[0])
        for batch, scenarios in batches.items():
            scenarios = scenarios[: args.runs]
            _alone(scenarios[:1])  # compiled kernels loaded
            alone, together = [], []
            for _ in range(args.repeats):
                seconds, first = _timed(_alone, scenarios)
                alone.append(seconds)
                seconds, second = _timed(_together, scenarios)
                together.append(seconds)
                if not _same(first, second):
                    raise SystemExit(f"{name}:{batch}: the recordings differ")
            a, b = (statistics.median(x) / len(scenarios) * 1e3 for x in (alone, together))
            ratios.append(a / b)
            print(
                f"  {name + ':' + batch:50s} {len(scenarios):3d} runs "
                f"{a:7.1f} {b:7.1f}  {a / b:5.2f}x"
            )
    print(f"  median ratio over batches: {statistics.median(ratios):.2f}x; recordings identical")


if __name__ == "__main__":
    main()
