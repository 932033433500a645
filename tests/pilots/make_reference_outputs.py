"""Write ``data/reference_outputs_dd5f117.npz``: simulation outputs of the code at commit dd5f117.

The speed work after it replaced scipy's per-matrix ``expm`` (and ``np.unique`` over the parameter
table) by a compiled exponential, which changes results at rounding level only.
``test_reference_outputs.py`` pins today's outputs to these numbers. They were written by
running this script against commit dd5f117 (the last commit before the change):

    PYTHONPATH=<checkout of dd5f117 mapped as manualcontrol> python make_reference_outputs.py

Run it against today's code only to look at the differences, never to overwrite.
"""

import sys
from pathlib import Path

import numpy as np

from manualcontrol.envs.schedules import Sigmoid, Sine
from manualcontrol.pilots import LevisonRemnant, Pilot, simulate
from manualcontrol.pilots.simulation import isolated_pilot_output

SHORT = dict(run_in=5.0, measurement_time=10.0, keep_run_in=True)
VARYING = {
    "K_p": Sigmoid(0.24, 0.4, 3.0, 4.0),
    "K_v": Sigmoid(0.36, 0.3, 4.0, 4.0),
    "omega_nms": Sine(8.0, 1.0, 0.2),
    "zeta_nms": Sigmoid(0.45, 0.3, 2.0, 3.0),
    "tau_v": Sigmoid(0.3, 0.25, 5.0, 4.0),
}
PREVIEW = dict(K_f=0.9, omega_f=1.0, K_p=0.24, K_v=0.36, omega_nms=8.0, zeta_nms=0.45, tau_v=0.3)


def cases():
    """Name -> array of every case; deterministic (seeded)."""
    out = {}
    remnant = LevisonRemnant(omega_r=10.0, injection="feedback", P_r=0.3)
    runs = {
        # every parameter varying: one matrix exponential per sample, calibrated remnant
        "compensatory_varying": simulate(
            Pilot("precision", VARYING, remnant=remnant), "DI", seed=3, **SHORT
        ),
        "compensatory_varying_sampled": simulate(
            Pilot("precision", VARYING, remnant=remnant), "DI", seed=3, loop="sampled", **SHORT
        ),
        # the performance suite's kind: preview, sigmoid tau_f, Padé-5 delay
        "preview_pade": simulate(
            Pilot(
                "preview",
                {**PREVIEW, "tau_f": Sigmoid(0.6, 0.3, 5.0, 4.0)},
                remnant=remnant,
                delay_order=5,
            ),
            "DI",
            seed=4,
            **SHORT,
        ),
        "preview_exact_sampled": simulate(
            Pilot("preview", {**PREVIEW, "tau_f": Sigmoid(0.6, 0.3, 5.0, 4.0)}),
            "DI",
            loop="sampled",
            **SHORT,
        ),
    }
    for name, recording in runs.items():
        for signal in ("u", "y", "e"):
            out[f"{name}_{signal}"] = np.asarray(recording[signal])
    # the isolated pilot with parameter traces that change every sample (resimulation)
    recording = runs["compensatory_varying"]
    n = len(recording)
    ramp = np.linspace(0.0, 1.0, n)
    traces = varying_traces(n)
    out["isolated_precision"] = isolated_pilot_output(
        "precision", traces, {"e": np.asarray(recording.e)}, recording.dt
    )
    preview = runs["preview_pade"]
    out["isolated_preview"] = isolated_pilot_output(
        "preview",
        {**traces, "K_f": 0.9 + 0.1 * ramp, "omega_f": 1.0 + 0.2 * ramp, "tau_f": 0.6 - 0.3 * ramp},
        {"ft_far": np.asarray(preview["ft_far"]), "y": np.asarray(preview.y)},
        preview.dt,
    )
    return out


def varying_traces(n):
    """Precision-model parameter traces that change every one of ``n`` samples."""
    ramp = np.linspace(0.0, 1.0, n)
    return {
        "K_p": 0.24 + 0.1 * ramp,
        "K_v": 0.36 - 0.05 * ramp,
        "omega_nms": 8.0 + np.sin(7.0 * ramp),
        "zeta_nms": 0.45 - 0.1 * ramp,
        "tau_v": 0.3 - 0.05 * ramp,
    }


if __name__ == "__main__":
    path = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).parent / "data" / "x.npz")
    np.savez(path, **cases())
    print(f"wrote {path}")
