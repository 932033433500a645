"""What `manualcontrol identify` prints and writes, and how it treats its --out folder.

The summary names the estimator and its settings and, on a simulation, the errors
against the true parameters; the library speaks its keywords and the command its flags;
a result is written whole or not at all, and another estimator's result is not replaced
without --overwrite.
"""

import json

import numpy as np
import pytest

from manualcontrol.bench.cli import (
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_RUNS_FAILED,
    EXIT_USAGE,
    cli_words,
    main,
)
from manualcontrol.envs.recording import Recording
from manualcontrol.pilots import Pilot, simulate


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture(scope="module")
def simulation(tmp_path_factory):
    """A remnant-free run of the typical SI pilot, 60 s: it carries its true parameters."""
    path = tmp_path_factory.mktemp("sim") / "run.npz"
    simulate(Pilot.typical("precision", "SI"), "SI", "vanderel-bw4", measurement_time=60.0).save(
        path
    )
    return path


def listing(folder):
    return sorted(p.name for p in folder.iterdir())


def test_summary_names_the_estimator_its_settings_and_the_errors_against_the_truth(
    simulation, tmp_path, capsys
):
    out_dir = tmp_path / "o"
    code, out, err = run(
        capsys, "identify", simulation, "--estimator", "dekf", "--set", "estimated=K_p,K_v",
        "--out", out_dir,
    )  # fmt: skip
    assert code == EXIT_OK, err
    summary = json.loads((out_dir / "summary.json").read_text())
    assert summary["estimator"] == "dekf"
    assert summary["settings"]["model"] == "precision"
    assert summary["settings"]["estimated"] == ["K_p", "K_v"]  # the bare names, a tuple
    assert summary["settings"]["noise"]["window"] == 5.0
    truth = summary["truth"]
    assert set(truth["nrmse"]) == {"K_p", "K_v"} and truth["scored_from_s"] == 0.0
    assert truth["error_kind"] == {"K_p": "nrmse", "K_v": "rmse"}  # K_v's true mean is 0
    assert 0.0 <= truth["nrmse"]["K_p"] < 0.2
    line = next(x for x in out.splitlines() if x.startswith("against the simulation's true"))
    assert line.startswith(
        "against the simulation's true parameters (over the whole run): NRMSE K_p "
    )
    assert "K_v " in line and "(RMSE: its true mean is near 0)" in line
    assert f"{truth['nrmse']['K_p']:.3g}" in line


def test_a_trial_without_true_parameters_prints_no_truth(simulation, tmp_path, capsys):
    bare = Recording.load(simulation)
    bare = Recording(dict(bare.signals), bare.dt)  # no parameter traces, no metadata
    path = tmp_path / "bare.npz"
    bare.save(path)
    code, out, err = run(capsys, "identify", path, "--set", "ce=SI", "--out", tmp_path / "o")
    assert code == EXIT_OK, err
    assert "true parameters" not in out
    assert "truth" not in json.loads((tmp_path / "o" / "summary.json").read_text())


def test_the_one_step_vaf_says_when_scoring_began_and_whiteness_is_explained(
    simulation, tmp_path, capsys
):
    code, out, err = run(
        capsys, "identify", simulation, "--estimator", "joint-ukf", "--out", tmp_path / "o"
    )
    assert code == EXIT_OK, err
    fit = next(line for line in out.splitlines() if line.startswith("fit: "))
    vaf = float(fit.split("one-step VAF ")[1].split(" %")[0])
    assert vaf > 90.0  # the start-up transient (thousands of per cent below zero) left out
    assert "(from t = " in fit and "when the filter had settled" in fit
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["fit"]["one_step_scored_from_s"] > 0.0
    assert summary["estimator"] == "joint-ukf"
    # a remnant-free run: coloured innovations, and one line saying what that means
    assert summary["fit"]["innovation_lags_outside_95_percent"] > 0.2
    guide = out.splitlines()[out.splitlines().index(fit) + 1]
    assert guide.startswith("  (white innovations need u to be the model's output plus")
    assert "remnant-free simulation" in guide and "frequency-domain check" in guide


