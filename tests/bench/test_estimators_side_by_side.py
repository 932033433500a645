"""Several estimators a batch: one simulation each, rows keyed by estimator, a joint report."""

import json
import re
import warnings

import pytest

from manualcontrol.bench.cli import EXIT_OK, EXIT_USAGE, main
from manualcontrol.bench.report import write_report
from manualcontrol.bench.runner import run_suite
from manualcontrol.bench.scenarios import SuiteError, load_suite, parse_suite
from manualcontrol.estimators.members.pilot_filter import GenericValuesWarning
from manualcontrol.pilots import simulation

SUITE = {
    "name": "three",
    "defaults": {"run_in": 3.0, "measurement_time": 12.0},
    "batch": [
        {
            "name": "comp",
            "task": "compensatory",
            "element": "popovici2017",
            "forcing": "popovici2017",
            "realisations": [0, 1],
            "pilot": {"model": "precision"},
            "estimator": {"model": "precision", "preset": "vertregt2020"},
            "estimators": [
                {"name": "dekf", "total_derivative": "dimensional"},
                "joint-ukf",
                {"name": "dual-ukf", "r2_parameter": 2.0},
            ],
            "reference": {"source": "made up", "parameters": {"K_p": {"nrmse": 0.1}}},
        }
    ],
}


def test_each_run_is_simulated_once_and_read_by_every_estimator(tmp_path, monkeypatch):
    suite = parse_suite(SUITE)
    assert suite.batches[0].estimator_names == ("dekf", "joint-ukf", "dual-ukf")
    scenarios = suite.scenarios()
    assert len(scenarios) == 6
    assert len({s.simulation_key for s in scenarios}) == 2
    assert scenarios[0].estimator == {
        "model": "precision",
        "preset": "vertregt2020",
        "name": "dekf",
        "total_derivative": "dimensional",
    }
    simulated = []
    original = simulation.simulate

    def counting(*args, realisation, seed, **kwargs):
        simulated.append((realisation, seed))
        return original(*args, realisation=realisation, seed=seed, **kwargs)

    monkeypatch.setattr(simulation, "simulate", counting)
    rows = run_suite(suite, tmp_path, backend="inprocess")
    assert sorted(simulated) == sorted({(s.realisation, s.remnant_seed) for s in scenarios})
    assert [row["estimator"] for row in rows] == ["dekf", "joint-ukf", "dual-ukf"] * 2
    assert all(row["status"] == "ok" for row in rows), [row.get("error") for row in rows]
    keys = [row["key"] for row in rows]
    assert len(set(keys)) == 6 and all(f"-{row['estimator']}-" in row["key"] for row in rows)
    # the same recording: every estimator's stored scenario differs in its estimator only
    stored = [json.loads((tmp_path / "runs" / f"{k}.json").read_text()) for k in keys[:3]]
    for row in stored[1:]:
        assert {**row["scenario"], "estimator": None} == {
            **stored[0]["scenario"],
            "estimator": None,
        }
    report = write_report(suite, rows, tmp_path).read_text()
    assert "| NRMSE (rel. bias) | dekf | joint-ukf | dual-ukf | paper |" in report
    assert re.search(r"\| K_p \| .* \| 0\.100 \(—\) \|", report)
    assert "2 runs simulated, each identified by 3 estimators" in report
    assert (tmp_path / "figures" / "comp-estimators.png").is_file()


def test_the_estimators_of_a_suite_can_be_replaced():
    suite = load_suite("vertregt2020-feasibility")
    only = suite.with_estimators(["joint-ukf"])
    assert {batch.estimator_names for batch in only.batches} == {("joint-ukf",)}
    assert len(only.scenarios()) == len(suite.scenarios()) // 3
    # a listed estimator keeps its own settings
    dekf = suite.with_estimators(["dekf"]).batches[0].estimators[0]
    assert dekf["total_derivative"] == "dimensional"
    with pytest.raises(SuiteError, match="estimators names no estimator of the family: kalman"):
        suite.with_estimators(["kalman"])
    with pytest.raises(SuiteError, match="names one twice"):
        suite.with_estimators(["dekf", "dekf"])


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"estimator": {"name": "dekf"}}, "takes no name, got name = 'dekf'"),
        ({"estimators": []}, "estimators must be a non-empty list"),
        ({"estimators": ["dekf", "dekf"]}, "must not repeat a name, repeated: ['dekf']"),
        ({"estimators": [{"model": "precision"}]}, "estimators[0] needs a name"),
        ({"estimators": ["kalman"]}, "estimators[0] (kalman): estimator name must be one of"),
        (
            {"estimators": [{"name": "joint-ukf", "sigma_points": "many"}]},
            "estimators[0] (joint-ukf): sigma_points must be one of",
        ),
        (
            {"estimators": [{"name": "joint-ukf", "total_derivative": "printed"}]},
            "total_derivative",
        ),
    ],
)
def test_bad_estimator_lists_name_the_batch_and_entry(change, message):
    batch = {**SUITE["batch"][0], **change}
    with pytest.raises(SuiteError, match=re.escape(message)) as error:
        parse_suite({**SUITE, "batch": [batch]})
    assert "batch 1 (comp)" in str(error.value)


