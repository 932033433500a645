"""Speed of a 180 s preview run (100 Hz, 18,000 samples) against scipy.signal.lsim.

Side by side in one process, median of 5 after one warm-up (numba compiles on first
use; its cache makes later processes start warm):
- simulate(): van der El preview pilot, time-varying tau_f (sigmoid 0.6 -> 0.3 s),
  Levison remnant with a given gain, exact delay (the default);
- the same with the remnant gain calibrated to P_r = 35 % (three runs inside);
- the same with every pilot parameter time-varying (a matrix exponential per sample);
- scipy.signal.lsim (interp=False) of the constant-parameter closed loop with a
  Padé-5 delay, built as one state-space model of the same size.

Run: .venv/bin/python benchmarks/bench_simulate.py
"""

import statistics
import time

import numpy as np
import scipy.signal

from manualcontrol.envs.schedules import Sigmoid
from manualcontrol.pilots import LevisonRemnant, Pilot, SimulationSetup, simulate
from manualcontrol.pilots.simulation import closed_loop

REPEATS = 5


def median_time(function):
    function()
    times = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main():
    tau_f = Sigmoid(0.6, 0.3, 50.0, 10.0)
    remnant = LevisonRemnant(K_r=0.5, omega_r=10.0, injection="feedback")
    pilot = Pilot("preview", {"tau_f": tau_f}, remnant=remnant)
    calibrated = Pilot(
        "preview",
        {"tau_f": tau_f},
        remnant=LevisonRemnant(omega_r=10.0, injection="feedback", P_r=0.35),
    )
    all_varying = Pilot(
        "preview",
        {
            "tau_f": tau_f,
            "K_p": Sigmoid(1.3, 1.0, 60.0, 10.0),
            "omega_nms": Sigmoid(10.5, 9.0, 60.0, 10.0),
            "zeta_nms": Sigmoid(0.35, 0.45, 60.0, 10.0),
            "tau_v": Sigmoid(0.26, 0.3, 60.0, 10.0),
        },
        remnant=remnant,
    )

    # the constant-parameter closed loop as one LTI model (Padé-5 delay) for lsim
    constant = Pilot("preview", {}, remnant=remnant, delay_order=5)
    setup = SimulationSetup.create(constant, "SI", "vanderel-bw4")
    signals = setup.forcing_signals(setup.parameter_traces())
    loop = closed_loop(setup)
    A, B, C, D = loop.system.A, loop.system.B, loop.system.C, loop.system.D
    assert loop.inputs == ("ft", "fd", "noise", "ft_far")
    n = setup.n_samples
    t = np.arange(n) * setup.dt
    rng = np.random.default_rng(0)
    inputs = np.column_stack(
        [signals["ft"], signals["fd"], rng.standard_normal(n), signals["ft_far"]]
    )

    results = {
        "simulate, tau_f varying, remnant": median_time(lambda: simulate(pilot, "SI", seed=1)),
        "simulate, + P_r calibration": median_time(lambda: simulate(calibrated, "SI", seed=1)),
        "simulate, all parameters varying": median_time(
            lambda: simulate(all_varying, "SI", seed=1)
        ),
        f"lsim, constant closed loop ({A.shape[0]} states)": median_time(
            lambda: scipy.signal.lsim((A, B, C, D), inputs, t, interp=False)
        ),
    }
    reference = results[f"lsim, constant closed loop ({A.shape[0]} states)"]
    print(f"180 s run, {n} samples, median of {REPEATS}")
    for name, seconds in results.items():
        print(
            f"  {name:48s} {seconds * 1e3:8.1f} ms  {180.0 / seconds:8.0f}x real time  "
            f"{seconds / reference:5.2f}x lsim"
        )


if __name__ == "__main__":
    main()
