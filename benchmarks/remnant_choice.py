"""The RML's offline choices against its defaults on the human-like suite.

For every simulated run of ``human-like`` (the suite's own recordings), the RML filtered
and smoothed: with its defaults (the remnant at the perception, the generic start), with
``start="describing-function"``, with ``remnant_injection="choose"``, and with both, and
filtered with the causal ``remnant_injection="choose-causal"``: the
share of runs whose identified frequency response
lies within 2 dB and 10 deg of the true pilot's at the forcing frequencies (the bench's
``frequency_gain_error_db`` / ``frequency_phase_error_deg``), and which point was
chosen, per batch (the causal choice: the point followed at the end).

Run: .venv/bin/python benchmarks/remnant_choice.py [--quick]
"""

import sys
import warnings
from collections import Counter, defaultdict

from manualcontrol.bench.runner import simulate_scenario
from manualcontrol.bench.scenarios import load_suite
from manualcontrol.bench.scoring import score
from manualcontrol.estimators.registry import make_estimator

#: (estimator, remnant_injection, start): the offline choices filtered and smoothed, and
#: the causal choice, which only a filter from the generic start can make online.
CONFIGURATIONS = [
    (name, injection, start)
    for name in ("rml", "rml-smoothed")
    for injection in ("input", "choose")
    for start in ("generic", "describing-function")
] + [("rml", "choose-causal", "generic")]

#: Configurations whose choice of the remnant point is counted per batch.
RECORD_CHOICE = (("rml", "choose", "describing-function"), ("rml", "choose-causal", "generic"))


def main(quick):
    warnings.simplefilter("ignore")
    suite = load_suite("human-like")
    seen = set()
    passed = Counter()
    runs = Counter()
    chosen = defaultdict(Counter)
    at_limit = {}
    for scenario in suite.scenarios(quick=quick):
        if scenario.simulation_key in seen:
            continue
        seen.add(scenario.simulation_key)
        recording = simulate_scenario(scenario)
        for name, injection, start in CONFIGURATIONS:
            spec = {**dict(scenario.estimator), "name": name}
            spec.update(remnant_injection=injection, start=start)
            result = make_estimator(spec).estimate(recording)
            row = score(scenario, recording, result)
            ok = row["frequency_gain_error_db"] <= 2.0 and row["frequency_phase_error_deg"] <= 10.0
            passed[(name, injection, start)] += ok
            runs[(name, injection, start)] += 1
            key = (name, injection, start)
            share = (row["max_time_at_limit"], row["parameter_at_limit"])
            at_limit[key] = max(at_limit.get(key, (0.0, "")), share)
            if key in RECORD_CHOICE:
                kept = result.settings["remnant_injection"]["chosen"]
                chosen[(scenario.batch, injection)][kept] += 1
    for key in sorted(runs):
        print(
            f"{key[0]:13s} remnant_injection={key[1]:13s} start={key[2]:19s} within 2 dB and "
            f"10 deg: {passed[key]}/{runs[key]} ({100 * passed[key] / runs[key]:.0f} %); "
            f"largest share of a run at a limit {100 * at_limit[key][0]:.1f} % "
            f"({at_limit[key][1] or 'none'})"
        )
    for (batch, injection), counts in chosen.items():
        print(f"{batch:36s} {injection:13s} chosen (at the end): {dict(counts)}")


if __name__ == "__main__":
    main("--quick" in sys.argv[1:])
