"""Speed of the Kalman family: samples per CPU-second, medians of repeats, one process.

Usage (from the repository root)::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_filters.py [--repeats 5]
    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_filters.py --dekf-only

Reports, for the Popovici compensatory run (90 s at 100 Hz) and the thesis preview DI run
(180 s): the DEKF, the joint and the dual UKF (state counts in brackets), the smoother
pass beside the filter it smooths, the Schiess-Roland joint EKF (13 states) and the
online ``update()`` per sample beside ``estimate()``. CPU time (``time.process_time``),
so the figures hold on a shared machine; the first run of each compiles and is not
counted. ``--dekf-only`` runs the DEKF lines alone (they also run on older versions of
the package, for side-by-side ratios).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests" / "estimators"))
from scenarios import compensatory, preview, preview_initial


def cpu_median(function, repeats):
    function()  # compile / warm
    times = []
    for _ in range(repeats):
        start = time.process_time()
        function()
        times.append(time.process_time() - start)
    return float(np.median(times))


def line(label, samples, seconds, extra=""):
    print(f"{label:<48s} {samples / seconds:>10,.0f} samples/s{extra}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--dekf-only", action="store_true")
    args = parser.parse_args()
    from manualcontrol.estimators import DEKF

    runs = {
        "compensatory (Popovici, 30 % remnant)": (compensatory(True), {"model": "precision"}),
        "preview DI (thesis, remnant)": (
            preview("DI", True),
            {
                "model": "preview",
                "ce": "DI",
                "anticipation_time": 1.5,
                "initial": preview_initial("DI"),
            },
        ),
    }
    for label, (recording, settings) in runs.items():
        n = len(recording)
        dekf = DEKF(**settings)
        line(
            f"DEKF, {label}", n, cpu_median(lambda d=dekf, r=recording: d.estimate(r), args.repeats)
        )
    if args.dekf_only:
        return
    from manualcontrol.estimators import DualUKF, JointUKF, smooth

    for label, (recording, settings) in runs.items():
        n = len(recording)
        for kind in (JointUKF, DualUKF):
            estimator = kind(**settings)
            internal = estimator.internal_model
            result = estimator.estimate(recording.slice_samples(0, 600))
            states = internal.n_states + len(result.estimated)
            seconds = cpu_median(lambda e=estimator, r=recording: e.estimate(r), args.repeats)
            line(f"{kind.__name__} [{states}], {label}", n, seconds)
    # 11 states: the precision model with Pade-4 delays (6 canonical states + 5 parameters)
    recording, _ = runs["compensatory (Popovici, 30 % remnant)"]
    joint = JointUKF(model="precision", delay_order=4)
    seconds = cpu_median(lambda: joint.estimate(recording), args.repeats)
    line("JointUKF [11], compensatory, Pade-4 delay", len(recording), seconds)
    # the smoother pass beside its filter
    for kind in (DEKF, JointUKF):
        estimator = kind(model="precision")
        stored = estimator.estimate(recording, smoother_inputs=True)
        filter_seconds = cpu_median(
            lambda e=estimator: e.estimate(recording, smoother_inputs=True), args.repeats
        )
        smooth_seconds = cpu_median(lambda s=stored: smooth(s), args.repeats)
        line(f"{kind.__name__} filter with smoother storage", len(recording), filter_seconds)
        line(
            f"{kind.__name__} smoother pass",
            len(recording),
            smooth_seconds,
            f"   ({filter_seconds / smooth_seconds:.1f}x the filter's speed)",
        )
    # the 13-state joint EKF of Schiess & Roland, when that member is installed
    try:
        from manualcontrol.estimators import SchiessRoland
        from manualcontrol.pilots import Pilot, simulate
    except ImportError:
        SchiessRoland = None
    if SchiessRoland is not None:
        pilot = Pilot("schiess-roland", remnant={"kind": "schiess-roland", "noise_variance": 576.0})
        run = simulate(
            pilot,
            "schiess-roland1975",
            "schiess-roland1975",
            measurement_time=15.0,
            run_in=0.0,
            seed=0,
            measurement_noise={"u": 0.00092, "y": 0.00092},
        )
        ekf = SchiessRoland()
        seconds = cpu_median(lambda: ekf.estimate(run), args.repeats)
        line("SchiessRoland joint EKF [13], 15-s case-3 run", len(run), seconds)
    # online update() against estimate(), compensatory DEKF
    dekf = DEKF(model="precision")
    signals = dekf.signals(recording)
    keys = dekf.sample_keys
    samples = [{key: float(signals[key][k]) for key in keys} for k in range(len(recording))]
    window = round(dekf.settings.noise.window / recording.dt) + 1

    def online():
        dekf.reset(
            recording.dt,
            var_u0=float(np.var(signals["u"][:window])),
            var_e0=float(np.var(signals["e"][:window])),
        )
        for sample in samples:
            dekf.update(sample)

    seconds = cpu_median(online, max(1, args.repeats // 2))
    batch = cpu_median(lambda: dekf.estimate(recording), args.repeats)
    line(
        "DEKF update(), one sample at a time",
        len(recording),
        seconds,
        f"   ({seconds / batch:.1f}x the per-sample cost inside estimate())",
    )


if __name__ == "__main__":
    main()