def test_identify_refuses_another_estimators_result_unless_overwrite(simulation, tmp_path, capsys):
    out_dir = tmp_path / "o"
    assert run(capsys, "identify", simulation, "--out", out_dir)[0] == EXIT_OK
    before = (out_dir / "summary.json").read_bytes()
    code, _, err = run(capsys, "identify", simulation, "--estimator", "dekf", "--out", out_dir)
    assert code == EXIT_USAGE
    assert (
        f"manualcontrol identify: error: --out {out_dir}: the folder holds a rml "
        "identification (its summary.json); writing a dekf identification there would "
        "replace it: give another --out folder, or pass --overwrite to replace it"
    ) in err
    assert (out_dir / "summary.json").read_bytes() == before
    # the same estimator again: replaced without asking
    assert run(capsys, "identify", simulation, "--out", out_dir)[0] == EXIT_OK
    code, _, err = run(
        capsys, "identify", simulation, "--estimator", "dekf", "--overwrite", "--out", out_dir
    )
    assert code == EXIT_OK, err
    assert json.loads((out_dir / "summary.json").read_text())["estimator"] == "dekf"
    assert listing(out_dir) == ["estimation.npz", "parameters.png", "summary.json"]
    assert listing(tmp_path) == ["o"]  # no staging folder left beside it
    # describe refuses an identification's folder too
    code, _, err = run(capsys, "describe", simulation, "--out", out_dir)
    assert code == EXIT_USAGE and "the folder holds a dekf identification" in err


def test_no_plot_writes_the_same_result_without_a_figure_and_removes_a_stale_one(
    simulation, tmp_path, capsys
):
    drawn, bare = tmp_path / "drawn", tmp_path / "bare"
    assert run(capsys, "identify", simulation, "--out", drawn)[0] == EXIT_OK
    code, out, err = run(capsys, "identify", simulation, "--no-plot", "--out", bare)
    assert code == EXIT_OK, err
    assert listing(bare) == ["estimation.npz", "summary.json"]
    assert "parameters.png" not in out and f"wrote {bare / 'estimation.npz'}" in out
    assert (bare / "summary.json").read_bytes() == (drawn / "summary.json").read_bytes()
    for name, values in np.load(drawn / "estimation.npz").items():
        assert values.tobytes() == np.load(bare / "estimation.npz")[name].tobytes(), name
    # over an earlier result with a figure: the figure, which no longer matches, goes
    (drawn / "notes.txt").write_text("mine")
    assert run(capsys, "identify", simulation, "--no-plot", "--out", drawn)[0] == EXIT_OK
    assert listing(drawn) == ["estimation.npz", "notes.txt", "summary.json"]


def test_describe_without_its_figure_writes_the_same_summary_and_removes_a_stale_one(
    simulation, tmp_path, capsys
):
    drawn, bare = tmp_path / "drawn", tmp_path / "bare"
    short = ("--method", "least-squares")  # the run is half of its forcing's period
    assert run(capsys, "describe", simulation, *short, "--out", drawn)[0] == EXIT_OK
    code, out, err = run(capsys, "describe", simulation, *short, "--no-plot", "--out", bare)
    assert code == EXIT_OK, err
    assert listing(bare) == ["summary.json"] and "bode.png" not in out
    assert (bare / "summary.json").read_bytes() == (drawn / "summary.json").read_bytes()
    assert run(capsys, "describe", simulation, *short, "--no-plot", "--out", drawn)[0] == EXIT_OK
    assert listing(drawn) == ["summary.json"]


def test_an_interrupted_identify_leaves_the_earlier_result_whole(
    simulation, tmp_path, capsys, monkeypatch
):
    from manualcontrol.bench import report

    out_dir = tmp_path / "o"
    (out_dir).mkdir()
    (out_dir / "notes.txt").write_text("mine")
    assert run(capsys, "identify", simulation, "--out", out_dir)[0] == EXIT_OK
    files = {name: (out_dir / name).read_bytes() for name in listing(out_dir)}

    def interrupted(*args, **kwargs):  # Ctrl-C while the figure is drawn, the rest written
        raise KeyboardInterrupt

    monkeypatch.setattr(report, "plot_estimation", interrupted)
    code, _, err = run(capsys, "identify", simulation, "--set", "estimated=K_p", "--out", out_dir)
    assert code == EXIT_INTERRUPTED
    assert err == (
        f"manualcontrol identify: interrupted (Ctrl-C); nothing was written (the earlier "
        f"result in {out_dir} is left as it was)\n"
    )
    assert {name: (out_dir / name).read_bytes() for name in listing(out_dir)} == files
    assert listing(tmp_path) == ["o"]