def test_the_cli_lists_the_family_and_overrides_a_suites_estimators(tmp_path, capsys):
    assert main(["estimators"]) == EXIT_OK
    out = capsys.readouterr().out
    for name in ("dekf", "joint-ukf", "dual-ukf"):
        assert re.search(rf"^{name} +\S", out, re.MULTILINE)
    code = main(
        [
            "bench",
            "vertregt2020-feasibility",
            "--estimators",
            "dekf,kalman",
            "--out",
            str(tmp_path / "x"),
        ]
    )
    assert code == EXIT_USAGE
    assert "--estimators: estimators names no estimator of the family: kalman" in (
        capsys.readouterr().err
    )
    assert not (tmp_path / "x").exists()


def test_identify_refuses_a_pilot_model_for_an_estimator_with_its_own(tmp_path, capsys):
    from manualcontrol.pilots import Pilot, simulate

    recording = simulate(Pilot("precision"), "popovici2017", "popovici2017", measurement_time=10.0)
    path = recording.save(tmp_path / "run.npz")
    code = main(
        [
            "identify",
            str(path),
            "--estimator",
            "rdi",
            "--model",
            "preview",
            "--out",
            str(tmp_path / "out"),
        ]
    )
    assert code == EXIT_USAGE
    assert "the rdi estimator has its own model" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
    code = main(["identify", str(path), "--estimator", "kalman", "--out", str(tmp_path / "o2")])
    assert code == EXIT_USAGE
    assert "--estimator must be one of dekf" in capsys.readouterr().err


def test_identify_runs_the_rml_and_its_smoothed_twin_on_a_pilot_model(tmp_path, capsys):
    from manualcontrol.estimators import load_result
    from manualcontrol.pilots import Pilot, simulate

    recording = simulate(Pilot("precision"), "popovici2017", "popovici2017", measurement_time=20.0)
    path = recording.save(tmp_path / "run.npz")
    for name in ("rml", "rml-smoothed"):
        out = tmp_path / name
        code = main(
            ["identify", str(path), "--estimator", name, "--model", "precision", "--out", str(out)]
        )
        assert code == EXIT_OK, capsys.readouterr().err
        saved = sorted(out.glob("*.npz"))
        assert saved, list(out.iterdir())
        result = load_result(saved[0])
        assert result.estimator == "rml" and result.smoothed == (name != "rml")


def test_identify_reports_the_cross_validated_scale(tmp_path, capsys):
    from manualcontrol.pilots import Pilot, simulate

    recording = simulate(Pilot("precision"), "popovici2017", "popovici2017", measurement_time=30.0)
    path = recording.save(tmp_path / "run.npz")
    out = tmp_path / "cv"
    command = ["identify", str(path), "--estimator", "dekf-cv", "--out", str(out)]
    code = main([*command, "--set", "cv_scales=[0.5,2.0]", "--set", "cv_folds=2"])
    printed = capsys.readouterr().out
    assert code == EXIT_OK
    summary = json.loads((out / "summary.json").read_text())
    chosen = summary["cross_validation"]
    assert chosen["scales"] == [0.5, 2.0] and chosen["folds"] == 2
    assert chosen["scale"] == chosen["scales"][chosen["errors"].index(min(chosen["errors"]))]
    assert f"process noise: the filter's Q x{chosen['scale']:g}" in printed
    # without a forcing to set the band, a usage error that names both ways to give one
    bare = type(recording)({n: recording[n] for n in recording.signal_names}, recording.dt)
    bare_path = bare.save(tmp_path / "bare.npz")
    bare_command = ["identify", str(bare_path), "--estimator", "dekf-cv", "--set", "cv_folds=2"]
    code = main([*bare_command, "--out", str(tmp_path / "b")])
    assert code == EXIT_USAGE
    assert "--forcing PRESET" in capsys.readouterr().err
    assert not (tmp_path / "b").exists()


