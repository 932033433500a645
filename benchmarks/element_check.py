"""The element check on operators whose output wanders: raw, and less the element's transient.

``describe`` compares the element given with the one measured from ``y``, ``u`` and
``fd`` at the forcing lines. The typical SI and DI pilots here carry a Levison remnant
with the 0.01 rad/s break of the thesis's DI simulations (30 % and 55 % of the stick's
power), so ``y`` wanders and does not repeat over the period. Per element, remnant,
disturbance entry point and seed: the mean absolute gap (dB / deg) of the given element
to the measured one read raw (``y/x``) and as ``element_error`` reads it (less the
element's fitted response to its change of state, ``element_drift``), and the same
check given a wrong element (the other integrator, or twice the gain) or the wrong entry
point, which must stay far off. ``describe`` warns above 1 dB or 10 deg.

Run: .venv/bin/python benchmarks/element_check.py [--seeds N]
"""

import argparse
import warnings

import numpy as np

from manualcontrol.estimators.analysis.frequency import describing_function
from manualcontrol.pilots import LevisonRemnant, Pilot, simulate

WRONG = {"SI": ("DI", "0.5/s"), "DI": ("SI", "2/s^2")}


def raw_gap(measured) -> tuple[float, float]:
    """The gap without the transient taken out (the check before it was)."""
    ratio = measured.element / measured.element_measured
    return (
        float(np.mean(np.abs(20.0 * np.log10(np.abs(ratio))))),
        float(np.mean(np.abs(np.degrees(np.angle(ratio))))),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    args = parser.parse_args()
    print(
        "| element | remnant | entry | seed | raw | less the transient | wrong elements | "
        "wrong entry point |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    worst_right, nearest_wrong = [0.0, 0.0], np.inf
    for element in ("SI", "DI"):
        for share in (0.3, 0.55):
            remnant = LevisonRemnant(omega_r=0.01, injection="feedback", P_r=share)
            pilot = Pilot.typical("precision", element).with_remnant(remnant)
            for at in ("input", "output"):
                for seed in range(args.seeds):
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        run = simulate(pilot, element, seed=seed, disturbance_at=at)
                    right = describing_function(run, element=element)
                    gap = right.element_error()
                    worst_right = [max(worst_right[0], gap[0]), max(worst_right[1], gap[1])]
                    wrong = [
                        describing_function(run, element=w).element_error() for w in WRONG[element]
                    ]
                    other = "output" if at == "input" else "input"
                    point = describing_function(run, element=element, disturbance_at=other)
                    point_gap = point.element_error()
                    nearest_wrong = min(nearest_wrong, point_gap[0], *(g[0] for g in wrong))
                    raw = raw_gap(right)
                    print(
                        f"| {element} | {share:.0%} | {at} | {seed} | "
                        f"{raw[0]:.1f} / {raw[1]:.0f} | "
                        f"{gap[0]:.2f} / {gap[1]:.1f} | "
                        + ", ".join(
                            f"{w} {g[0]:.1f} / {g[1]:.0f}"
                            for w, g in zip(WRONG[element], wrong, strict=True)
                        )
                        + f" | {point_gap[0]:.1f} / {point_gap[1]:.0f} |"
                    )
    print(
        f"largest gap to the right element: {worst_right[0]:.2f} dB, {worst_right[1]:.1f} deg; "
        f"smallest gain gap to a wrong one: {nearest_wrong:.1f} dB"
    )


if __name__ == "__main__":
    main()
