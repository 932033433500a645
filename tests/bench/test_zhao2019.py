"""The zhao2019 suite: lane-keeping batches, their scores, the paper's section."""

import dataclasses
import re

import numpy as np
import pytest

from manualcontrol.bench.driving import estimate_lag, estimate_noise, straight_drift
from manualcontrol.bench.papers import section_writer
from manualcontrol.bench.report import write_report
from manualcontrol.bench.runner import run_scenario, simulate_scenario
from manualcontrol.bench.scenarios import SuiteError, load_suite, parse_suite
from manualcontrol.envs.recording import Recording


@pytest.fixture(scope="module")
def suite():
    return load_suite("zhao2019")


def _scenario(suite, batch, **changes):
    scenario = next(s for s in suite.scenarios(quick=True) if s.batch == batch)
    return dataclasses.replace(scenario, **changes)


def test_the_suite_has_three_drives_three_members_and_three_conditions(suite):
    references = [dict(batch.reference) for batch in suite.batches]
    assert {r["drive"] for r in references} == {"kp-rising", "kc-rising", "both-rising"}
    assert {r["member"] for r in references} == {"UKF1", "UKF2", "multi-UKF"}
    assert len(suite.batches) == 24 and len(suite.scenarios()) == 84
    drive = simulate_scenario(_scenario(suite, "both-rising-ukf1"))
    assert drive.duration > 220.0  # 200 s or more at 100 Hz
    assert drive.dt == 0.01 and drive.metadata["speed"] == pytest.approx(64 / 3.6)
    assert drive.parameters["K_p"][-1] / drive.parameters["K_p"][0] == pytest.approx(1.3)


def test_a_lane_keeping_run_is_scored(suite, tmp_path):
    scenario = _scenario(suite, "both-rising-noise-multi", measurement_time=60.0)
    row = run_scenario(scenario, tmp_path)
    assert row["status"] == "ok", row.get("error")
    for key in ("nrmse_K_p", "lag_K_p", "noise_K_c", "straight_drift_K_c", "vaf_resimulated"):
        assert np.isfinite(row[key]), key
    assert row["estimator"] == "zhao-multi-ukf" and row["vaf_one_step"] > 99.0
    assert (tmp_path / "runs" / f"{scenario.key}.npz").is_file()


def test_ukf2_reacts_faster_and_is_noisier_and_the_multi_ukf_beats_both(suite, tmp_path):
    """Done when (sensor-noise drive, both parameters rising, one seed)."""
    rows = {
        member: run_scenario(_scenario(suite, f"both-rising-noise-{member}"))
        for member in ("ukf1", "ukf2", "multi")
    }
    for name in ("K_p", "K_c"):
        assert rows["ukf2"][f"lag_{name}"] < rows["ukf1"][f"lag_{name}"]
        assert rows["ukf2"][f"noise_{name}"] > 2 * rows["ukf1"][f"noise_{name}"]
        best_member = min(rows["ukf1"][f"nrmse_{name}"], rows["ukf2"][f"nrmse_{name}"])
        assert rows["multi"][f"nrmse_{name}"] < best_member


def test_the_lag_search_equals_one_lag_at_a_time():
    def one_at_a_time(t, estimate, truth):  # the search as first written
        changing = np.flatnonzero(np.abs(np.diff(truth)) > 1e-12 * max(1.0, abs(truth[0])))
        window = (t >= t[changing[0]] - 5.0) & (t <= t[changing[-1] + 1] + 20.0)
        ok = window & np.isfinite(estimate)
        best, best_lag = np.inf, float("nan")
        for lag in np.arange(0.0, 20.0 + 1e-9, 0.05):
            shifted = np.interp(t[ok] - lag, t, truth)
            rms = float(np.sqrt(np.mean((estimate[ok] - shifted) ** 2)))
            if rms < best - 1e-15:
                best, best_lag = rms, float(lag)
        return best_lag

    rng = np.random.default_rng(4)
    t = np.arange(0.0, 120.0, 0.01)
    for seed in range(4):
        truth = np.interp(t, [40.0, 40.0 + 10 * (seed + 1)], [2.0, 3.0 + seed])
        estimate = np.interp(t - 0.7 * seed, t, truth) + 0.2 * rng.standard_normal(t.size)
        estimate[rng.integers(0, t.size, 50)] = np.nan
        assert estimate_lag(t, estimate, truth) == one_at_a_time(t, estimate, truth)


