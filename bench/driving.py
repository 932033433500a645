"""Lane-keeping scenarios on the bench: batches with ``task = "lane-keeping"``.

A lane-keeping batch reuses the suite schema's keys with the driving meaning:

=================  ==========================================================================
key                lane keeping
=================  ==========================================================================
``element``        the environment: a vehicle preset name (``"mid-size"``) or a table with
                   any of ``vehicle`` (preset or table), ``speed``, ``steering``,
                   ``near_distance``, ``far_gain``, ``far_preview``, ``lane_width`` and
                   ``output_noise`` (sensor noise on ``Gamma_d``/``delta_sw``, see
                   :func:`~manualcontrol.pilots.driving.simulate_driving`)
``forcing``        the road: a preset (``"zhao2019"``, ``"straight"``) or ``"random"``
``realisations``   ``[0]`` for a fixed road; the road seeds for ``"random"``
``pilot``          the driver: ``model = "cybernetic-driver"``, ``parameters``, ``remnant``
                   (a remnant table: ``kind``, ``injection``, ``P_r``, ...), ``delay_order``
``remnant_seeds``  seeds of the remnant and sensor noise
=================  ==========================================================================

``available_preview`` does not apply; ``loop`` is always the sampled loop of the
environment (the key is ignored). :func:`simulate_lane_keeping` runs the scenario's
drive, :func:`score_lane_keeping` scores an estimator on it: per estimated parameter the
relative bias and NRMSE (thesis eq. 37) from ``score_from``, and the paper's
observations made measurable:

* ``lag_<p>``: the delay (s) that best aligns the estimate with the truth around the
  truth's change (minimum RMS of ``estimate(t) - truth(t - lag)``, 0-20 s in 0.05-s
  steps, from 5 s before the change to 20 s after it); NaN when the truth is constant;
* ``noise_<p>``: RMS of the estimate about its centred 2-s moving average, relative to
  the mean truth (the fast fluctuation);
* ``straight_drift_<p>``: the largest relative change of the estimate on the longest
  straight where both perception angles are near zero (from 2 s after the straight
  begins, when the far point sees no curvature and ``|theta_near|`` is below 2 mrad);

and the VAF of the one-step ``Gamma_d`` prediction and of the driver model resimulated
with the estimated traces (:func:`~manualcontrol.pilots.driving.resimulate_driver`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from manualcontrol.bench.batches import (
    Batch,
    SuiteError,
    batch_estimators,
    int_list,
    suite_error,
)
from manualcontrol.envs._validation import check_choice, check_positive
from manualcontrol.envs.driving import (
    ROAD_PRESETS,
    STEERING_MODES,
    LaneKeeping,
    Road,
    road_preset,
    vehicle_preset,
)
from manualcontrol.envs.recording import Recording
from manualcontrol.estimators.analysis import metrics
from manualcontrol.pilots.driver import Driver
from manualcontrol.pilots.driving import output_noise_levels, resimulate_driver, simulate_driving

__all__ = [
    "ENVIRONMENT_KEYS",
    "TASK",
    "build_driver",
    "parse_lane_keeping_batch",
    "score_lane_keeping",
    "simulate_lane_keeping",
]

TASK = "lane-keeping"
#: Keys of a lane-keeping batch's ``element`` table.
ENVIRONMENT_KEYS = (
    "vehicle",
    "speed",
    "steering",
    "near_distance",
    "far_gain",
    "far_preview",
    "lane_width",
    "output_noise",
)
_BATCH_KEYS = {
    "name",
    "task",
    "element",
    "forcing",
    "realisations",
    "remnant_seeds",
    "pilot",
    "estimator",
    "estimators",
    "reference",
    "quick",
    "dt",
    "run_in",
    "measurement_time",
    "loop",
    "score_from",
}
_PILOT_KEYS = {"model", "parameters", "remnant", "delay_order"}
MOVING_WINDOW = 10.0  # s, as the tracking suites
STRAIGHT_SETTLE = 2.0  # s after a straight begins
NEAR_ZERO_ANGLE = 2e-3  # rad


def build_driver(data: Mapping[str, Any]) -> Driver:
    """The :class:`~manualcontrol.pilots.driver.Driver` of a batch's ``pilot`` table."""
    return Driver.from_dict(dict(data))


