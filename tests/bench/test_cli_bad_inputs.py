"""Every user mistake exits 2 with one line, no traceback, nothing left behind."""

import json

import numpy as np
import pytest

from manualcontrol.bench.cli import EXIT_OK, EXIT_RUNS_FAILED, EXIT_USAGE, _env_options, main
from manualcontrol.envs.recording import Recording


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def listing(folder):
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))


@pytest.fixture
def blocker(tmp_path):
    path = tmp_path / "file"
    path.write_text("")
    return path


@pytest.mark.parametrize(
    "argv",
    [
        ("simulate", "--out", "{b}/x.npz", "--measurement-time", "1"),
        ("identify", "{rec}", "--out", "{b}/o"),
        ("bench", "popovici2017", "--quick", "--out", "{b}/r"),
        ("train", "--out", "{b}/agent", "--steps", "8"),
    ],
)
def test_output_under_a_file_is_a_usage_error(tmp_path, capsys, blocker, argv):
    recording = tmp_path / "rec.npz"
    Recording({"t": np.arange(10) * 0.01, "u": np.zeros(10), "e": np.zeros(10)}, 0.01).save(
        recording
    )
    before = listing(tmp_path)
    code, _, err = run(capsys, *(a.format(b=blocker, rec=recording) for a in argv))
    assert code == EXIT_USAGE
    assert f"--out {blocker}/" in err and f"{blocker} is a file, not a folder" in err
    assert "Traceback" not in err
    assert listing(tmp_path) == before


def test_bench_refusals_leave_no_folder(tmp_path, capsys, monkeypatch):
    import importlib.util

    code, _, err = run(capsys, "bench", "popovici2017", "--workers", "0", "--out", tmp_path / "r")
    assert code == EXIT_USAGE and "--workers: must be >= 1, got 0" in err
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "ray" else real(name, *a)
    )
    code, _, err = run(capsys, "bench", "popovici2017", "--backend", "ray", "--out", tmp_path / "r")
    assert code == EXIT_USAGE and "--backend ray needs Ray: pip install" in err
    assert not (tmp_path / "r").exists()


def test_empty_npz_names_the_file(tmp_path, capsys):
    empty = tmp_path / "empty.npz"
    empty.write_bytes(b"")
    code, _, err = run(capsys, "identify", empty, "--out", tmp_path / "o")
    assert code == EXIT_USAGE
    assert f"{empty} is not a readable .npz file" in err
    assert not (tmp_path / "o").exists()


def test_simulate_plot_failure_names_the_path_and_leaves_no_recording(tmp_path, capsys):
    code, _, err = run(
        capsys,
        "simulate",
        "--out",
        tmp_path / "x.npz",
        "--plot",
        "/proc/x.png",
        "--measurement-time",
        "1",
    )
    assert code == EXIT_USAGE
    assert "cannot write /proc/x.png" in err and ".part" not in err
    assert not (tmp_path / "x.npz").exists()


def test_simulate_defaults_are_a_stable_typical_pilot(tmp_path, capsys):
    for element in ("SI", "DI"):
        out = tmp_path / f"{element}.npz"
        code, _, _ = run(capsys, "simulate", "--element", element, "--out", out)
        assert code == EXIT_OK
        recording = Recording.load(out)
        # bounded, of the order of the forcing (the default run reached 1e50)
        assert np.abs(recording.y).max() < 10 * np.abs(recording.ft).max()
    assert recording.metadata["pilot"]["parameters"]["K_p"]["value"] == pytest.approx(0.24)


def test_simulate_refuses_an_unstable_pilot_unless_allowed(tmp_path, capsys):
    argv = ("simulate", "--param", "K_v=0.5", "--param", "K_p=1.5", "--measurement-time", "10")
    code, _, err = run(capsys, *argv, "--out", tmp_path / "u.npz")
    assert code == EXIT_USAGE and "close an unstable loop" in err
    assert not (tmp_path / "u.npz").exists()
    code, _, err = run(capsys, *argv, "--allow-unstable", "--out", tmp_path / "u.npz")
    assert code == EXIT_OK and "warning: " in err
    assert "unstable loop" in Recording.load(tmp_path / "u.npz").metadata["diverging"]


@pytest.mark.parametrize(
    ("item", "expected"),
    [
        ("include_rates=False", {"include_rates": False}),
        ("include_rates=false", {"include_rates": False}),
        ("include_rates=yes", {"include_rates": True}),
        ("loss_of_control=7.5", {"loss_of_control": 7.5}),
        ("loss_of_control=null", {"loss_of_control": None}),
        ("realisation=null", {"realisation": None}),
        ("forcing=popovici2017", {"forcing": "popovici2017"}),
    ],
)
def test_env_options_are_parsed_to_their_type(item, expected):
    assert _env_options([item]) == expected


