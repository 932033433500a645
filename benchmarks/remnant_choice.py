"""The RML with remnant_injection="choose" against its default on the human-like suite.

For every simulated run of ``human-like`` (the suite's own recordings), the RML online
and smoothed, with the remnant at the perception (the default) and with
``remnant_injection="choose"``: the share of runs whose identified frequency response
lies within 2 dB and 10 deg of the true pilot's at the forcing frequencies (the bench's
``frequency_gain_error_db`` / ``frequency_phase_error_deg``), and which point was
chosen, per batch.

Run: .venv/bin/python benchmarks/remnant_choice.py [--quick]
"""

import sys
import warnings
from collections import Counter, defaultdict

from manualcontrol.bench.runner import simulate_scenario
from manualcontrol.bench.scenarios import load_suite
from manualcontrol.bench.scoring import score
from manualcontrol.estimators.registry import make_estimator


def main(quick):
    warnings.simplefilter("ignore")
    suite = load_suite("human-like")
    seen = set()
    passed = Counter()
    runs = Counter()
    chosen = defaultdict(Counter)
    for scenario in suite.scenarios(quick=quick):
        if scenario.simulation_key in seen:
            continue
        seen.add(scenario.simulation_key)
        recording = simulate_scenario(scenario)
        for name in ("rml", "rml-smoothed"):
            for injection in ("input", "choose"):
                spec = {**dict(scenario.estimator), "name": name, "remnant_injection": injection}
                result = make_estimator(spec).estimate(recording)
                row = score(scenario, recording, result)
                ok = (
                    row["frequency_gain_error_db"] <= 2.0
                    and row["frequency_phase_error_deg"] <= 10.0
                )
                passed[(name, injection)] += ok
                runs[(name, injection)] += 1
                if injection == "choose" and name == "rml":
                    chosen[scenario.batch][result.settings["remnant_injection"]["chosen"]] += 1
    for key in sorted(runs):
        print(
            f"{key[0]:13s} remnant_injection={key[1]:6s} within 2 dB and 10 deg: "
            f"{passed[key]}/{runs[key]} ({100 * passed[key] / runs[key]:.0f} %)"
        )
    for batch, counts in chosen.items():
        print(f"{batch:36s} chosen: {dict(counts)}")


if __name__ == "__main__":
    main("--quick" in sys.argv[1:])