def test_lag_noise_and_straight_metrics_on_known_signals():
    t = np.arange(0.0, 100.0, 0.01)
    truth = np.interp(t, [30.0, 50.0], [1.0, 2.0])
    delayed = np.interp(t - 1.5, [30.0, 50.0], [1.0, 2.0])
    assert estimate_lag(t, delayed, truth) == pytest.approx(1.5)
    assert np.isnan(estimate_lag(t, delayed, np.ones_like(t)))
    rng = np.random.default_rng(0)
    noisy = truth + 0.01 * rng.standard_normal(t.size)
    # white noise about its 200-sample moving average keeps (1 - 1/200) of its variance
    expected = 0.01 * np.sqrt(1 - 1 / 200) / np.mean(truth)
    assert estimate_noise(t, noisy, truth, 0.0) == pytest.approx(expected, rel=0.02)
    angles = np.where((t > 40) & (t < 60), 0.0, 0.05)
    recording = Recording(
        signals={"t": t, "theta_far": angles, "theta_near": np.where(t < 41.0, 0.01, 0.0)},
        dt=0.01,
    )
    estimate = np.where(t > 50.0, 1.03, 1.0)
    assert straight_drift(recording, estimate) == pytest.approx(0.03)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"element": {"wheels": 4}}, "element has unknown key(s) ['wheels']"),
        ({"forcing": "bumpy"}, "forcing (road) must be one of 'zhao2019', 'straight', got 'bumpy'"),
        ({"realisations": [0, 1]}, "realisations must be [0] for the fixed road 'zhao2019'"),
        ({"available_preview": 1.0}, "available_preview does not apply to lane keeping"),
        ({"measurement_time": 500.0}, "measurement_time must fit the road"),
        (
            {"pilot": {"model": "cybernetic-driver", "parameters": {"K_x": 1.0}}},
            "pilot: the cybernetic driver has no",
        ),
        (
            {"estimator": {"name": "zhao-ukf", "preset": "ukf9"}},
            "estimator (zhao-ukf): preset must be one of",
        ),
        (
            {"element": {"output_noise": {"y_L": 0.1}}},
            "output_noise keys must be 'Gamma_d' or 'delta_sw'",
        ),
    ],
)
def test_bad_lane_keeping_batches_are_named(change, message):
    batch = {
        "name": "drive",
        "task": "lane-keeping",
        "element": "mid-size",
        "forcing": "zhao2019",
        "realisations": [0],
        "pilot": {"model": "cybernetic-driver"},
        "estimator": {"name": "zhao-ukf"},
        **change,
    }
    with pytest.raises(SuiteError, match=re.escape(message)):
        parse_suite({"name": "s", "batch": [batch]})


def test_the_paper_section(suite, tmp_path):
    scenarios = [
        _scenario(suite, f"kp-rising-{member}", measurement_time=30.0)
        for member in ("ukf1", "ukf2", "multi")
    ]
    rows = [run_scenario(scenario, tmp_path) for scenario in scenarios]
    assert section_writer("zhao2019") is not None
    report = write_report(suite, rows, tmp_path).read_text()
    assert "rad/s (the paper: about -1, -10, -50)" in report
    assert "| kp-rising | multi-UKF |" in report
    assert (tmp_path / "figures" / "zhao2019-kp-rising-remnant-free.png").is_file()