@pytest.mark.parametrize(
    ("item", "message"),
    [
        ("include_rates=maybe", "--env include_rates must be true or false, got 'maybe'"),
        ("action_bound=big", "--env action_bound must be a number, got 'big'"),
        ("loss_of_control=far", "--env loss_of_control must be a number or null, got 'far'"),
        ("colour=red", "--env colour: unknown environment keyword; known:"),
        ("include_rates", "--env must look like KEY=VALUE, got 'include_rates'"),
    ],
)
def test_bad_env_options_are_refused(tmp_path, capsys, item, message):
    code, _, err = run(capsys, "train", "--env", item, "--steps", "8", "--out", tmp_path / "a")
    assert code == EXIT_USAGE and message in err
    assert not (tmp_path / "a").exists()


@pytest.fixture
def long_run(tmp_path, capsys):
    path = tmp_path / "run.npz"
    assert run(capsys, "simulate", "--out", path, "--measurement-time", "60")[0] == EXIT_OK
    return path


def test_identify_reports_the_fit(tmp_path, capsys, long_run):
    code, out, _ = run(capsys, "identify", long_run, "--set", "ce=SI", "--out", tmp_path / "o")
    assert code == EXIT_OK
    assert "one-step VAF" in out and "resimulated VAF" in out and "lag-1 autocorrelation" in out
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["fit"]["vaf_one_step_percent"] > 95.0
    assert summary["fit"]["vaf_resimulated_percent"] > 90.0
    assert 0.0 <= summary["fit"]["innovation_lags_outside_95_percent"] <= 1.0
    assert summary["closed_loop"]["stable"] is True


def test_identify_says_when_the_filter_diverged(tmp_path, capsys, long_run):
    code, _, err = run(
        capsys,
        "identify",
        long_run,
        "--set",
        "ce=SI",
        "--set",
        "max_covariance=1e-6",
        "--out",
        tmp_path / "o",
    )
    assert code == EXIT_RUNS_FAILED
    assert "error: the filter diverged at t = " in err and "Try a smaller --set q2" in err


def test_identify_time_in_milliseconds(tmp_path, capsys):
    t = np.arange(6000) * 10.0  # ms
    rng = np.random.default_rng(0)
    e = np.convolve(rng.standard_normal(6000), np.ones(50) / 50, "same")
    csv = tmp_path / "trial.csv"
    csv.write_text(
        "time_ms,error,stick\n"
        + "\n".join(f"{a},{b},{c}" for a, b, c in zip(t, e, 1.3 * e, strict=True))
    )
    argv = ("identify", csv, "--column", "t=time_ms", "--column", "e=error", "--column", "u=stick")
    code, _, err = run(capsys, *argv, "--out", tmp_path / "o")
    assert code == EXIT_USAGE
    assert "the sample time is 10 s" in err and "--time-unit ms" in err
    code, _, _ = run(capsys, *argv, "--time-unit", "ms", "--set", "ce=SI", "--out", tmp_path / "o")
    assert code in (EXIT_OK, EXIT_RUNS_FAILED)
    assert (tmp_path / "o" / "summary.json").is_file()


def test_identify_preview_hint_speaks_the_command_line(tmp_path, capsys):
    t = np.arange(3000) * 0.01
    csv = tmp_path / "pursuit.csv"
    ft, y = np.sin(t), 0.9 * np.sin(t - 0.1)
    csv.write_text(
        "t,ft,y,u\n" + "\n".join(f"{a},{b},{c},{b - c}" for a, b, c in zip(t, ft, y, strict=True))
    )
    code, _, err = run(
        capsys,
        "identify",
        csv,
        "--model",
        "preview",
        "--set",
        "anticipation_time=0.5",
        "--set",
        "ce=SI",
        "--out",
        tmp_path / "o",
    )
    assert code == EXIT_USAGE
    assert "--forcing PRESET" in err and "--target-period SECONDS" in err
    assert "forcing=" not in err and "target_period=" not in err
    assert not (tmp_path / "o").exists()


def test_a_directory_is_not_a_recording(tmp_path, capsys):
    folder = tmp_path / "trials"
    folder.mkdir()
    for command in ("identify", "describe"):
        code, _, err = run(capsys, command, folder, "--out", tmp_path / "o")
        assert code == EXIT_USAGE
        assert err == (
            f"manualcontrol {command}: error: {folder} is a directory, not a recording file "
            "(give a .csv, .mat or .npz file, or text as .tsv, .txt, .dat)\n"
        )
    assert not (tmp_path / "o").exists()