def test_identify_reports_the_change_a_sigmoid_fit_found(tmp_path, capsys):
    from manualcontrol.envs.schedules import Sigmoid
    from manualcontrol.pilots import Pilot, simulate

    pilot = Pilot("precision", {"K_p": Sigmoid(1.5, 0.8, 12.0, 4.0), "K_v": 0.5})
    recording = simulate(
        pilot, "popovici2017", "popovici2017", measurement_time=24.0, loop="sampled"
    )
    path = recording.save(tmp_path / "run.npz")
    out = tmp_path / "sigmoid"
    command = ["identify", str(path), "--estimator", "sigmoid-fit", "--out", str(out)]
    code = main([*command, "--set", "starts=1", "--set", 'estimated=["K_p","K_v"]'])
    captured = capsys.readouterr()
    printed = captured.out
    assert code == EXIT_OK
    found = json.loads((out / "summary.json").read_text())["sigmoid"]
    # remnant-free, sampled loop, the pilot's own structure: the change found but for
    # what the model's start at rest leaves (the loop had run in; well under 1 %)
    assert found["t_mid"] == pytest.approx(12.0, abs=0.1)
    assert found["start"]["K_p"] == pytest.approx(1.5, rel=1e-2)
    assert found["end"]["K_p"] == pytest.approx(0.8, rel=1e-2)
    assert "change: inflection at 12.00 s" in printed and "K_p 1.5 -> 0.8" in printed
    assert found["warnings"] == [] and "warning" not in captured.err
    assert "no one-step prediction" in printed, printed
    # scored from the first sample, where the model's start at rest costs most of the 1 %
    resimulated = json.loads((out / "summary.json").read_text())["fit"]["vaf_resimulated_percent"]
    assert resimulated > 99.0 and f"resimulated VAF {resimulated:.1f} %" in printed


def test_identify_reports_which_pass_a_restarted_filter_kept(tmp_path, capsys):
    from manualcontrol.pilots import Pilot, simulate

    pilot = Pilot("precision", {"K_p": 1.5, "K_v": 0.5})
    recording = simulate(pilot, "popovici2017", "popovici2017", measurement_time=30.0)
    path = recording.save(tmp_path / "run.npz")
    out = tmp_path / "restarts"
    command = ["identify", str(path), "--estimator", "rml-smoothed", "--out", str(out)]
    code = main([*command, "--set", "restarts=1", "--set", 'initial={"K_p": 0.6}'])
    printed = capsys.readouterr().out
    assert code == EXIT_OK
    record = json.loads((out / "summary.json").read_text())["restarts"]
    assert len(record["initial"]) == len(record["innovation_cost"]) == 2
    assert record["initial"][0]["K_p"] == 0.6 and record["ended"] == ""
    kept = record["chosen"] + 1
    costs = ", ".join(f"{cost:.4f}" for cost in record["innovation_cost"])
    assert f"restarts: pass {kept} of 2 kept (innovation cost of each pass {costs}" in printed
    assert (
        f"standard errors against the pass kept before it: {record['evidence'][1]:+.1f})" in printed
    )
    # without restarts nothing is said
    main(["identify", str(path), "--estimator", "rml-smoothed", "--out", str(tmp_path / "one")])
    assert "restarts" not in capsys.readouterr().out
    assert "restarts" not in json.loads((tmp_path / "one" / "summary.json").read_text())


def test_identify_says_which_held_parameters_sit_at_generic_values(tmp_path, capsys):
    from manualcontrol.pilots import Pilot, simulate

    recording = simulate(Pilot("precision"), "popovici2017", "popovici2017", measurement_time=20.0)
    path = recording.save(tmp_path / "run.npz")
    base = ["identify", str(path), "--estimator", "dekf"]
    held = ["--set", 'estimated=["K_p","K_v"]', "--set", 'initial={"tau_v": 0.25}']
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main([*base, *held, "--out", str(tmp_path / "held")]) == EXIT_OK
    printed = capsys.readouterr().out
    # tau_v was given; the neuromuscular parameters took Popovici's eqs. 29-30
    assert "held at the generic starting values, not estimated: omega_nms 10, zeta_nms 0.3;" in (
        printed
    )
    # said once, with the values: not again by the library's warning
    assert not [w for w in caught if issubclass(w.category, GenericValuesWarning)]
    summary = json.loads((tmp_path / "held" / "summary.json").read_text())
    assert summary["held_at_generic_values"] == {"omega_nms": 10.0, "zeta_nms": 0.3}
    # every parameter estimated, or held by the single integrator's rule: nothing to say
    assert main([*base, "--set", "ce=SI", "--out", str(tmp_path / "si")]) == EXIT_OK
    assert "generic starting values" not in capsys.readouterr().out
    assert "held_at_generic_values" not in (tmp_path / "si" / "summary.json").read_text()
