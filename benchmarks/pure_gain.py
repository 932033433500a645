"""Lab trials on a pure gain: the precision model with and without McRuer's lag.

Humans equalise a pure gain with a lag (McRuer & Jex 1967). Each trial here is a lab's
compensatory trial on a unit gain, as the real recordings this tool is for are: 60 Hz,
the disturbance entering at the element's input, no target, one 80-s forcing period
(a ten-line multisine whose period is a whole number of samples). The operator is the
precision model with its lag at the typical values for a gain
(:func:`~manualcontrol.pilots.stability.typical_parameters`), its delay 0.22, 0.27 or
0.32 s, with a Levison remnant at the output feedback of 15 % or 40 % of the stick's
power.

For each trial, against the describing function measured at the forcing lines (the
mean absolute gain and phase gaps, weighted by the forcing power, as ``identify``'s
frequency check reports them):

- ``describe``'s fit with the precision model (``--model precision``) and with its lag
  (``precision-lag``, ``describe``'s default on a gain), and the lag fit's ``K_p`` and
  ``T_I`` against the operator's;
- the filters ``rml`` (``identify``'s default) and ``dekf-smoothed`` on either model
  (their second-half medians), the element given (limits from it and human ranges).

Run: .venv/bin/python benchmarks/pure_gain.py [--seeds N]
"""

import argparse
import dataclasses
import statistics
import warnings

from manualcontrol.envs.elements import parse_element
from manualcontrol.envs.signals import ForcingPair, Multisine, forcing_preset
from manualcontrol.estimators.analysis.frequency import describing_function, fit_describing_function
from manualcontrol.estimators.analysis.identification import build_estimator, identify
from manualcontrol.pilots import Pilot, simulate
from manualcontrol.pilots.models import LAGGED_PRECISION, make_model
from manualcontrol.pilots.remnant import LevisonRemnant
from manualcontrol.pilots.stability import typical_parameters

PERIOD = 80.0  # s: 4,800 samples at 60 Hz
DT = 1.0 / 60.0
MODELS = ("precision", LAGGED_PRECISION)
FILTERS = ("rml", "dekf-smoothed")


def lab_forcing() -> Multisine:
    """Ten lines spread as a lab's disturbance is, on an 80-s period."""
    source = forcing_preset("plaetinck2018").target
    scale = source.measurement_time / PERIOD
    return Multisine(source.frequencies * scale, source.amplitudes, source.phases, PERIOD)


def trial(delay: float, remnant_share: float, seed: int):
    """A lab's recording of the lagging operator, and the operator's values."""
    element = parse_element("1")
    values = typical_parameters(make_model(LAGGED_PRECISION), element)
    values["tau_v"] = delay
    remnant = LevisonRemnant(omega_r=10.0, injection="feedback", P_r=remnant_share)
    disturbance = lab_forcing()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        recording = simulate(
            Pilot(LAGGED_PRECISION, values, remnant=remnant),
            element,
            ForcingPair(None, disturbance, "lab", 0),
            dt=DT,
            seed=seed,
            disturbance_at="input",
        )
    # a lab's file names no forcing object: the lines are read off fd over the period
    metadata = {k: v for k, v in recording.metadata.items() if k != "forcing"}
    return dataclasses.replace(recording, metadata=metadata), values


def measure(recording, values):
    """The gaps (dB, deg) of each fit and filter to the measured describing function."""
    element = parse_element("1")
    measured = describing_function(recording, period=PERIOD, element=element)
    row = {}
    for model in MODELS:
        fit = fit_describing_function(measured, model)
        row[f"describe {model}"] = (fit.gain_error_db, fit.phase_error_deg)
        if model == LAGGED_PRECISION:
            row["lag fit K_p / true"] = fit.values["K_p"] / values["K_p"]
            row["lag fit T_I / true"] = fit.values["T_I"] / values["T_I"]
    for name in FILTERS:
        for model in MODELS:
            estimator = build_estimator(name, model=model, element=element)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                found = identify(
                    recording,
                    estimator,
                    element=element,
                    target={"target_period": PERIOD},
                    period=PERIOD,
                )
            check = found.summary["fit"]["frequency_check"]
            row[f"{name} {model}"] = (check["gain_error_db"], check["phase_error_deg"])
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=1, help="trials per delay and remnant")
    args = parser.parse_args()
    rows = []
    for share in (0.15, 0.4):
        for delay in (0.22, 0.27, 0.32):
            for seed in range(args.seeds):
                recording, values = trial(delay, share, 100 + seed)
                row = measure(recording, values)
                rows.append(row)
                gaps = "  ".join(
                    f"{key} {value[0]:.1f} dB {value[1]:.0f} deg"
                    for key, value in row.items()
                    if isinstance(value, tuple)
                )
                print(f"remnant {share:.0%} tau_v {delay:.2f} seed {seed}: {gaps}", flush=True)
    print(f"\n{len(rows)} trials; medians (range) of the gaps to the measured describing function")
    print("| fitted | gain gap, dB | phase gap, deg |")
    print("| --- | --- | --- |")
    for key in rows[0]:
        if not isinstance(rows[0][key], tuple):
            continue
        gains = [row[key][0] for row in rows]
        phases = [row[key][1] for row in rows]
        print(
            f"| {key} | {statistics.median(gains):.1f} ({min(gains):.1f}-{max(gains):.1f}) "
            f"| {statistics.median(phases):.0f} ({min(phases):.0f}-{max(phases):.0f}) |"
        )
    for key in ("lag fit K_p / true", "lag fit T_I / true"):
        ratios = [row[key] for row in rows]
        print(
            f"{key}: median {statistics.median(ratios):.2f} ({min(ratios):.2f}-{max(ratios):.2f})"
        )


if __name__ == "__main__":
    main()