def test_random_bytes_named_npz_are_not_a_recording(tmp_path, capsys):
    garbage = tmp_path / "trial.npz"
    garbage.write_bytes(np.random.default_rng(0).bytes(3000))
    code, _, err = run(capsys, "identify", garbage, "--out", tmp_path / "o")
    assert code == EXIT_USAGE
    assert err == (
        f"manualcontrol identify: error: {garbage} is not a readable .npz file, so not a "
        "recording: its bytes are not a .npz archive (a zip of arrays, as manualcontrol and "
        "numpy write it); it may be another format renamed .npz, or damaged\n"
    )
    assert "pickle" not in err


def test_a_file_of_unknown_suffix_is_said_in_the_command_lines_words(tmp_path, capsys):
    path = tmp_path / "trial.json"
    path.write_text("t,u\n0,1\n")
    code, _, err = run(capsys, "identify", path, "--out", tmp_path / "o")
    assert code == EXIT_USAGE
    assert (
        "allowed suffixes: .npz, .csv, .mat, or text as .tsv, .txt, .dat (rename the file to "
        "end in one of them)"
    ) in err
    assert "format=" not in err


def test_a_missing_suite_file_lists_the_builtin_suites(tmp_path, capsys, monkeypatch):
    from manualcontrol.bench.scenarios import BUILTIN_SUITES

    monkeypatch.chdir(tmp_path)
    code, _, err = run(capsys, "bench", "base.toml")
    assert code == EXIT_USAGE
    assert err == (
        "manualcontrol bench: error: no such suite file 'base.toml' (built-in suites: "
        f"{', '.join(BUILTIN_SUITES)})\n"
    )
    (tmp_path / "suites.toml").mkdir()
    code, _, err = run(capsys, "bench", "suites.toml")
    assert code == EXIT_USAGE and "'suites.toml' is a directory, not a suite file" in err
    assert not (tmp_path / "results").exists()


def test_a_driver_model_estimator_on_a_tracking_batch_says_so(tmp_path, capsys):
    code, _, err = run(
        capsys, "bench", "popovici2017", "--estimators", "zhao-ukf", "--out", tmp_path / "r"
    )
    assert code == EXIT_USAGE
    assert err == (
        "manualcontrol bench: error: --estimators: zhao-ukf identifies a driver keeping a car "
        "in its lane; batch 'constant' is a compensatory tracking batch (estimators for it: "
        "dekf, schiess-roland, rdi, rml, sigmoid-fit, joint-ukf, dual-ukf and their -cv and "
        "-smoothed twins)\n"
    )
    code, _, err = run(
        capsys, "bench", "zhao2019", "--estimators", "dekf-smoothed", "--out", tmp_path / "r"
    )
    assert code == EXIT_USAGE
    assert (
        "dekf-smoothed identifies a pilot in a tracking loop; batch 'kp-rising-ukf1' is a "
        "lane-keeping batch (estimators for it: zhao-ukf, zhao-multi-ukf, zhao-ukf-smoothed)"
    ) in err
    assert not (tmp_path / "r").exists()


def test_a_suite_file_naming_a_misfit_estimator_says_so(tmp_path, capsys):
    suite = tmp_path / "mixed.toml"
    suite.write_text(
        """
name = "mixed"
[[batch]]
name = "comp"
task = "compensatory"
element = "SI"
forcing = "vanderel-bw4"
realisations = [0]
[batch.pilot]
model = "precision"
parameters = { K_p = 1.5, K_v = 0.0, tau_v = 0.3, omega_nms = 10.5, zeta_nms = 0.35 }
[batch.estimator]
name = "zhao-multi-ukf"
"""
    )
    code, _, err = run(capsys, "bench", suite, "--out", tmp_path / "r")
    assert code == EXIT_USAGE
    assert "estimator (zhao-multi-ukf): zhao-multi-ukf identifies a driver keeping a car" in err
    assert "batch 'comp' is a compensatory tracking batch" in err


