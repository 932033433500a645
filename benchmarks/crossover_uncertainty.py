"""The measured crossover's uncertainty, and the verdicts it spares the typical pilots.

For the typical pilot of each element (the lag pilot on a gain) with a Levison remnant
at the error (10 rad/s) of a given share, over ``--seeds`` runs: the deviation of the
crossover (of its natural log) and of the phase margin the describing function states
(:meth:`DescribingFunction.crossover_uncertainty`, median and largest over the runs) beside the
deviation of the readings over the runs; and how many runs ``human_likeness`` judges
outside the human range on either figure when a reading outside by no more than two
of its deviations counts as inside (now) and when it does not (before). A last row
flies a loop far outside on 1/s (K_p 5.2, tau_v 0.1 s, omega_nms 30: 8-11 rad/s), which
must stay outside.

Run: .venv/bin/python benchmarks/crossover_uncertainty.py [--seeds N]
"""

import argparse
import math
import warnings

import numpy as np

from manualcontrol.estimators.analysis.human_likeness import _judge, human_likeness
from manualcontrol.pilots import LevisonRemnant, Pilot, simulate
from manualcontrol.pilots.models import LAGGED_PRECISION, make_model
from manualcontrol.pilots.stability import typical_parameters

JUDGED = ("crossover_frequency", "phase_margin")
FAR_OUTSIDE = dict(K_p=5.2, K_v=0.0, tau_v=0.1, omega_nms=30.0, zeta_nms=0.35)


def pilot_on(element: str, share: float, far_outside: bool = False) -> Pilot:
    remnant = LevisonRemnant(omega_r=10.0, injection="feedback", P_r=share)
    if far_outside:
        return Pilot("precision", FAR_OUTSIDE, remnant=remnant)
    if element == "gain":
        lagged = make_model(LAGGED_PRECISION)
        return Pilot(lagged, typical_parameters(lagged, "gain"), remnant=remnant)
    return Pilot.typical("precision", element).with_remnant(remnant)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=16)
    seeds = parser.parse_args().seeds
    print(
        "| element | remnant | crossover sd of log: stated median (largest) / over runs | "
        "phase margin sd (deg): stated median (largest) / over runs | judged outside (now) "
        "| judged outside (bare reading) |"
    )
    print("| --- | --- | --- | --- | --- | --- |")
    cases = [(e, s, False) for e in ("gain", "SI", "DI") for s in (0.15, 0.4)]
    for element, share, far_outside in [*cases, ("SI", 0.15, True)]:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the far loop's parameters are no human's
            pilot = pilot_on(element, share, far_outside)
        readings, stated, now, before = [], [], 0, 0
        for seed in range(seeds):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                result = human_likeness(simulate(pilot, element, seed=seed))
            describing = result.describing
            readings.append((math.log(describing.crossover_frequency), describing.phase_margin))
            stated.append(describing.crossover_uncertainty())
            now += any(name in result.verdict.outside for name in JUDGED)
            figures = result.figures()
            bare = _judge(result.element_kind, figures, {})
            before += any(j.name in JUDGED and j.inside is False for j in bare)
        median, largest = np.median(stated, axis=0), np.max(stated, axis=0)
        spread = np.std(readings, axis=0)
        print(
            f"| {element}{' (far outside)' if far_outside else ''} | {100 * share:.0f} % | "
            f"{median[0]:.3f} ({largest[0]:.2f}) / {spread[0]:.3f} | "
            f"{median[1]:.1f} ({largest[1]:.0f}) / {spread[1]:.1f} | {now} of {seeds} | "
            f"{before} of {seeds} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
