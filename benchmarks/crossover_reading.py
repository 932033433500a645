"""How often the measured crossover frequency is the pilot model's, read three ways.

Typical pilots (the precision model; with its lag on a gain) on K, K/s, K/s^2 and
K/(s(s+1)), each forcing (``vanderel-bw4`` with the disturbance at the element's output
and at its input, ``plaetinck2018``, ``popovici2017``), with a Levison remnant of 15, 30
or 55 % of the stick's power broken at 0.01 rad/s at the ``y`` feedback (the thesis's DI
remnant: a slow wander), at 3 rad/s at the pilot's input, or at 10 rad/s at the
feedback, ``--seeds`` seeds each. The measured open loop's downward crossing of 1 is
read:

- ``first``: the first crossing between any lines (how it was read before);
- ``first, unswamped``: the first between the lines whose injected signal-to-noise ratio
  is 1 or more;
- ``best-read, unswamped``: as ``describing_function`` reads it, the crossing between
  the best-read pair of those lines (the larger of their smaller weights).

Per element: the runs whose reading is within 25 % of the model's own crossover (on a
fine grid, ``model_crossover``), and the runs with no reading (NaN).

Run: .venv/bin/python benchmarks/crossover_reading.py [--seeds N]
"""

import argparse
import warnings

import numpy as np

from manualcontrol.estimators.analysis.frequency import (
    _crossover,
    describing_function,
    model_crossover,
)
from manualcontrol.estimators.analysis.human_likeness import reference_model, reference_pilot
from manualcontrol.pilots import LevisonRemnant, Pilot, simulate

ELEMENTS = ("gain", "SI", "DI", "1/(s(s+1))")
FORCINGS = (
    ("vanderel-bw4", "output"),
    ("vanderel-bw4", "input"),
    ("plaetinck2018", "output"),
    ("popovici2017", "output"),
)
REMNANTS = ((0.01, "feedback"), (3.0, "input"), (10.0, "feedback"))
SHARES = (0.15, 0.3, 0.55)
READINGS = ("first", "first, unswamped", "best-read, unswamped")


def readings(measured) -> dict[str, float]:
    """The crossover (rad/s) each way of reading it."""
    unswamped = measured.readable_lines
    first = (
        _crossover(measured.frequencies[unswamped], measured.open_loop[unswamped])[0]
        if np.count_nonzero(unswamped) >= 2
        else np.nan
    )
    return {
        "first": _crossover(measured.frequencies, measured.open_loop)[0],
        "first, unswamped": first,
        "best-read, unswamped": measured.crossover_frequency,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2)
    args = parser.parse_args()
    print(
        "| element | runs | " + " | ".join(f"{name}: within 25 % (NaN)" for name in READINGS) + " |"
    )
    print("| --- | --- |" + " --- |" * len(READINGS))
    totals = {name: [0, 0] for name in READINGS}
    count = 0
    for element in ELEMENTS:
        values = reference_pilot(element)
        model = reference_model(values)
        within = {name: [0, 0] for name in READINGS}
        runs = 0
        for forcing, at in FORCINGS:
            for omega_r, injection in REMNANTS:
                for share in SHARES:
                    remnant = LevisonRemnant(omega_r=omega_r, injection=injection, P_r=share)
                    pilot = Pilot(model, values, remnant=remnant)
                    for seed in range(args.seeds):
                        with warnings.catch_warnings():
                            warnings.simplefilter("ignore")
                            run = simulate(pilot, element, forcing, seed=seed, disturbance_at=at)
                        measured = describing_function(run, element=element)
                        truth = model_crossover(model, values, measured)[0]
                        runs += 1
                        for name, value in readings(measured).items():
                            if not np.isfinite(value):
                                within[name][1] += 1
                            elif abs(np.log(value / truth)) < np.log(1.25):
                                within[name][0] += 1
        count += runs
        for name in READINGS:
            totals[name][0] += within[name][0]
            totals[name][1] += within[name][1]
        cells = " | ".join(f"{within[n][0]} ({within[n][1]})" for n in READINGS)
        print(f"| {element} | {runs} | {cells} |")
    cells = " | ".join(f"{totals[n][0]} ({totals[n][1]})" for n in READINGS)
    print(f"| all | {count} | {cells} |")


if __name__ == "__main__":
    main()