def test_training_progress_before_the_first_episode_has_no_reward(capsys):
    from manualcontrol.bench.cli import _training_report

    _training_report("    1,000/100,000 steps      512 steps/s  mean reward per step n/a")
    _training_report("   11,000/100,000 steps      530 steps/s  mean reward per step -0.0123")
    first, later = capsys.readouterr().out.splitlines()
    assert first == (
        "    1,000/100,000 steps      512 steps/s  (no episode has ended yet: no mean reward)"
    )
    assert later.endswith("mean reward per step -0.0123")


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--dt", "0"], "argument --dt: must be a finite number > 0, got '0'"),
        (["--dt", "nan"], "argument --dt: must be a finite number > 0, got 'nan'"),
        (["--measurement-time", "-20"], "argument --measurement-time: must be a finite number"),
        (["--run-in", "-5"], "argument --run-in: must be a finite number >= 0, got '-5'"),
        (["--seed", "-1"], "argument --seed: must be a whole number >= 0, got '-1'"),
        (["--delay-order", "200"], "--delay-order: delay_order must be <= 12, got 200"),
        (["--realisation", "99"], "--realisation: realisation must lie in [0, 9]"),
        (["--measurement-time", "1e9"], "--measurement-time: measurement_time = 1e+09 s holds"),
        (["--measurement-time", "20", "--dt", "30"], "--measurement-time: measurement_time must"),
        (["--model", "precison"], "--model: pilot model must be one of 'precision'"),
        (["--forcing", "vanderel-bw5"], "--forcing: forcing preset must be one of"),
        (["--task", "pursuite"], "--task: task must be one of 'compensatory'"),
        (["--loop", "discrete"], "--loop: loop must be one of 'continuous', 'sampled'"),
        (["--element", "1/(s"], "--element: controlled element must be one of"),
        (["--param", "Kp=1.5"], "--param: PrecisionModel has no parameter(s) 'Kp'"),
        (["--param", "K_p=high"], "--param K_p=: a parameter value must be a finite number"),
        (["--param", "K_p=sigmoid:1.3,1.8"], "give 4 numbers (start, end, t_mid, transition_time)"),
        (["--param", "K_p=1", "--param", "K_p=2"], "--param K_p= is given twice"),
    ],
)
def test_simulate_bad_inputs_name_their_flag(tmp_path, capsys, extra, message):
    out = tmp_path / "s.npz"
    code, _, err = run(capsys, "simulate", "--measurement-time", "5", *extra, "--out", out)
    assert code == EXIT_USAGE and message in err, err
    assert "Traceback" not in err and not out.exists()


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--steps", "0"], "argument --steps: must be >= 1, got 0"),
        (["--envs", "0"], "argument --envs: must be >= 1, got 0"),
        (["--net-arch", "0"], "argument --net-arch: must be >= 1, got 0"),
        (["--neuromuscular", "0", "0.3"], "argument --neuromuscular: must be a finite number > 0"),
        (["--checkpoint-every", "-1"], "argument --checkpoint-every: must be >= 1, got -1"),
        (["--select-every", "0"], "argument --select-every: must be >= 1, got 0"),
        (["--select-episodes", "5"], "--select-episodes 5 needs --select-every N"),
        (
            ["--select-every", "8", "--select-episodes", "0"],
            "argument --select-episodes: must be >= 1, got 0",
        ),
        (["--motor-noise", "-0.1"], "--motor-noise: power_ratio must lie in [0, 1)"),
        (["--delay", "-0.2"], "--delay: delay must lie in [0, 2]"),
        (["--delay", "ramp:0.2,0.3"], "give 4 numbers (start, end, t_start, t_end), got 2"),
        (["--task", "compensatroy"], "--task: task must be one of 'compensatory'"),
    ],
)
def test_train_bad_inputs_name_their_flag(tmp_path, capsys, extra, message):
    out = tmp_path / "agent"
    code, _, err = run(capsys, "train", "--steps", "8", *extra, "--out", out)
    assert code == EXIT_USAGE and message in err, err
    assert not out.exists()


def test_identify_and_describe_refuse_contradictions(tmp_path, capsys, long_run):
    recording = long_run
    cases = [
        (["--column", "u=stick", "--column", "y=stick"], "the file's column 'stick' is given"),
        (["--column", "stick=u"], "--column stick=u: 'stick' is no signal"),
        (["--realisation", "2"], "--realisation 2 picks a realisation of --forcing PRESET"),
        (["--period", "60"], "--period 60 contradicts the recording's forcing, which repeats"),
    ]
    for extra, message in cases:
        for command in ("identify", "describe"):
            out = tmp_path / f"{command}-out"
            code, _, err = run(capsys, command, recording, *extra, "--out", out)
            assert code == EXIT_USAGE and message in err, (command, extra, err)
            assert not out.exists()
    bench = tmp_path / "bench-results"
    bench.mkdir()
    (bench / "results.csv").write_text("suite\n")
    code, _, err = run(capsys, "describe", recording, "--out", bench)
    assert code == EXIT_USAGE and "the folder holds a benchmark's results (bench)" in err
    identified = tmp_path / "identified"
    identified.mkdir()
    (identified / "summary.json").write_text('{"estimator": "rml"}')
    code, _, err = run(capsys, "bench", "popovici2017", "--quick", "--out", identified)
    assert code == EXIT_USAGE and "the folder holds a rml identification" in err
    assert sorted(p.name for p in identified.iterdir()) == ["summary.json"]
    fix = ("--fix", "tau_v=-0.2")
    code, _, err = run(capsys, "describe", recording, *fix, "--out", tmp_path / "f")
    assert code == EXIT_USAGE and "--fix tau_v=-0.2 lies outside the range" in err
    code, _, err = run(capsys, "describe", recording, "--task", "preview", "--out", tmp_path / "t")
    assert code == EXIT_USAGE and "--task preview contradicts the recording" in err
    code, _, err = run(
        capsys, "describe", recording, "--model", "schiess-roland", "--method", "least-squares",
        "--out", tmp_path / "m",
    )  # fmt: skip
    assert (
        code == EXIT_USAGE
        and "--model must be one of precision, precision-lag, preview, gain-delay" in err
    )


