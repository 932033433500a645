"""Scores of a run and the report's own numbers, against values computed by hand."""

import math

import numpy as np
import pytest

from manualcontrol.bench.report import best_estimators, summarise, write_report
from manualcontrol.bench.runner import simulate_scenario
from manualcontrol.bench.scenarios import parse_suite
from manualcontrol.bench.scoring import score
from manualcontrol.estimators.analysis import metrics
from manualcontrol.estimators.registry import make_estimator

SHORT = {
    "name": "short",
    "defaults": {"run_in": 5.0, "measurement_time": 20.0},
    "batch": [
        {
            "name": "comp",
            "task": "compensatory",
            "element": "popovici2017",
            "forcing": "popovici2017",
            "realisations": [0],
            "remnant_seeds": [2],
            "pilot": {"model": "precision", "remnant": "popovici2017"},
            "estimator": {"name": "dekf", "model": "precision", "preset": "vertregt2020"},
        },
        {
            "name": "other",
            "task": "compensatory",
            "element": "popovici2017",
            "forcing": "popovici2017",
            "realisations": [0],
            "pilot": {"model": "precision"},
            "estimator": {"name": "dekf", "model": "precision", "preset": "vertregt2020"},
        },
    ],
}


def test_a_row_holds_every_vaf_beside_its_ceiling_as_evaluate_computes_them():
    suite = parse_suite(SHORT)
    scenario = suite.scenarios()[0]
    recording = simulate_scenario(scenario)
    assert {"u_n", "y_n"} <= set(recording.signal_names)
    result = make_estimator(scenario.estimator).estimate(recording)
    row = score(scenario, recording, result)
    measured = metrics.evaluate(result, recording, start=scenario.score_from)
    assert row["vaf_one_step"] == measured.one_step_vaf
    assert row["vaf_resimulated"] == measured.resimulated_vaf
    assert row["vaf_resimulated_ceiling"] == measured.resimulated_vaf_ceiling
    assert row["vaf_resimulated_ideal"] == measured.remnant_free_vaf
    assert row["vaf_resimulated_ideal_ceiling"] == measured.remnant_free_vaf_ceiling
    for name in result.estimated:
        assert row[f"nrmse_{name}"] == measured.nrmse[name]
        assert row[f"rel_bias_{name}"] == measured.relative_bias[name]
    assert row["smoothed"] is False
    # the remnant-free ceiling: the true pilot reproduces the remnant-free run (up to
    # holding its perceptions over each sample), the ceiling against u does not
    assert row["vaf_resimulated_ideal_ceiling"] > 99.9
    assert row["vaf_resimulated_ceiling"] < 95.0
    mask = recording.t >= scenario.score_from
    free = np.asarray(recording.u) - np.asarray(recording["u_n"])
    model = metrics.resimulate(result, recording, remnant_free=True)
    assert row["vaf_resimulated_ideal"] == pytest.approx(
        100 * (1 - np.sum((free - model)[mask] ** 2) / np.sum(free[mask] ** 2))
    )


def _row(batch, estimator, nrmse_K_p, nrmse_K_v, bias_K_p, vaf, ceiling, smoothed=False):
    return {
        "key": f"{batch}-{estimator}-{nrmse_K_p}",
        "batch": batch,
        "estimator": estimator,
        "status": "ok",
        "nrmse_K_p": nrmse_K_p,
        "rel_bias_K_p": bias_K_p,
        "nrmse_K_v": nrmse_K_v,
        "rel_bias_K_v": 0.0,
        "vaf_resimulated": vaf,
        "vaf_resimulated_ceiling": ceiling,
        "vaf_resimulated_ideal": vaf + 10.0,
        "vaf_resimulated_ideal_ceiling": 99.99,
        "vaf_one_step": 90.0,
        "smoothed": smoothed,
        "diverged": False,
    }


ROWS = [
    _row("comp", "a", 0.10, 0.20, -0.05, 70.0, 79.0),
    _row("comp", "a", 0.30, 0.20, +0.15, 72.0, 81.0),
    _row("comp", "b", 0.10, 0.10, +0.05, 60.0, 79.0),
    _row("comp", "b", 0.10, 0.10, +0.05, 62.0, 81.0),
    _row("comp", "c", 0.05, 0.05, 0.0, 75.0, 79.0, smoothed=True),
    _row("comp", "c", 0.05, 0.05, 0.0, 75.0, 81.0, smoothed=True),
    _row("other", "a", 0.01, 0.01, 0.0, 95.0, 99.0),
    _row("other", "b", 0.015, 0.015, 0.0, 95.0, 99.0),
]


def test_summaries_are_the_means_of_the_rows():
    summary = summarise(ROWS, "comp", "a")
    assert summary["runs"] == 2 and summary["failed"] == 0
    assert summary["parameters"]["K_p"] == {"rel_bias": pytest.approx(0.05), "nrmse": 0.2}
    assert summary["vaf_resimulated"] == 71.0
    assert summary["vaf_resimulated_ceiling"] == 80.0
    assert summary["smoothed"] is False and summarise(ROWS, "comp", "c")["smoothed"] is True


def test_the_best_online_and_smoothed_estimators_are_named():
    suite = parse_suite(SHORT)
    lines = best_estimators(suite, ROWS)
    text = "\n".join(lines)
    # comp: a scores (0.2 + 0.2)/2 = 0.2, b (0.1 + 0.1)/2 = 0.1: b; the smoothed c apart
    assert "| comp | b (0.100) | c (0.050) |" in text
    assert "| other | a (0.010) | — |" in text
    # a and b win one batch each; b is closer to the best where it loses (0.015/0.01 =
    # 1.5 against a's 0.2/0.1 = 2), so b is the suite's best online estimator
    assert "**Best online estimator of the suite: b** (best in 1 of 2 batches)." in text
    assert "**Best smoothed estimator of the suite: c** (best in 1 of 1 batches)." in text


def test_the_report_prints_the_ceilings_and_the_ranking(tmp_path):
    suite = parse_suite(SHORT)
    report = write_report(suite, ROWS, tmp_path).read_text()
    assert "| ceiling (true parameters) [%] | 80.000 | 80.000 | 80.000 | |" in report
    assert "## Best estimator" in report
    assert math.isfinite(summarise(ROWS, "other", "b")["vaf_resimulated_ceiling"])
