"""A results folder belongs to one suite: running another suite into it is refused.

``bench other.toml --out <a suite's results>`` used to replace ``results.csv`` with the
other suite's rows and leave the old report and figures beside them. The same suite's
folder resumes as before; an empty, absent or result-free folder is used as it is.
"""

import copy
import json
import re

import pytest

from manualcontrol.bench import runner
from manualcontrol.bench.runner import run_suite
from manualcontrol.bench.scenarios import parse_suite

SUITE = {
    "name": "first",
    "defaults": {"run_in": 2.0, "measurement_time": 5.0},
    "batch": [
        {
            "name": "comp",
            "task": "compensatory",
            "element": "SI",
            "forcing": "vanderel-bw4",
            "realisations": [0],
            "pilot": {
                "model": "precision",
                "parameters": {
                    "K_p": 1.3,
                    "K_v": 0.0,
                    "tau_v": 0.26,
                    "omega_nms": 10.5,
                    "zeta_nms": 0.35,
                },
            },
            "estimator": {"name": "dekf", "model": "precision", "ce": "SI"},
        }
    ],
}


def suite_named(name, realisations=(0,)):
    data = copy.deepcopy(SUITE)
    data["name"] = name
    data["batch"][0]["realisations"] = list(realisations)
    return parse_suite(data)


def refusal(out, found, where, running):
    return re.escape(
        f"out folder {str(out)!r} holds results of suite {found} (its {where}), not of suite "
        f"{running} being run; writing there would mix the two suites' results (and leave "
        f"the other's report): choose another --out folder, or remove {str(out)!r} first"
    )


@pytest.fixture
def fake_runs(monkeypatch):
    """run_scenarios (alone and in groups) without simulating: a row per scenario, stored."""
    ran = []

    def fake(scenarios, out=None):
        rows = []
        for scenario in scenarios:
            row = {"key": scenario.key, "suite": scenario.suite, "status": "ok", "error": ""}
            if out is not None:
                (out / "runs" / f"{scenario.key}.json").write_text(json.dumps(row))
            ran.append(scenario.key)
            rows.append(row)
        return rows

    monkeypatch.setattr(runner, "run_scenarios", fake)
    monkeypatch.setattr(
        runner, "run_scenario_groups", lambda groups, out=None: (fake(g, out) for g in groups)
    )
    return ran


def test_another_suites_results_are_refused_and_left_as_they_were(tmp_path):
    out = tmp_path / "results"
    first = run_suite(suite_named("first"), out, backend="inprocess")
    assert first[0]["status"] == "ok", first[0].get("error")
    (out / "report.md").write_text("# first\n")
    table = (out / "results.csv").read_text()
    stored = sorted(p.name for p in (out / "runs").iterdir())
    with pytest.raises(ValueError, match=refusal(out, "'first'", "results.csv", "'second'")):
        run_suite(suite_named("second"), out, backend="inprocess")
    assert (out / "results.csv").read_text() == table
    assert sorted(p.name for p in (out / "runs").iterdir()) == stored
    assert (out / "report.md").read_text() == "# first\n"
    # the same suite resumes: nothing left to run, the same table
    calls = []
    again = run_suite(
        suite_named("first"), out, backend="inprocess", progress=lambda d, t, r: calls.append(d)
    )
    assert calls == [1] and again == first
    assert (out / "results.csv").read_text() == table


def test_an_interrupted_run_of_another_suite_is_read_from_its_stored_runs(tmp_path, fake_runs):
    out = tmp_path / "results"
    run_suite(suite_named("first", realisations=(0, 1)), out, backend="inprocess")
    (out / "results.csv").unlink()  # stopped before the table was written
    with pytest.raises(ValueError, match=refusal(out, "'first'", "runs/*.json", "'second'")):
        run_suite(suite_named("second"), out, backend="inprocess")
    assert not (out / "results.csv").exists()


def test_the_same_suite_resumes_and_runs_only_what_is_new(tmp_path, fake_runs):
    out = tmp_path / "results"
    run_suite(suite_named("first"), out, backend="inprocess")
    fake_runs.clear()
    rows = run_suite(suite_named("first", realisations=(0, 1)), out, backend="inprocess")
    assert len(rows) == 2 and len(fake_runs) == 1  # the new realisation only
    assert {row["suite"] for row in rows} == {"first"}


@pytest.mark.parametrize("kind", ["absent", "empty", "unrelated files", "table without suite"])
def test_a_folder_without_another_suites_results_is_used(tmp_path, fake_runs, kind):
    out = tmp_path / "results"
    if kind != "absent":
        out.mkdir()
    if kind == "unrelated files":
        (out / "notes.txt").write_text("mine\n")
        (out / "runs").mkdir()
        (out / "runs" / "broken.json").write_text("{not json")
    if kind == "table without suite":
        (out / "results.csv").write_text("a,b\n1,2\n")
    rows = run_suite(suite_named("second"), out, backend="inprocess")
    assert [row["suite"] for row in rows] == ["second"]
    assert "second" in (out / "results.csv").read_text()


def test_a_list_of_scenarios_is_checked_by_the_suites_they_name(tmp_path, fake_runs):
    out = tmp_path / "results"
    run_suite(suite_named("first"), out, backend="inprocess")
    with pytest.raises(ValueError, match=refusal(out, "'first'", "results.csv", "'second'")):
        run_suite(suite_named("second").scenarios(), out, backend="inprocess")
    # a mixed list that includes the folder's suite is its own (a resume of it)
    mixed = suite_named("first").scenarios() + suite_named("second").scenarios()
    assert len(run_suite(mixed, out, backend="inprocess")) == 2


def test_a_table_of_two_suites_names_the_foreign_one(tmp_path):
    out = tmp_path / "results"
    out.mkdir()
    (out / "results.csv").write_text("key,suite\na,first\nb,third\n")
    with pytest.raises(ValueError, match=refusal(out, "'third'", "results.csv", "'first'")):
        run_suite(suite_named("first"), out, backend="inprocess")
