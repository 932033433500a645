"""Scores of one benchmark run: the thesis's performance metrics (Part I Sec. IV-E).

Computed by :func:`manualcontrol.estimators.metrics.evaluate` from
``scenario.score_from`` on (``t >= 0`` by default: the run-in before it lets the
filter converge, as in the thesis; Popovici et al. leave out the first 15 s of runs
without run-in): per estimated parameter the relative bias and the NRMSE (eq. 37; RMSE
for near-zero parameters), the VAF of the one-step filter output and of the
resimulated pilot output (eq. 38), and the innovation consistency. Added here: the
10-s moving VAF of the one-step output (1-s steps, for the report's figure), the
run's health and the realised remnant power ratio.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from manualcontrol.bench.scenarios import Scenario
from manualcontrol.envs.recording import Recording
from manualcontrol.estimators import metrics

__all__ = ["score"]

MOVING_WINDOW = 10.0  # s, thesis Fig. 7


def score(scenario: Scenario, recording: Recording, result: Any) -> dict[str, Any]:
    """The results-row entries of one run (see the module docstring)."""
    if scenario.task == "lane-keeping":
        from manualcontrol.bench.driving import score_lane_keeping

        return score_lane_keeping(scenario, recording, result)
    measured = metrics.evaluate(result, recording, start=scenario.score_from)
    window = np.asarray(recording.t) >= scenario.score_from - 1e-9
    row: dict[str, Any] = {}
    for name, value in measured.nrmse.items():
        row[f"nrmse_{name}"] = value
        row[f"rel_bias_{name}"] = measured.relative_bias[name]
    row["vaf_one_step"] = measured.one_step_vaf
    row["vaf_resimulated"] = measured.resimulated_vaf
    row["vaf_resimulated_ideal"] = measured.ideal_resimulated_vaf
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
    row["diverged"] = bool(health.diverged)
    row["divergence_time"] = health.divergence_time
    row["remnant_power_ratio"] = recording.metadata.get("remnant_power_ratio")
    return row
