"""What limits the RML on a batch with remnant: the same filter on altered evidence.

For each run of the chosen batches (the batch's own RML settings), NRMSE means over the
batch (from the batch's ``score_from``) for:

``as-is``
    the recording as the bench identifies it (online and smoothed);
``remnant-free``
    the remnant-free run's signals (``e + y_n``, ``u - u_n``): what a perfect removal of
    the remnant would leave to the same filter, its bound for that batch;
``projected-e``
    ``e`` replaced by its causal projection onto the forcing frequencies (least squares
    on their sines and cosines with exponential forgetting over ``--window`` s): the
    forcing as an instrument, the remnant-correlated part of ``e`` removed
    (compensatory multisine batches only);
``reopened``
    the filter reset to its initial parameter variances (``P0``, correlations cleared)
    at ``--change`` s, as a change detector that is never late and never wrong would
    do (online only; it reaches into the filter's belief).

Run, for example:
  .venv/bin/python benchmarks/rml_limits.py remnant-robustness popovici-tv-30 --change 46

A diagnostic of the RML's limits, not a tuning tool: nothing here is an option of
the estimator.
"""

import argparse
import multiprocessing
import os
import statistics

import numpy as np
from _rml_batches import rml_scenarios


def _projection(x, t, frequencies, window, dt):
    """Causal least-squares fit of ``x`` on the sines and cosines of ``frequencies``."""
    basis = np.concatenate([np.sin(np.outer(t, frequencies)), np.cos(np.outer(t, frequencies))], 1)
    n = basis.shape[1]
    forget = np.exp(-dt / window)
    P = np.eye(n) * 1e3
    theta = np.zeros(n)
    fitted = np.empty_like(x)
    for k in range(len(x)):
        b = basis[k]
        Pb = P @ b
        gain = Pb / (forget + b @ Pb)
        theta = theta + gain * (x[k] - b @ theta)
        P = (P - np.outer(gain, Pb)) / forget
        fitted[k] = b @ theta
    return fitted


def _nrmse(names, t, mean, recording, start):
    from manualcontrol.estimators.analysis.metrics import nrmse

    window = t >= start - 1e-9
    return {
        name: nrmse(mean[window, j], recording.parameters[name][window])
        for j, name in enumerate(names)
        if name in recording.parameters
    }


def _reopened(estimator, recording, change, start):
    """Online means with the parameter covariance reset to ``P0`` at ``change`` s."""
    dt = recording.dt
    first = slice(0, round(estimator.settings.noise.window / dt) + 1)
    estimator.reset(
        dt,
        var_u0=float(np.nanvar(recording.u[first])),
        var_e0=float(np.nanvar(recording.e[first])),
        t0=float(recording.t[0]),
    )
    config, belief = estimator._records[1], estimator._records[3]
    P0 = estimator._resolved.P0
    names = estimator.resolved.estimated
    mean = np.empty((len(recording), len(names)))
    for k, t in enumerate(recording.t):
        if abs(t - change) < dt / 2:
            for a, label in enumerate(estimator._labels):
                if config.slot[a] >= 0:
                    belief.P[a, :] = 0.0
                    belief.P[:, a] = 0.0
                    belief.P[a, a] = P0[label]
        estimate = estimator.update({"e": recording.e[k], "u": recording.u[k], "t": t})
        mean[k] = [estimate.mean[n] for n in names]
    return _nrmse(names, recording.t, mean, recording, start)


def _job(task):
    from manualcontrol.bench.runner import simulate_scenario
    from manualcontrol.envs.signals import Multisine, forcing_preset
    from manualcontrol.estimators import make_estimator

    scenario, change, window = task
    recording = simulate_scenario(scenario)
    spec = {**scenario.estimator, "name": "rml"}
    start = scenario.score_from
    rows = {}

    def identify(label, altered):
        for smooth in (False, True):
            result = make_estimator(spec).estimate(altered, smooth=smooth)
            names = result.parameter_names
            scores = _nrmse(names, result.t, result.mean, recording, start)
            rows[f"{label} {'smoothed' if smooth else 'online'}"] = {
                n: scores[n] for n in result.estimated if n in scores
            }

    identify("as-is", recording)
    identify(
        "remnant-free",
        recording.with_signals(e=recording.e + recording["y_n"], u=recording.u - recording["u_n"]),
    )
    forcing = forcing_preset(scenario.forcing, scenario.realisation)
    parts = [f for f in (forcing.target, forcing.disturbance) if f is not None]
    if scenario.task == "compensatory" and all(isinstance(f, Multisine) for f in parts):
        frequencies = np.concatenate([f.frequencies for f in parts])
        projected = _projection(recording.e, recording.t, frequencies, window, recording.dt)
        identify("projected-e", recording.with_signals(e=projected))
    if change is not None and scenario.task == "compensatory":
        rows["reopened online"] = _reopened(make_estimator(spec), recording, change, start)
    return scenario.batch, rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("suite", help="built-in suite name or .toml file")
    parser.add_argument("batches", help="comma-separated batch names")
    parser.add_argument("--change", type=float, help="time (s) of the oracle reopening")
    parser.add_argument("--window", type=float, default=5.0, help="projection memory (s)")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args()
    if args.window <= 0:
        parser.error(f"--window must be > 0 s, got {args.window}")
    batches, scenarios = rml_scenarios(parser, args.suite, args.batches)
    context = multiprocessing.get_context("fork" if os.name == "posix" else "spawn")
    with context.Pool(args.workers) as pool:
        jobs = [(s, args.change, args.window) for s in scenarios]
        results = pool.map(_job, jobs, chunksize=1)
    for batch in batches:
        mine = [rows for name, rows in results if name == batch]
        print(f"{batch}: {len(mine)} runs, NRMSE means")
        for experiment in mine[0]:
            names = sorted(mine[0][experiment])
            means = {n: statistics.mean(rows[experiment][n] for rows in mine) for n in names}
            figures = " ".join(f"{n}={v:.3f}" for n, v in means.items())
            print(f"  {experiment:24s} {figures}")


if __name__ == "__main__":
    main()
