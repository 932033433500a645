"""Schiess-Roland joint EKF speed beside the DEKF, in the same run.

One core (numba's loop is single-threaded, BLAS pinned to one thread); median of 7
runs after a warm-up (numba compiles on first use; its cache makes later processes
start warm), in wall time and in this process's CPU time (on a shared, loaded machine
the wall time also counts the time the process waited for a core). Samples per second
of the filter kernel over a whole recording, the Python shell excluded; the shell's
cost per run is reported separately (``estimate()``):

- Schiess-Roland: 13 states (6 dynamic + 7 parameters), the delay history read each
  step, two measurements; the paper's case 3 (q = 576) over 60 s at 100 Hz, with the
  integer and the bicubic delay read, and with the full adaptive noise;
- DEKF: the compensatory run of tests/estimators/scenarios.py (90 s, 7 + 3 states).

Run: .venv/bin/python benchmarks/bench_schiess_roland.py
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import math
import statistics
import sys
import time
from pathlib import Path

from manualcontrol.estimators import DEKF
from manualcontrol.estimators.members import _schiess_roland_core as core
from manualcontrol.estimators.members.schiess_roland import SchiessRoland
from manualcontrol.pilots import Pilot, SchiessRolandRemnant, simulate

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests" / "estimators"))
from scenarios import compensatory

REPEATS = 7
TRUTH = {"K_1": 1.0, "tau_1": 0.1, "tau_2": 0.1, "tau_3": 0.5, "theta": 0.05}


def timings(function):
    """Median (wall, CPU) seconds of ``REPEATS`` runs after one warm-up."""
    function()
    wall, cpu = [], []
    for _ in range(REPEATS):
        start, start_cpu = time.perf_counter(), time.process_time()
        function()
        wall.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return statistics.median(wall), statistics.median(cpu)


def schiess_roland_kernel(estimator, recording):
    signals = estimator.signals(recording)
    states = estimator.initial_states_of(recording)

    def run():
        estimator.reset(recording.dt, initial_states=states, t0=float(recording.t[0]))
        out = estimator._new_output(len(recording), store=False)
        core.sr_run(*estimator._records, signals["ft"], signals["u"], signals["y"], out)

    return run


def dekf_kernel(dekf, recording):
    signals = dekf.signals(recording)
    import numpy as np

    n = round(dekf.settings.noise.window / recording.dt)
    var_u0 = float(np.nanvar(signals["u"][: n + 1]))
    var_e0 = float(np.nanvar(signals["e"][: n + 1]))
    inputs = np.ascontiguousarray(
        np.column_stack([signals[name] for name in dekf.internal_model.input_names])
    )

    def run():
        dekf.reset(recording.dt, var_u0=var_u0, var_e0=var_e0)
        out = dekf._new_output(len(recording), store=False)
        dekf._run(inputs, signals["u"], signals["e"], out)

    return run


def main():
    e0 = 0.25 * math.sin(0.25) + 0.959
    pilot = Pilot("schiess-roland", TRUTH, remnant=SchiessRolandRemnant(noise_variance=576.0))
    recording = simulate(
        pilot,
        "schiess-roland1975",
        "schiess-roland1975",
        run_in=0.0,
        measurement_time=60.0,
        start_time=0.25,
        initial_state={
            "y": (-0.959, -5.6363),
            "u": (1.0342, (-0.688 - 0.6237 + 5.0 * e0) / 0.1 + 2.5484),
            "n": (0.4105, 2.5484),
        },
        measurement_noise={"u": 0.00092, "y": 0.00092},
        seed=0,
    )
    dekf_recording = compensatory(True)
    rows = []
    dekf = DEKF(model="precision")
    wall, cpu = timings(dekf_kernel(dekf, dekf_recording))
    rows.append(("DEKF compensatory, 7 + 3 states", len(dekf_recording), wall, cpu))
    for label, options in (
        ("Schiess-Roland, integer delay read", {}),
        ("Schiess-Roland, bicubic delay read", {"delay_read": "bicubic"}),
        ("Schiess-Roland, integer, full adaptive noise", {"adaptive": "full"}),
    ):
        estimator = SchiessRoland(process_noise=576.0, **options)
        wall, cpu = timings(schiess_roland_kernel(estimator, recording))
        rows.append((label, len(recording), wall, cpu))
    estimate_time = timings(lambda: SchiessRoland(process_noise=576.0).estimate(recording))[0]
    dekf_wall, dekf_cpu = rows[0][1] / rows[0][2], rows[0][1] / rows[0][3]
    header = ("run", "samples", "wall /s", "vs DEKF", "CPU /s", "vs DEKF")
    print("{:46s} {:>7s} {:>10s} {:>7s} {:>10s} {:>7s}".format(*header))
    for label, samples, wall, cpu in rows:
        print(
            f"{label:46s} {samples:7d} {samples / wall:10,.0f} {samples / wall / dekf_wall:6.2f}x "
            f"{samples / cpu:10,.0f} {samples / cpu / dekf_cpu:6.2f}x"
        )
    print(
        f"SchiessRoland.estimate(), 60 s, shell included: {estimate_time * 1e3:.1f} ms "
        f"({len(recording) / estimate_time:,.0f} samples/s)"
    )


if __name__ == "__main__":
    main()
