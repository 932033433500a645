"""DEKF speed against the plain-numpy oracle, and its accuracy tables.

Speed (one core: numba's loop is single-threaded, BLAS is pinned to one thread):
median of 5 runs after one warm-up (numba compiles on first use; its cache makes later
processes start warm), side by side:
- compensatory run: 90 s at 100 Hz (9,000 samples), 7 states + 3 parameters, 30 %
  remnant, Popovici defaults;
- preview run: DI, 180 s (18,000 samples), 11 states + 6 parameters, 55 % remnant;
- the numpy oracle (tests/estimators/dekf_oracle.py) on the first 3,000 samples of
  each (a full run would take minutes), and the largest relative difference of the
  two implementations on those samples: with the papers' settings and with a
  well-conditioned initial canonical variance (see tests/estimators/test_dekf.py).

Accuracy: the scenarios of tests/estimators/scenarios.py, faithful settings and the
improved options of tests/estimators/test_dekf_accuracy.py, realisation 0 (as in the
tests) and the worst and median over realisations 0-4 (remnant seeds 1-5); the
preview feasibility case beside thesis Table II.

Run: .venv/bin/python benchmarks/bench_dekf.py [--quick]
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from manualcontrol.estimators import DEKF, evaluate, nrmse, relative_bias
from manualcontrol.pilots import HumanLimitWarning

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests" / "estimators"))
from dekf_oracle import NumpyDEKF
from scenarios import (
    ANTICIPATION,
    PREVIEW_START,
    compensatory,
    compensatory_tv,
    preview,
    preview_initial,
)
from test_dekf_accuracy import FAITHFUL, REMNANT, REMNANT_FREE

REPEATS = 5
ORACLE_SAMPLES = 3000
THESIS_TABLE_II = {
    "SI": {"K_f": 0.063, "tau_f": 0.252, "K_p": 0.093, "omega_nms": 0.034, "zeta_nms": 0.352,
           "tau_v": 0.189, "VAF": 94.0},
    "DI": {"K_f": 0.130, "omega_f": 0.122, "tau_f": 0.109, "K_p": 0.167, "K_v": 0.063,
           "omega_nms": 0.051, "zeta_nms": 0.114, "tau_v": 0.067, "VAF": 96.9},
}  # fmt: skip


def median_time(function):
    function()
    times = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def oracle_run(dekf, recording):
    signals = dekf.signals(recording)
    n = round(dekf.settings.noise.window / recording.dt)
    var_u0 = float(np.nanvar(signals["u"][: n + 1]))
    var_e0 = float(np.nanvar(signals["e"][: n + 1]))
    oracle = NumpyDEKF(dekf, recording.dt, var_u0, var_e0)
    inputs = np.column_stack([signals[name] for name in dekf.internal_model.input_names])
    return oracle.run(inputs, signals["u"], signals["e"])


def largest_difference(dekf, recording):
    result = dekf.estimate(recording)
    mean, std, scalars = oracle_run(dekf, recording)
    worst = 0.0
    for ours, theirs in (
        (result.mean, mean),
        (result.std, std),
        (result.prediction, scalars[:, 0]),
        (result.innovation_variance, scalars[:, 2]),
    ):
        scale = np.nanmax(np.abs(theirs), axis=0) + 1e-300
        worst = max(worst, float(np.nanmax(np.abs(ours - theirs) / scale)))
    return worst


def speed():
    cases = {
        "compensatory (7 + 3 states)": (
            compensatory(remnant=True),
            {"model": "precision"},
        ),
        "preview DI (11 + 6 states)": (
            preview("DI", remnant=True),
            {
                "model": "preview",
                "ce": "DI",
                "anticipation_time": 1.5,
                "initial": preview_initial("DI"),
            },
        ),
    }
    print(f"Speed, one core, median of {REPEATS} (samples per second)")
    print(f"  {'run':30s} {'samples':>8s} {'DEKF':>12s} {'numpy oracle':>14s} {'ratio':>7s}"
          f"  {'max rel. diff (papers / well-conditioned)':>s}")  # fmt: skip
    for name, (recording, settings) in cases.items():
        dekf = DEKF(**settings)
        compiled = len(recording) / median_time(lambda d=dekf, r=recording: d.estimate(r))
        segment = recording.slice_samples(0, ORACLE_SAMPLES)
        oracle = ORACLE_SAMPLES / median_time(lambda d=dekf, r=segment: oracle_run(d, r))
        papers = largest_difference(dekf, segment)
        conditioned = largest_difference(
            DEKF(**settings, P0_canonical=1e-8, preset="vertregt2020"), segment
        )
        print(
            f"  {name:30s} {len(recording):8d} {compiled:12,.0f} {oracle:14,.0f} "
            f"{compiled / oracle:6.0f}x  {papers:.1e} / {conditioned:.1e}"
        )


def compensatory_rows(realisations):
    scenarios = {
        "constant": lambda r, rem: compensatory(rem, r, r + 1),
        "time-varying": lambda r, rem: compensatory_tv(rem, r, r + 1),
    }
    configurations = {"faithful": FAITHFUL, "improved (remnant-free)": REMNANT_FREE,
                      "improved (remnant)": REMNANT}  # fmt: skip
    names = ("K_p", "K_v", "tau_v", "omega_nms", "zeta_nms")
    print("\nCompensatory (Popovici Sec. IV-A), metrics from 15 s")
    print("  constant: final value error / mean error over t >= 30 s; time-varying: NRMSE")
    for scenario, make in scenarios.items():
        for remnant in (False, True):
            label = f"{scenario}, {'30 % remnant' if remnant else 'remnant-free'}"
            print(f"\n  {label}")
            print(f"    {'settings':26s} {'real.':>6s} {'VAF 1-step':>10s} {'VAF resim':>9s}  "
                  + "  ".join(f"{n:>15s}" for n in names))  # fmt: skip
            for config, settings in configurations.items():
                rows = []
                for r in realisations:
                    recording = make(r, remnant)
                    result = DEKF(model="precision", **settings).estimate(recording)
                    metrics = evaluate(result, recording, start=15.0)
                    values = []
                    for name in names:
                        truth = recording.parameters[name]
                        if scenario == "constant":
                            final = result.final()[name] / truth[-1] - 1.0
                            steady = result.mean_of(name)[recording.t >= 30.0].mean() / truth[-1]
                            values.append((final, steady - 1.0))
                        else:
                            values.append((metrics.nrmse[name], None))
                    rows.append((str(r), metrics.one_step_vaf, metrics.resimulated_vaf, values))
                for r, one, resim, values in rows[:1] + _summary(rows):
                    cells = "  ".join(
                        f"{a:+7.3f}/{b:+7.3f}" if b is not None else f"{a:15.3f}" for a, b in values
                    )
                    print(f"    {config:26s} {r:>6s} {one:10.2f} {resim:9.2f}  {cells}")


def _summary(rows):
    """Worst (largest magnitude) and median of every column over the realisations."""
    if len(rows) < 2:
        return []
    n = len(rows[0][3])
    worst, median = [], []
    for i in range(n):
        firsts = [row[3][i][0] for row in rows]
        seconds = [row[3][i][1] for row in rows]
        has_second = seconds[0] is not None
        worst.append(
            (
                max(firsts, key=abs),
                max(seconds, key=abs) if has_second else None,
            )
        )
        median.append(
            (
                float(np.median(firsts)),
                float(np.median(seconds)) if has_second else None,
            )
        )
    one = [row[1] for row in rows]
    resim = [row[2] for row in rows]
    return [
        ("worst", min(one), min(resim), worst),
        ("median", float(np.median(one)), float(np.median(resim)), median),
    ]


def preview_table(realisations):
    print("\nPreview, tau_f varying, remnant-free, all parameters (thesis Table II),")
    print("  NRMSE (relative bias) over the 120-s measurement window; VAF resimulated")
    for ce in ("SI", "DI"):
        settings = {
            "model": "preview",
            "ce": ce,
            "anticipation_time": ANTICIPATION[ce],
            "initial": preview_initial(ce),
            "preset": "vertregt2020",
        }
        for label, extra in (("thesis preset, eq. 49 printed", {}),
                             ("thesis preset, eq. 49 dimensional",
                              {"total_derivative": "dimensional"})):  # fmt: skip
            table: dict[str, list[tuple[float, float]]] = {}
            vafs = []
            for r in realisations:
                recording = preview(ce, realisation=r)
                result = DEKF(**settings, **extra).estimate(recording)
                mask = recording.t >= PREVIEW_START
                metrics = evaluate(result, recording, start=PREVIEW_START)
                vafs.append(metrics.resimulated_vaf)
                for name in result.estimated:
                    truth = recording.parameters[name][mask]
                    estimate = result.mean_of(name)[mask]
                    table.setdefault(name, []).append(
                        (nrmse(estimate, truth), relative_bias(estimate, truth))
                    )
            print(f"\n  {ce}, {label} (mean over realisations {list(realisations)})")
            thesis = THESIS_TABLE_II[ce]
            for name, values in table.items():
                mean_error = float(np.mean([v[0] for v in values]))
                mean_bias = float(np.mean([v[1] for v in values]))
                worst = max(v[0] for v in values)
                reference = thesis.get(name)
                ref = f"thesis {reference:.3f}" if reference is not None else ""
                print(f"    {name:10s} NRMSE {mean_error:6.3f} (bias {mean_bias:+6.3f}), "
                      f"worst {worst:6.3f}   {ref}")  # fmt: skip
            print(f"    {'VAF':10s} {np.mean(vafs):6.1f} %   thesis {thesis['VAF']:.1f} %")


def main():
    quick = "--quick" in sys.argv
    warnings.simplefilter("ignore", HumanLimitWarning)
    speed()
    realisations = range(1) if quick else range(5)
    compensatory_rows(realisations)
    preview_table(range(1) if quick else range(3))


if __name__ == "__main__":
    main()