def _environment(element: Any) -> dict[str, Any]:
    """Environment keywords from a batch's ``element`` (module docstring)."""
    if isinstance(element, str):
        vehicle_preset(element)
        return {"vehicle": element}
    if not isinstance(element, Mapping):
        raise TypeError(f"element must be a vehicle preset or a table, got {element!r}")
    unknown = sorted(set(element) - set(ENVIRONMENT_KEYS))
    if unknown:
        raise ValueError(
            f"element has unknown key(s) {unknown}; allowed: {', '.join(ENVIRONMENT_KEYS)}"
        )
    environment = dict(element)
    vehicle_preset(environment.get("vehicle", "mid-size"))
    if "steering" in environment:
        check_choice("steering", environment["steering"], STEERING_MODES)
    for key in ("speed", "near_distance", "far_gain", "far_preview", "lane_width"):
        if key in environment:
            check_positive(key, environment[key])
    return environment


def parse_lane_keeping_batch(where: str, merged: Mapping[str, Any]) -> Batch:
    """Validate a lane-keeping batch (``[[batch]]`` merged with the defaults)."""
    name = merged["name"]
    where = f"{where} ({name})"
    unknown = sorted(set(merged) - _BATCH_KEYS - {"available_preview"})
    if unknown:
        raise suite_error(where, f"unknown key(s) {unknown} for a lane-keeping batch")
    if merged.get("available_preview") is not None:
        raise suite_error(where, "available_preview does not apply to lane keeping")
    try:
        environment = _environment(merged["element"])
        road = merged["forcing"]
        if road != "random":
            check_choice("forcing (road)", road, ROAD_PRESETS)
        dt = check_positive("dt", merged.get("dt", 0.01))
        run_in = check_positive("run_in", merged.get("run_in", 0.0), allow_zero=True)
        measurement_time = merged.get("measurement_time")
        if measurement_time is not None:
            measurement_time = check_positive("measurement_time", measurement_time)
        score_from = check_positive("score_from", merged.get("score_from", 0.0), allow_zero=True)
        output_noise_levels(environment.pop("output_noise", None))
        # the environment checks the rest (speeds, distances, the drive fitting the road)
        lane = LaneKeeping(
            road, dt=dt, run_in=run_in, measurement_time=measurement_time, **environment
        )
    except (TypeError, ValueError) as error:
        raise suite_error(where, str(error)) from None
    # the measured samples run from t = 0 (after the run-in) to the episode's last step
    last = (lane.episode_steps - lane.n_run_in - 1) * dt
    if score_from > last + 1e-9:  # the scoring window's tolerance (bench.scoring)
        raise suite_error(
            where,
            f"score_from must lie in [0, {last:g}] s, the times of the measured samples "
            f"(t = 0 to {last:g} s: measurement_time = {lane.measurement_time:g} s at "
            f"dt = {dt:g} s), got {score_from!r}: it would leave nothing to score",
        )
    realisations = int_list(where, "realisations", merged["realisations"])
    if road != "random" and realisations != (0,):
        raise suite_error(where, f"realisations must be [0] for the fixed road {road!r}")
    seeds = int_list(where, "remnant_seeds", merged.get("remnant_seeds", [0]))
    quick = dict(merged.get("quick", {}))
    unknown = sorted(set(quick) - {"realisations", "remnant_seeds"})
    if unknown:
        raise suite_error(where, f"quick has unknown key(s) {unknown}")
    quick_realisations = int_list(
        where, "quick.realisations", quick.get("realisations", [realisations[0]])
    )
    quick_seeds = int_list(where, "quick.remnant_seeds", quick.get("remnant_seeds", [seeds[0]]))
    pilot = dict(merged["pilot"])
    unknown = sorted(set(pilot) - _PILOT_KEYS)
    if unknown:
        raise suite_error(
            where, f"pilot has unknown key(s) {unknown}; allowed: {sorted(_PILOT_KEYS)}"
        )
    try:
        build_driver(pilot)
    except (TypeError, ValueError, KeyError) as error:
        raise suite_error(where, f"pilot: {error}") from None
    shared, estimators = batch_estimators(where, merged)
    template = {
        "task": TASK,
        "element": merged["element"],
        "forcing": road,
        "pilot": pilot,
        "dt": dt,
        "run_in": run_in,
        "measurement_time": measurement_time,
        "loop": "sampled",
        "available_preview": None,
        "score_from": score_from,
    }
    return Batch(
        name,
        template,
        realisations,
        seeds,
        quick_realisations,
        quick_seeds,
        dict(merged.get("reference", {})),
        estimators,
        shared,
    )