def test_lab_file_time_mistakes_are_named_in_flags(tmp_path, capsys, long_run):
    t = np.arange(3000) * 0.01
    table = np.column_stack([t, np.sin(t), np.cos(t)])
    timed = tmp_path / "timed.csv"
    np.savetxt(timed, table, delimiter=",", header="t,e,u", comments="", fmt="%.6f")
    untimed = tmp_path / "untimed.csv"
    np.savetxt(untimed, table[:, 1:], delimiter=",", header="e,u", comments="", fmt="%.6f")
    cases = [
        ([timed, "--dt", "0.02"], "--dt 0.02 contradicts the time column 't', which steps"),
        ([timed, "--time-unit", "ms"], "with --time-unit ms the sample time is 1e-05 s"),
        ([untimed, "--dt", "100"], "--dt 100 is the sample time in seconds"),
        ([long_run, "--set", "estimated="], "--set estimated= names no parameter"),
        ([long_run, "--model", "previw"], "--model: model must be one of 'precision'"),
        (
            [long_run, "--estimator", "rml-cv", "--set", "cv_band=[5, 1]"],
            "--set cv_band: band must satisfy 0 < low < high",
        ),
    ]
    for argv, message in cases:
        out = tmp_path / "out"
        code, _, err = run(capsys, "identify", *argv, "--out", out)
        assert code == EXIT_USAGE and message in err, (argv, err)
        assert not out.exists()
    # describe's stretch too short for least squares says how long a stretch tells the lines
    short = tmp_path / "short.npz"
    assert run(capsys, "simulate", "--out", short, "--measurement-time", "20")[0] == EXIT_OK
    method = ("--method", "least-squares")
    code, _, err = run(capsys, "describe", short, *method, "--out", tmp_path / "d")
    assert code == EXIT_USAGE
    assert "half the forcing's period (60 s) tells lines one harmonic apart" in err


def test_simulate_replaces_a_file_only_when_told(tmp_path, capsys):
    out = tmp_path / "lab.npz"
    out.write_bytes(b"a lab's recording")
    argv = ("simulate", "--measurement-time", "5", "--out", out)
    code, _, err = run(capsys, *argv)
    assert code == EXIT_USAGE and f"--out {out}: the file exists" in err
    assert out.read_bytes() == b"a lab's recording"
    assert run(capsys, *argv, "--overwrite")[0] == EXIT_OK
    assert len(Recording.load(out)) == 500


def test_a_private_algorithm_option_is_refused_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "agent"
    code, _, err = run(
        capsys, "train", "--steps", "8", "--algorithm-option", "_init_setup_model=false",
        "--out", out,
    )  # fmt: skip
    assert code == EXIT_USAGE and "SAC takes no option '_init_setup_model'" in err
    assert "_init_setup_model" not in err.split("its options:")[1]
    assert not out.exists()


def test_simulate_the_lag_model_on_a_gain_and_not_elsewhere(tmp_path, capsys):
    code, _, err = run(capsys, "simulate", "--model", "precision-lag", "--element", "gain",
                       "--measurement-time", "10", "--out", tmp_path / "k.npz")  # fmt: skip
    assert code == EXIT_OK, err
    assert "T_I" in Recording.load(tmp_path / "k.npz").metadata["pilot"]["parameters"]
    code, _, err = run(capsys, "simulate", "--model", "precision-lag", "--element", "SI",
                       "--out", tmp_path / "s.npz")  # fmt: skip
    assert code == EXIT_USAGE
    assert "on --element SI humans adopt none" in err and "(--model precision)" in err
    assert not (tmp_path / "s.npz").exists()
