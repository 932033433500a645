"""CPU time of one benchmark-suite run, by stage: simulate, estimate, score, store.

For each batch of the chosen suites, the first scenario is run ``--repeats`` times in
this process after one warm-up run (compiled kernels loaded), and the median CPU time
of each stage printed (process CPU time, so other load on the machine counts little;
one BLAS thread, as the bench's runs have):

- simulate: ``runner.simulate_scenario`` (the closed loop, remnant calibration);
- estimate: the DEKF over the whole run;
- score: ``bench.scoring.score`` (metrics, the resimulated isolated pilot);
- store: the results row and traces written as ``run_scenario`` writes them.

Multisines remember their last evaluations (``envs.signals``), and the runs of a batch
share them. A repeat of one scenario would find every evaluation remembered, so the
memory is emptied before each repeat: each figure is a batch's first run, the dearest
(``--warm-forcing`` keeps it, as for the later runs of a batch).

Run: .venv/bin/python benchmarks/bench_pipeline.py [--suite NAME ...] [--repeats N]
For the code before a change, run the same file with PYTHONPATH pointing at an old
tree mapped as ``manualcontrol``; alternate the two for side-by-side medians.
"""

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

from threadpoolctl import threadpool_limits

from manualcontrol.bench.runner import make_estimator, simulate_scenario
from manualcontrol.bench.scenarios import load_suite
from manualcontrol.bench.scoring import score


def stages(scenario, folder):
    """CPU seconds of each stage of one run."""
    times = {}
    start = time.process_time()
    recording = simulate_scenario(scenario)
    times["simulate"] = time.process_time() - start
    start = time.process_time()
    result = make_estimator(scenario.estimator).estimate(recording)
    times["estimate"] = time.process_time() - start
    start = time.process_time()
    row = score(scenario, recording, result)
    times["score"] = time.process_time() - start
    start = time.process_time()
    result.save(folder / "run.npz")
    (folder / "run.json").write_text(json.dumps(row, default=float))
    times["store"] = time.process_time() - start
    times["total"] = sum(times.values())
    return times


def _forget_forcing():
    import manualcontrol.envs.signals as signals

    signals._EVALUATIONS.clear()


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--suite", action="append", help="suite name (repeatable; default the three built-in)"
    )
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument(
        "--warm-forcing",
        action="store_true",
        help="keep remembered forcing evaluations between repeats (a batch's later runs)",
    )
    args = parser.parse_args()
    # one BLAS thread, as the bench runs every scenario (runner._one_thread): process
    # CPU time counts every thread's spinning, which made the estimate stage read 2.5x
    # its single-thread cost
    threadpool_limits(1)
    forget = (lambda: None) if args.warm_forcing else _forget_forcing
    names = args.suite or ["vertregt2020-performance", "popovici2017", "vertregt2020-feasibility"]
    with tempfile.TemporaryDirectory() as temporary:
        folder = Path(temporary)
        print(f"CPU ms per run, median of {args.repeats} (first scenario of each batch)")
        print(f"  {'batch':42s} {'simulate':>9s} {'estimate':>9s} {'score':>9s} {'store':>7s}")
        totals = []
        for name in names:
            suite = load_suite(name)
            firsts = {}
            for scenario in suite.scenarios():
                firsts.setdefault(scenario.batch, scenario)
            for batch, scenario in firsts.items():
                stages(scenario, folder)  # warm-up
                runs = []
                for _ in range(args.repeats):
                    forget()
                    runs.append(stages(scenario, folder))
                median = {key: statistics.median(run[key] for run in runs) for key in runs[0]}
                totals.append(median["total"])
                print(
                    f"  {name + ':' + batch:42s} {median['simulate'] * 1e3:9.1f} "
                    f"{median['estimate'] * 1e3:9.1f} {median['score'] * 1e3:9.1f} "
                    f"{median['store'] * 1e3:7.1f}   total {median['total'] * 1e3:6.1f}"
                )
        print(f"  median total over batches: {statistics.median(totals) * 1e3:.1f} ms")


if __name__ == "__main__":
    main()