def simulate_lane_keeping(scenario: Any) -> Recording:
    """The scenario's drive (run-in kept, as the tracking scenarios)."""
    environment = _environment(scenario.element)
    noise = environment.pop("output_noise", None)
    if scenario.forcing == "random":
        road: Any = Road.random(scenario.realisation, 50_000.0)
    else:
        road = road_preset(scenario.forcing)
    return simulate_driving(
        scenario.build_pilot(),
        road,
        seed=scenario.remnant_seed,
        output_noise=noise,
        keep_run_in=True,
        dt=scenario.dt,
        run_in=scenario.run_in,
        measurement_time=scenario.measurement_time,
        **environment,
    )


# ------------------------------------------------------------------------ scoring


def _moving_average(values: np.ndarray, samples: int) -> np.ndarray:
    kernel = np.ones(samples) / samples
    padded = np.pad(values, (samples // 2, samples - 1 - samples // 2), mode="edge")
    return np.convolve(padded, kernel, mode="valid")


def estimate_lag(t: np.ndarray, estimate: np.ndarray, truth: np.ndarray) -> float:
    """Delay (s) that best aligns ``estimate`` with ``truth`` around its change (module doc)."""
    changing = np.flatnonzero(np.abs(np.diff(truth)) > 1e-12 * max(1.0, abs(truth[0])))
    if changing.size == 0:
        return float("nan")
    window = (t >= t[changing[0]] - 5.0) & (t <= t[changing[-1] + 1] + 20.0)
    ok = window & np.isfinite(estimate)
    lags = np.arange(0.0, 20.0 + 1e-9, 0.05)
    times = t[ok]
    rms = np.empty(len(lags))
    # 50 lags at once (~20 MB on a zhao2019 window): the same interpolations and row
    # means as one lag at a time
    for first in range(0, len(lags), 50):
        chunk = lags[first : first + 50]
        shifted = np.interp((times[None, :] - chunk[:, None]).ravel(), t, truth)
        errors = estimate[ok][None, :] - shifted.reshape(len(chunk), len(times))
        rms[first : first + 50] = np.sqrt(np.mean(errors**2, axis=1))
    best, best_lag = np.inf, float("nan")
    for lag, value in zip(lags.tolist(), rms.tolist(), strict=True):
        if value < best - 1e-15:  # the earliest of lags within 1e-15 of the best
            best, best_lag = value, lag
    return best_lag


def estimate_noise(t: np.ndarray, estimate: np.ndarray, truth: np.ndarray, start: float) -> float:
    """RMS of the estimate about its centred 2-s moving average, over the mean truth."""
    samples = max(3, round(2.0 / float(t[1] - t[0])))
    smooth = _moving_average(estimate, samples)
    keep = (t >= start) & np.isfinite(estimate) & np.isfinite(smooth)
    if not keep.any():
        return float("nan")
    return float(np.sqrt(np.mean((estimate - smooth)[keep] ** 2)) / abs(np.mean(truth)))


def straight_stretch(recording: Recording) -> tuple[int, int] | None:
    """First and last sample of the longest straight with both angles near zero."""
    far = np.abs(np.asarray(recording["theta_far"])) < 1e-9
    edges = np.diff(np.concatenate(([0], far.astype(np.int8), [0])))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    if starts.size == 0:
        return None
    longest = int(np.argmax(stops - starts))
    first = starts[longest] + round(STRAIGHT_SETTLE / recording.dt)
    last = stops[longest] - 1
    near = np.abs(np.asarray(recording["theta_near"]))
    while first <= last and near[first] > NEAR_ZERO_ANGLE:
        first += 1
    return (int(first), int(last)) if first < last else None


def straight_drift(recording: Recording, estimate: np.ndarray) -> float:
    """Largest relative change of ``estimate`` over :func:`straight_stretch`."""
    stretch = straight_stretch(recording)
    if stretch is None:
        return float("nan")
    first, last = stretch
    reference = estimate[first]
    return float(np.max(np.abs(estimate[first : last + 1] - reference)) / abs(reference))


def score_lane_keeping(scenario: Any, recording: Recording, result: Any) -> dict[str, Any]:
    """The results-row entries of one lane-keeping run (module docstring)."""
    t = np.asarray(recording.t)
    mask = t >= scenario.score_from
    if not mask.any():
        raise SuiteError(f"score_from = {scenario.score_from!r} s is after the last sample")
    row: dict[str, Any] = {}
    for name in result.estimated:
        if name not in recording.parameters:
            continue
        truth = np.asarray(recording.parameters[name])
        estimate = np.asarray(result.mean_of(name))
        row[f"nrmse_{name}"] = metrics.nrmse(estimate[mask], truth[mask])
        row[f"rel_bias_{name}"] = metrics.relative_bias(estimate[mask], truth[mask])
        row[f"lag_{name}"] = estimate_lag(t, estimate, truth)
        row[f"noise_{name}"] = estimate_noise(t, estimate, truth, scenario.score_from)
        row[f"straight_drift_{name}"] = straight_drift(recording, estimate)
    measured = np.asarray(recording["Gamma_d"])
    row["vaf_one_step"] = metrics.vaf(measured[mask], result.prediction[mask])
    inputs = np.column_stack(
        [recording[n] for n in ("theta_far", "theta_near", "delta_d", "Gamma_s")]
    )
    resimulated, _ = resimulate_driver(
        result.mean, inputs, recording.metadata["speed"], recording.dt
    )
    row["vaf_resimulated"] = metrics.vaf(measured[mask], resimulated[mask])
    clean = np.asarray(recording["Gamma_d_true"]) if "Gamma_d_true" in recording else measured
    if "u_n" in recording:
        clean = clean - np.asarray(recording["u_n"])
    row["vaf_resimulated_ideal"] = metrics.vaf(clean[mask], resimulated[mask])
    within_1, within_2 = metrics.innovation_fractions(
        result.innovation[mask], result.innovation_variance[mask]
    )
    row["innovations_within_1sigma"] = within_1
    row["innovations_within_2sigma"] = within_2
    moving = metrics.moving_vaf(
        measured[mask], result.prediction[mask], recording.dt, MOVING_WINDOW
    )
    step = max(round(1.0 / recording.dt), 1)
    row["moving_vaf"] = [float(v) for v in moving[::step]]
    row["moving_vaf_t"] = [float(v) for v in t[mask][::step]]
    row["diverged"] = bool(result.health.diverged)
    row["divergence_time"] = result.health.divergence_time
    row["remnant_power_ratio"] = recording.metadata.get("remnant_power_ratio")
    row["max_lateral_offset"] = recording.metadata.get("max_lateral_offset")
    row["lane_departure"] = bool(recording.metadata.get("lane_departure"))
    return row
