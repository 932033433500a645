"""RML settings side by side on chosen batches: NRMSE per parameter, online and smoothed.

Each run of the chosen batches of a suite is simulated once per variant and identified
by the suite's RML (the batch's own estimator settings) with the variant's changes on
top; one filter pass gives the online and, through the smoother, the smoothed
estimate, both scored as ``manualcontrol bench`` scores them. Printed per batch and
variant: the batch means of the NRMSEs (as the report takes them) and of the
resimulated VAF.

Run, for example:
  .venv/bin/python benchmarks/rml_variants.py remnant-robustness \\
      popovici-tv-30,popovici-tv-20 '{}' '{"drift_gain": 50}' '{"drift_window": 1.0}'

Variants are JSON objects of RML settings (``{}`` is the suite's own). This is a tool for
comparing methods across batches, not for fitting numbers to one table.
"""

import argparse
import dataclasses
import json
import multiprocessing
import os
import statistics

from _rml_batches import rml_scenarios


def _job(task):
    from manualcontrol.bench.runner import simulate_scenario
    from manualcontrol.bench.scoring import score
    from manualcontrol.estimators import make_estimator, smooth

    scenario, changes = task
    recording = simulate_scenario(scenario)
    spec = {**scenario.estimator, **changes, "name": "rml"}
    full = make_estimator(spec).estimate(recording, smoother_inputs=True)
    online = score(scenario, recording, dataclasses.replace(full, smoother_inputs=None))
    return scenario.batch, online, score(scenario, recording, smooth(full))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("suite", help="built-in suite name or .toml file")
    parser.add_argument("batches", help="comma-separated batch names")
    parser.add_argument("variants", nargs="+", help="JSON objects of RML settings")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args()
    batches, scenarios = rml_scenarios(parser, args.suite, args.batches)
    variants = []
    for text in args.variants:
        try:
            changes = json.loads(text)
        except json.JSONDecodeError as error:
            parser.error(f"variant {text!r} is not JSON: {error}")
        if not isinstance(changes, dict):
            parser.error(f"variant {text!r} must be a JSON object of settings")
        variants.append(changes)
    context = multiprocessing.get_context("fork" if os.name == "posix" else "spawn")
    with context.Pool(args.workers) as pool:
        for text, changes in zip(args.variants, variants, strict=True):
            rows = pool.map(_job, [(s, changes) for s in scenarios], chunksize=1)
            for batch in batches:
                mine = [row for row in rows if row[0] == batch]
                names = sorted(k for k in mine[0][1] if k.startswith("nrmse_"))
                for kind, column in (("online", 1), ("smoothed", 2)):
                    means = {n: statistics.mean(r[column][n] for r in mine) for n in names}
                    vaf = statistics.mean(r[column]["vaf_resimulated"] for r in mine)
                    figures = " ".join(f"{n[6:]}={v:.3f}" for n, v in means.items())
                    print(f"{text} {batch} {kind}: {figures} vaf_resimulated={vaf:.2f}")


if __name__ == "__main__":
    main()