def test_a_still_stick_is_named_before_any_estimator_runs(simulation, tmp_path, capsys):
    recording = Recording.load(simulation)
    still = recording.with_signals(u=np.full(len(recording), 0.3))
    path = tmp_path / "still.npz"
    still.save(path)
    for command in ("identify", "describe"):
        code, _, err = run(capsys, command, path, "--out", tmp_path / command)
        assert code == EXIT_USAGE
        assert err == (
            f"manualcontrol {command}: error: {path}: u is constant (0.3 in all "
            f"{len(recording)} samples): the stick never moved; nothing can be identified "
            "(check that the column read as u is the stick's and that the trial was flown)\n"
        )
        assert not (tmp_path / command).exists()


def test_an_element_other_than_the_one_flown_is_said_before_the_results(
    simulation, tmp_path, capsys
):
    short = ("--method", "least-squares")  # the 60-s run is half a forcing period
    code, _, err = run(
        capsys, "describe", simulation, *short, "--element", "DI", "--out", tmp_path / "other"
    )
    first = err.splitlines()[0]
    assert first == (
        "manualcontrol describe: warning: --element DI (DoubleIntegrator(K=5)) differs from "
        "the element the recording was flown with (Integrator(K=1.5)); the identification "
        "uses --element"
    )
    # the same element written otherwise is the element flown: no warning
    code, _, err = run(
        capsys, "describe", simulation, *short, "--element", "1.5/s", "--out", tmp_path / "same"
    )
    assert code == EXIT_OK and "differs from the element" not in err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ("--set", 'initial={"K_p": nan}'),
            """--set initial=: '{"K_p": nan}' is not valid JSON (Expecting value at """
            """character 9); JSON writes strings in double quotes and has no nan or inf: """
            """where a setting allows infinity give the string "inf" or "-inf" """,
        ),
        (("--set", "estimated=[K_p"), "--set estimated=: '[K_p' is not valid JSON"),
        (
            ("--estimator", "rml-cv", "--set", "bogus=1"),
            "--set bogus: the rml-cv estimator has no such setting; its settings: P0, ",
        ),
        (("--set", "estimated=K_p,K_x"), "K_x"),
    ],
)
def test_set_mistakes_are_said_in_the_command_lines_words(
    simulation, tmp_path, capsys, argv, message
):
    code, _, err = run(capsys, "identify", simulation, *argv, "--out", tmp_path / "o")
    assert code == EXIT_USAGE
    assert message in err and "Traceback" not in err
    assert "from_dict" not in err and "Settings" not in err
    assert not (tmp_path / "o").exists()


def test_the_cross_validated_twins_list_their_own_keys(simulation, tmp_path, capsys):
    code, _, err = run(
        capsys, "identify", simulation, "--estimator", "rml-cv", "--set", "cv_fold=3",
        "--out", tmp_path / "o",
    )  # fmt: skip
    assert code == EXIT_USAGE
    assert "cv_scales, cv_folds, cv_gap, cv_band" in err


def test_a_bare_name_gives_a_tuple_of_names(simulation, tmp_path, capsys):
    code, out, err = run(
        capsys, "identify", simulation, "--set", "estimated=K_p", "--out", tmp_path / "o"
    )
    assert code in (EXIT_OK, EXIT_RUNS_FAILED), err  # K_p alone may not close a stable loop
    assert out.startswith("estimated K_p; final values")
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["estimated"] == ["K_p"]


def test_identify_help_documents_its_exit_codes(capsys):
    code, out, _ = run(capsys, "identify", "--help")
    out = " ".join(out.split())
    assert code == EXIT_OK
    assert "Exit codes: 0 identified and written; 2 a usage or input error" in out
    assert "3 written, but the filter diverged" in out and "130 interrupted with Ctrl-C" in out
    assert "--set estimated=K_p,K_v" not in out and "estimated=K_p,K_v (a bare name" in out


