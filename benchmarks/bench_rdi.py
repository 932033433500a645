"""RDI speed at 60 Hz with interpolation and smoothing, beside the DEKF.

One core (numba's loops are single-threaded; BLAS pinned to one thread), median of 5 runs
after a warm-up (numba compiles on first use and caches), side by side in one process:

- RDI, the paper's Sec. IV identifier: ARMAX(1,1) with the delay, every sample read
  bicubically (the prediction and the sign checks: three fractional reads of the input
  and two of its slope per sample), identification every 4 samples (15 Hz), on a
  10-minute open-loop recording at 60 Hz (36,000 samples, output noise), filtered and
  with the RTS smoother (``estimate(..., smooth=True)``: the smoother storage and the
  backward pass);
- RDI, gain and delay corrected at every sample (decimation 1), the same recording;
- RDI ``update()`` one sample at a time (the online path, a Python call per sample);
- the DEKF on the Popovici compensatory run (90 s at 100 Hz, 9,000 samples, 7 states +
  3 parameters), filtered and smoothed.

Run: .venv/bin/python benchmarks/bench_rdi.py
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import statistics
import sys
import time
from pathlib import Path

from manualcontrol.envs.schedules import BandLimitedRandomWalk
from manualcontrol.estimators import DEKF, RDI
from manualcontrol.pilots.open_loop import ARMAXSystem, simulate_open_loop

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests" / "estimators"))
from scenarios import compensatory

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
    walk = BandLimitedRandomWalk(0.3, 0.1 / 600, 0.3, 600.0, 11, lower=0.05, upper=1.2)
    system = ARMAXSystem((0.5924,), (1.5119, -1.1043), walk, noise_std=0.01)
    recording = simulate_open_loop(system, "boer-kenyon1998", measurement_time=600.0)
    n = len(recording)
    paper = RDI(
        n_a=1, n_b=1, decimation=4, input="ft", output="u", Q_d=0.4, Q_c=1e-6, R=0.1,
        P0_c=0.1, initial={"d": 0.3, "a_1": 0.5924, "b_0": 1.5119, "b_1": -1.1043},
    )  # fmt: skip
    every_sample = RDI(n_a=0, n_b=0, input="ft", output="u", Q_d=0.5, Q_c=0.05, R=0.5,
                       initial={"d": 0.3, "b_0": 1.0})  # fmt: skip

    def online():
        paper.reset(recording.dt)
        for r, u in zip(recording.ft.tolist(), recording.u.tolist(), strict=True):
            paper.update({"ft": r, "u": u})

    dekf_recording = compensatory(remnant=True)
    dekf = DEKF(model="precision")
    m = len(dekf_recording)
    rows = [
        ("RDI ARMAX(1,1), lambda 4, filtered", n, lambda: paper.estimate(recording)),
        ("RDI ARMAX(1,1), lambda 4, smoothed", n, lambda: paper.estimate(recording, smooth=True)),
        ("RDI gain+delay, lambda 1, filtered", n, lambda: every_sample.estimate(recording)),
        (
            "RDI gain+delay, lambda 1, smoothed",
            n,
            lambda: every_sample.estimate(recording, smooth=True),
        ),
        ("RDI ARMAX(1,1) update(), one sample a call", n, online),
        ("DEKF compensatory, filtered", m, lambda: dekf.estimate(dekf_recording)),
        ("DEKF compensatory, smoothed", m, lambda: dekf.estimate(dekf_recording, smooth=True)),
    ]
    print(f"{'case':45s} {'samples':>8s} {'median s':>9s} {'samples/s':>12s} {'x DEKF':>7s}")
    rates = {}
    for label, samples, function in rows:
        seconds = median_time(function)
        rates[label] = samples / seconds
    reference = rates["DEKF compensatory, filtered"]
    for label, samples, _ in rows:
        rate = rates[label]
        print(
            f"{label:45s} {samples:8d} {samples / rate:9.4f} {rate:12,.0f} {rate / reference:7.2f}"
        )
    print(f"(60-Hz real time: {60:,} samples/s; the smoothed paper RDI runs at "
          f"{rates['RDI ARMAX(1,1), lambda 4, smoothed'] / 60:,.0f}x real time)")  # fmt: skip


if __name__ == "__main__":
    main()
