"""The RMS ratio's reference with and without the run's own remnant.

``human_likeness``'s ``rms_ratio`` holds a run's error (its RMS about its mean) against
the typical precision pilot's on the same element and forcing. Against that pilot without remnant
(the reference before it took the run's remnant), a human's remnant reads as poor
tracking wherever the element does not integrate it away. Here the typical pilot
itself, with a Levison remnant of 15, 30 or 40 % of the stick's power, is judged both
ways:

- ``gain``: lab trials on a unit gain as ``benchmarks/pure_gain.py`` simulates them
  (60 Hz, the disturbance at the element's input, one 80-s period, the remnant at the
  output feedback, the typical lag pilot's delay);
- ``1/s`` and ``1/s^2``: the thesis's typical SI and DI pilots on the default forcing,
  the remnant at the pilot's input (break 3 rad/s);
- ``1/s^2, slow``: the DI pilot with the thesis's DI remnant (break 0.01 rad/s, at the
  ``y`` feedback), the disturbance at the element's input: the error it drives wanders,
  most of it in the stretch's mean.

Per element and remnant share, over ``--seeds`` runs: the range of the ratio against
the remnant-free reference (``rms_error / reference_rms_error``, the error read with its
mean, as the figure was) and of ``rms_ratio`` (the error about its mean against the
reference given the run's remnant), and how many runs each calls outside the human
range.

Run: .venv/bin/python benchmarks/rms_reference.py [--seeds N]
"""

import argparse
import warnings

import pure_gain

from manualcontrol.estimators.analysis.human_likeness import HUMAN_RANGES, human_likeness
from manualcontrol.pilots import LevisonRemnant, Pilot, simulate
from manualcontrol.pilots.stability import typical_parameters

SHARES = (0.15, 0.3, 0.4)


def runs(element: str, share: float, seeds: int):
    """The typical pilot on ``element`` with ``share`` remnant, one run per seed."""
    for seed in range(seeds):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if element == "gain":
                values = typical_parameters(
                    pure_gain.make_model(pure_gain.LAGGED_PRECISION), pure_gain.parse_element("1")
                )
                recording, _ = pure_gain.trial(values["tau_v"], share, seed)
                yield human_likeness(recording, "1", period=pure_gain.PERIOD)
            elif element == "DI, slow":
                remnant = LevisonRemnant(omega_r=0.01, injection="feedback", P_r=share)
                pilot = Pilot.typical("precision", "DI").with_remnant(remnant)
                yield human_likeness(simulate(pilot, "DI", seed=seed, disturbance_at="input"))
            else:
                remnant = LevisonRemnant(omega_r=3.0, injection="input", P_r=share)
                pilot = Pilot.typical("precision", element).with_remnant(remnant)
                yield human_likeness(simulate(pilot, element, seed=seed))


def outside(values, human) -> int:
    """How many of ``values`` lie outside the human range ``human``."""
    return sum(not human.low <= v <= human.high for v in values)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=8)
    args = parser.parse_args()
    print(f"typical pilots with remnant, {args.seeds} runs each; ranges over the runs")
    print(
        "| element | remnant | remnant_fraction | remnant-free reference | outside | "
        "rms_ratio (the run's remnant) | outside |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for element, kind in (
        ("gain", "gain"),
        ("SI", "integrator"),
        ("DI", "double_integrator"),
        ("DI, slow", "double_integrator"),
    ):
        human = HUMAN_RANGES[kind]["rms_ratio"]
        for share in SHARES:
            results = list(runs(element, share, args.seeds))
            old = [r.rms_error / r.reference_rms_error for r in results]
            new = [r.rms_ratio for r in results]
            fraction = [r.remnant_fraction for r in results]

            print(
                f"| {element} | {share:.0%} | {min(fraction):.2f}-{max(fraction):.2f} | "
                f"{min(old):.2f}-{max(old):.2f} | {outside(old, human)} | "
                f"{min(new):.2f}-{max(new):.2f} | {outside(new, human)} |"
            )
    print(f"human range of rms_ratio: {human.low:g}-{human.high:g}")


if __name__ == "__main__":
    main()