# ------------------------------------------------- the library's words, the CLI's flags


@pytest.mark.parametrize(
    ("library", "command", "cli"),
    [
        (
            "not checked: the forcing frequencies are unknown (give forcing= or period=, the "
            "forcing signals being in the recording)",
            "identify",
            "not checked: the forcing frequencies are unknown (give --forcing PRESET or "
            "--period SECONDS, the forcing signals being in the recording)",
        ),
        (
            "not checked: no controlled element known (give element=)",
            "identify",
            "not checked: no controlled element known (give --element)",
        ),
        ("pass dt= to build the time axis", "describe", "pass --dt SECONDS to build the time axis"),
        (
            "it looks like milliseconds: pass time_unit='ms'",
            "identify",
            "it looks like milliseconds: pass --time-unit ms",
        ),
        (
            "or give initial={'K_p': ...}",
            "identify",
            """or give --set initial='{"K_p": ...}'""",
        ),
        (
            "limits='human' derives the gain limits from the controlled element: give element=",
            "identify",
            "--set limits=human derives the gain limits from the controlled element: give "
            "--element",
        ),
        (
            "online give start='generic' or the values (initial=)",
            "identify",
            "online give --set start=generic or the values (--set initial=...)",
        ),
        (
            "the identified precision pilot (K_p=1.2, K_v=0.3) and the element close",
            "identify",
            "the identified precision pilot (K_p=1.2, K_v=0.3) and the element close",
        ),
        (
            "t is not uniformly sampled at dt=0.01",
            "identify",
            "t is not uniformly sampled at dt=0.01",
        ),
        (
            "widen it (limits={'K_p': [low, high]}), give the experiment's element (element=)",
            "identify",
            "widen it (--set limits='{\"K_p\": [low, high]}'), give the experiment's element "
            "(--element)",
        ),
        (  # already the command line's words: left as they are
            "widen it (--set limits='{\"K_p\": [low, high]}')",
            "identify",
            "widen it (--set limits='{\"K_p\": [low, high]}')",
        ),
        ("give start='generic'", "bench", "give start='generic'"),  # no --set in bench
    ],
)
def test_cli_words(library, command, cli):
    assert cli_words(library, command) == cli


def test_the_library_names_its_keywords(simulation):
    from manualcontrol.estimators.analysis.identification import (
        build_estimator,
        identified_loop,
        identify,
    )

    recording = Recording.load(simulation)
    recording = Recording(dict(recording.signals), recording.dt)  # no forcing, no element
    found = identify(recording, build_estimator("dekf", {"estimated": ("K_p",)}))
    assert found.check.frequency_note == (
        "not checked: the forcing frequencies are unknown (give forcing= or period=, the "
        "forcing signals being in the recording)"
    )
    assert found.closed_loop == {
        "stable": None,
        "message": "not checked: no controlled element known (give element=)",
    }
    # an unstable identified loop is said once: "the identified precision pilot ..."
    unstable = identified_loop(found.result, "DI")
    assert unstable["stable"] is False
    assert unstable["message"].startswith("the identified precision pilot (K_p=")
    assert "the identified the" not in unstable["message"]


def test_a_causal_remnant_choice_on_the_preview_model_is_refused_in_flags(tmp_path, capsys):
    run_path = tmp_path / "preview.npz"
    simulate(Pilot.typical("preview", "SI"), "SI", measurement_time=5.0).save(run_path)
    out_dir = tmp_path / "o"
    code, _, err = run(
        capsys, "identify", run_path, "--estimator", "rml", "--out", out_dir,
        "--set", "model=preview", "--set", "ce=SI", "--set", "anticipation_time=0.9",
        "--set", "remnant_injection=choose-causal",
    )  # fmt: skip
    assert code == EXIT_USAGE
    assert "error: --set remnant_injection=choose-causal measures" in err
    assert "give --set remnant_injection=choose (offline" in err
    assert "--set remnant_injection=input or --set remnant_injection=output" in err
    assert not out_dir.exists()
