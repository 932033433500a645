"""Scores of one benchmark run: the thesis's performance metrics (Part I Sec. IV-E).

Computed by :func:`manualcontrol.estimators.analysis.metrics.evaluate` from
``scenario.score_from`` on (``t >= 0`` by default: the run-in before it lets the
filter converge, as in the thesis; Popovici et al. leave out the first 15 s of runs
without run-in): per estimated parameter the relative bias and the NRMSE (eq. 37; RMSE
for near-zero parameters), the VAFs (eq. 38) and the innovation consistency. Added
here: the 10-s moving VAF of the one-step output (1-s steps, for the report's figure),
the run's health and the realised remnant power ratio.

Row columns of the VAFs (definitions in :mod:`manualcontrol.estimators.analysis.metrics`):

``vaf_one_step``
    the filter's one-step prediction against ``u`` as measured;
``vaf_resimulated``, ``vaf_resimulated_ceiling``
    the isolated model driven by the recorded perceptions, against ``u`` as measured,
    with the identified parameter traces and with the true ones (what a perfect
    estimator scores on this run);
``vaf_resimulated_ideal``, ``vaf_resimulated_ideal_ceiling``
    the isolated model driven by the remnant-free perceptions, against the
    remnant-free ``u - u_n`` (the thesis's Table III and IV VAF), identified and true
    traces.

How a run is judged the way a laboratory judges a human (added for the human-like
suite, in every row where they apply):

``frequency_gain_error_db``, ``frequency_phase_error_deg``
    the identified model's frequency response (parameters at their medians over the
    second half of the run) against the true pilot's (the true traces' second-half
    medians) at the forcing frequencies: mean absolute gain gap (dB) and phase gap
    (degrees, wrapped), over every perception channel of the model (the far view's
    with its preview ``exp(j w tau_f)``);
``max_time_at_limit``, ``parameter_at_limit``
    the largest share of the run any estimated parameter spends at a limit of the
    filter's projection, and which
    (:func:`~manualcontrol.estimators.analysis.fit_check.limit_shares`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from manualcontrol.bench.driving import score_lane_keeping
from manualcontrol.bench.scenarios import Scenario
from manualcontrol.envs.recording import Recording
from manualcontrol.envs.signals import ForcingPair, Multisine
from manualcontrol.estimators.analysis import metrics
from manualcontrol.estimators.analysis.fit_check import limit_shares, second_half_values
from manualcontrol.estimators.analysis.frequency import channel_responses

__all__ = ["score"]

MOVING_WINDOW = 10.0  # s, thesis Fig. 7


#: The ceilings of the last recording scored: every estimator of a scenario is scored
#: on the same recording one after the other, and the ceilings (true parameters) do
#: not depend on the estimator, only on the model structure.
_LAST_CEILINGS: list[Any] = []


def _ceilings(result: Any, recording: Recording, start: float) -> tuple[float, float]:
    if not metrics._has_pilot_model(result):
        return (math.nan, math.nan)  # an estimator with its own model (the RDI)
    model = metrics._model_of(result).name
    if _LAST_CEILINGS:
        seen, seen_model, seen_start, values = _LAST_CEILINGS[0]
        if seen is recording and seen_model == model and seen_start == start:
            return values
    values = metrics.vaf_ceilings(model, recording, start=start)
    _LAST_CEILINGS[:] = [(recording, model, start, values)]
    return values


def score(scenario: Scenario, recording: Recording, result: Any) -> dict[str, Any]:
    """The results-row entries of one run (see the module docstring)."""
    if scenario.task == "lane-keeping":
        return score_lane_keeping(scenario, recording, result)
    ceilings = _ceilings(result, recording, scenario.score_from)
    measured = metrics.evaluate(result, recording, start=scenario.score_from, ceilings=False)
    measured = dataclasses.replace(
        measured, resimulated_vaf_ceiling=ceilings[0], remnant_free_vaf_ceiling=ceilings[1]
    )
    window = np.asarray(recording.t) >= scenario.score_from - 1e-9
    row: dict[str, Any] = {}
    for name, value in measured.nrmse.items():
        row[f"nrmse_{name}"] = value
        row[f"rel_bias_{name}"] = measured.relative_bias[name]
    row["vaf_one_step"] = measured.one_step_vaf
    row["vaf_resimulated"] = measured.resimulated_vaf
    row["vaf_resimulated_ceiling"] = measured.resimulated_vaf_ceiling
    row["vaf_resimulated_ideal"] = measured.remnant_free_vaf
    row["vaf_resimulated_ideal_ceiling"] = measured.remnant_free_vaf_ceiling
    row["innovations_within_1sigma"] = measured.within_1_sigma
    row["innovations_within_2sigma"] = measured.within_2_sigma
    moving = metrics.moving_vaf(
        np.asarray(recording.u)[window],
        np.asarray(result.prediction)[window],
        recording.dt,
        MOVING_WINDOW,
    )
    step = max(round(1.0 / recording.dt), 1)
    row["moving_vaf"] = [float(v) for v in moving[::step]]
    row["moving_vaf_t"] = [float(v) for v in np.asarray(recording.t)[window][::step]]
    health = result.health
    row["smoothed"] = bool(getattr(result, "smoothed", False))
    row["diverged"] = bool(health.diverged)
    row["divergence_time"] = health.divergence_time
    row["remnant_power_ratio"] = recording.metadata.get("remnant_power_ratio")
    row.update(_frequency_errors(recording, result))
    shares = limit_shares(result)
    worst = max(shares, key=lambda name: shares[name][0], default=None)
    row["max_time_at_limit"] = shares[worst][0] if worst is not None else math.nan
    row["parameter_at_limit"] = worst if worst is not None and shares[worst][0] > 0 else ""
    return row


def _frequency_errors(recording: Recording, result: Any) -> dict[str, float]:
    """Identified against true frequency response at the forcing frequencies (see above)."""
    nothing = {"frequency_gain_error_db": math.nan, "frequency_phase_error_deg": math.nan}
    forcing = recording.metadata.get("forcing")
    if not metrics._has_pilot_model(result) or forcing is None:
        return nothing
    model = metrics._model_of(result)
    names = model.parameter_names
    if not all(name in recording.parameters for name in names):
        return nothing
    pair = ForcingPair.from_dict(forcing)
    omega = np.concatenate(
        [
            np.asarray(signal.frequencies)
            for signal in (pair.target, pair.disturbance)
            if isinstance(signal, Multisine)
        ]
    )
    if omega.size == 0:
        return nothing
    half = len(recording) // 2
    true = {name: float(np.median(recording.parameters[name][half:])) for name in names}
    found = second_half_values(result)
    if not all(math.isfinite(found[name]) for name in names):
        return nothing
    gains, phases = [], []
    truths = channel_responses(model, true, omega)
    estimates = channel_responses(model, found, omega)
    for channel in model.perceptions:
        truth, estimate = truths[channel], estimates[channel]
        if not np.any(truth):
            continue
        ratio = estimate / truth
        gains.append(np.abs(20.0 * np.log10(np.abs(ratio))))
        phases.append(np.abs(np.degrees(np.angle(ratio))))
    if not gains:
        return nothing
    return {
        "frequency_gain_error_db": float(np.mean(np.concatenate(gains))),
        "frequency_phase_error_deg": float(np.mean(np.concatenate(phases))),
    }
