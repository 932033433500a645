"""The schiess-roland1975 suite: its scenarios, their simulation, the paper's report section."""

import re
import sys

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

import importlib.resources

import numpy as np
import pytest

from manualcontrol.bench.papers.schiess_roland1975 import TABLE_VI, report_section
from manualcontrol.bench.report import write_report
from manualcontrol.bench.runner import run_suite, simulate_scenario
from manualcontrol.bench.scenarios import SuiteError, load_suite, parse_suite


def suite_table():
    text = importlib.resources.files("manualcontrol.bench").joinpath(
        "suites", "schiess-roland1975.toml"
    )
    return tomllib.loads(text.read_text())


def test_the_suite_has_the_papers_cases():
    suite = load_suite("schiess-roland1975")
    names = [batch.name for batch in suite.batches]
    assert names[:4] == ["case-1", "case-2", "case-3", "case-4"]
    assert len(suite.scenarios()) == 20 * len(names) and len(suite.scenarios(quick=True)) == len(
        names
    )
    case_4 = suite.batch("case-4")
    assert case_4.remnant_seeds == tuple(range(20))
    assert case_4.estimators[0]["passes"] == 3
    assert case_4.template["pilot"]["remnant"]["noise_variance"] == 25.0
    # case 2 runs on case 1's data
    one, two = (suite.batch(name).template for name in ("case-1", "case-2"))
    assert {k: v for k, v in one.items() if k != "estimator"} == {
        k: v for k, v in two.items() if k != "estimator"
    }


def test_scenario_simulation_starts_from_table_i():
    scenario = load_suite("schiess-roland1975").scenarios(quick=True)[0]
    recording = simulate_scenario(scenario)
    assert recording.t[0] == 0.25 and len(recording) == 1000
    assert recording.metadata["measurement_noise"] == {"y": 0.00092, "u": 0.00092}
    assert list(recording.metadata["initial_state"]["n"]) == [0.4105, 2.5484]
    assert recording.n[0] == pytest.approx(0.4105, abs=1e-12)  # n carries no measurement noise
    assert abs(recording.y[0] + 0.959) < 0.15  # c plus noise of standard deviation 0.03


def test_other_suites_keep_their_scenario_keys():
    scenario = load_suite("popovici2017").scenarios(quick=True)[0]
    data = scenario.to_dict()
    assert not {"start_time", "measurement_noise", "initial_state"} & set(data)
    ours = load_suite("schiess-roland1975").scenarios(quick=True)[0].to_dict()
    assert ours["start_time"] == 0.25 and ours["measurement_noise"]["u"] == 0.00092


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"measurement_noise": {"n": 0.1}}, "measurement_noise got unknown key(s) 'n'"),
        ({"measurement_noise": {"u": -1.0}}, "measurement_noise.u must be >= 0, got -1.0"),
        ({"initial_state": {"y": []}}, "initial_state.y must have at least 1 entries, got 0"),
        ({"initial_state": [1.0]}, "initial_state must be a table of signal = [value, rate, ...]"),
        ({"start_time": "soon"}, "start_time must be a real number, got 'soon'"),
    ],
)
def test_bad_suite_entries_name_the_batch(change, message):
    table = suite_table()
    table["batch"] = [{**table["batch"][0], **change}]
    with pytest.raises(SuiteError, match=re.escape("batch 1 (case-1): " + message)):
        parse_suite(table, "suite.toml")


def test_report_section_puts_ours_beside_tables_ii_iii_and_vi(tmp_path):
    table = suite_table()
    keep = {"case-4", "divergence-plain", "divergence-modified"}
    table["batch"] = [batch for batch in table["batch"] if batch["name"] in keep]
    for batch in table["batch"]:
        batch["remnant_seeds"] = [0, 1]
    suite = parse_suite(table, "test")
    rows = run_suite(suite, tmp_path, backend="inprocess")
    assert {row["status"] for row in rows} == {"ok"}
    lines = report_section(suite, rows, tmp_path)
    text = "\n".join(lines)
    assert "### case-4 (2 seeds" in text and "| K_1 | 1 | 0.9843 |" in text
    assert re.search(r"At least as close to the truth as the paper \(✓\): \*\*\d of 7\*\*", text)
    # Table VI from the paper's own parameter sets: within 0.05 of the printed values
    differences = re.findall(r"\| paper, [a-z ,0-9]+ \| .* \| ([0-9.]+) \|", text)
    assert len(differences) == len(TABLE_VI) and max(map(float, differences)) <= 0.05
    assert "| truth (Table I) | -38.843, -18.072, -2.670" in text
    plain = re.search(r"\| divergence-plain \| 2 \| ([0-9.]+) \| (\d+)% \|", text)
    modified = re.search(r"\| divergence-modified \| 2 \| ([0-9.]+) \| (\d+)% \|", text)
    assert float(plain.group(1)) > 5 * float(modified.group(1)) and int(plain.group(2)) > 50
    report = write_report(suite, rows, tmp_path).read_text()
    assert "## Schiess & Roland (1975): Tables II, III and VI" in report
    assert np.isfinite([float(d) for d in differences]).all()
