"""The manualcontrol command: every subcommand once, its exit codes and error messages."""

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from manualcontrol.bench.cli import EXIT_OK, EXIT_RUNS_FAILED, EXIT_USAGE, main
from manualcontrol.envs.recording import Recording
from manualcontrol.estimators.registry import EstimatorEntry

TINY_SUITE = """
name = "tiny"
[defaults]
run_in = 2.0
measurement_time = 10.0
[[batch]]
name = "comp"
task = "compensatory"
element = "DI"
forcing = "vanderel-bw4"
realisations = [0]
[batch.pilot]
model = "precision"
parameters = { K_p = 0.24, K_v = 0.36, tau_v = 0.3, omega_nms = 8.0, zeta_nms = 0.45 }
[batch.estimator]
name = "dekf"
model = "precision"
ce = "DI"
"""


def run(capsys, *argv):
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_help_lists_every_command():
    result = subprocess.run(
        [sys.executable, "-m", "manualcontrol.bench.cli", "--help"], capture_output=True, text=True
    )
    assert result.returncode == 0
    for command in ("simulate", "identify", "bench", "suites", "train", "evaluate"):
        assert command in result.stdout
    assert "Exit codes" in result.stdout


def test_suites_lists_the_builtin_suites(capsys):
    code, out, _ = run(capsys, "suites")
    assert code == EXIT_OK
    assert "vertregt2020-performance: " in out and "800 runs" in out and "--quick: 8 runs" in out


def test_simulate_then_identify(tmp_path, capsys):
    recording_path = tmp_path / "run.csv"
    code, out, _ = run(
        capsys,
        "simulate",
        "--model", "precision",
        "--element", "DI",
        "--param", "K_p=0.24",
        "--param", "K_v=0.36",
        "--param", "tau_v=sigmoid:0.3,0.25,20,5",
        "--run-in", "5",
        "--measurement-time", "40",
        "--out", str(recording_path),
        "--plot", str(tmp_path / "run.png"),
    )  # fmt: skip
    assert code == EXIT_OK, out
    recording = Recording.load(recording_path)
    assert recording.duration == pytest.approx(40.0)
    np.testing.assert_allclose(recording.parameters["tau_v"][-1], 0.25, atol=1e-3)
    assert (tmp_path / "run.png").is_file()

    out_dir = tmp_path / "identified"
    code, out, err = run(
        capsys,
        "identify", str(recording_path),
        "--model", "precision",
        "--set", "ce=DI",
        "--set", 'initial={"K_p": 0.24, "K_v": 0.36}',
        "--out", str(out_dir),
    )  # fmt: skip
    assert code == EXIT_OK, err
    summary = json.loads((out_dir / "summary.json").read_text())
    assert summary["final"]["K_v"] == pytest.approx(0.36, rel=0.1)
    assert (out_dir / "estimation.npz").is_file() and (out_dir / "parameters.png").is_file()


def test_identify_reads_an_experiment_file_with_a_column_mapping(tmp_path, capsys):
    from manualcontrol.pilots import Pilot, simulate

    recording = simulate(
        Pilot("precision"), "popovici2017", "popovici2017", run_in=0.0, measurement_time=30.0
    )
    path = tmp_path / "trial.csv"
    lines = ["time,target,output,stick"]
    columns = zip(recording.t, recording.ft, recording.y, recording.u, strict=True)
    lines += [",".join(repr(float(v)) for v in row) for row in columns]
    path.write_text("\n".join(lines))
    code, out, err = run(
        capsys, "identify", str(path), "--column", "u=stick", "--out", str(tmp_path / "o")
    )
    assert code == EXIT_OK, err
    assert "estimated K_p, K_v, tau_v, omega_nms, zeta_nms" in out


def test_bench_runs_a_suite_file(tmp_path, capsys):
    suite = tmp_path / "tiny.toml"
    suite.write_text(textwrap.dedent(TINY_SUITE))
    code, out, _ = run(
        capsys,
        "bench",
        str(suite),
        "--out",
        str(tmp_path / "r"),
        "--backend",
        "inprocess",
        "--quiet",
    )
    assert code == EXIT_OK
    assert "(1 runs, 0 failed)" in out and (tmp_path / "r" / "report.md").is_file()
    # without --quiet the report's drawing says how it goes, a line per batch
    code, _, err = run(
        capsys, "bench", str(suite), "--out", str(tmp_path / "s"), "--backend", "inprocess"
    )
    assert code == EXIT_OK and "report: batch 1 of 1, " in err


def test_bench_with_failing_runs_exits_3(tmp_path, capsys, monkeypatch):
    from manualcontrol.bench import runner

    class Broken:
        def estimate(self, recording):
            raise RuntimeError("no")

    monkeypatch.setitem(
        runner.ESTIMATORS, "broken", EstimatorEntry("broken", "", "", lambda settings: Broken())
    )
    suite = tmp_path / "tiny.toml"
    suite.write_text(
        textwrap.dedent(TINY_SUITE).replace(
            'name = "dekf"\nmodel = "precision"\nce = "DI"', 'name = "broken"'
        )
    )
    code, out, _ = run(
        capsys,
        "bench",
        str(suite),
        "--out",
        str(tmp_path / "r"),
        "--backend",
        "inprocess",
        "--quiet",
    )
    assert code == EXIT_RUNS_FAILED and "1 failed" in out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["bench", "no-such-suite"], "suite must be a built-in name"),
        (["simulate", "--element", "TI", "--out", "x.npz"], "controlled element must be one of"),
        (
            ["simulate", "--param", "K_p", "--out", "x.npz"],
            "--param must look like NAME=VALUE, got 'K_p'",
        ),
        (["simulate", "--param", "K_p=ramp:1", "--out", "x.npz"], "bad ramp schedule 'ramp:1'"),
        (["identify", "missing.npz"], "no such recording file"),
        (["evaluate", "no-agent-here"], "has no config.json"),
        (["train", "--hide-queue", "--out", "a"], "--hide-queue needs an action delay"),
        (
            ["train", "--algorithm", "ppo", "--algorithm-option", "n_step=64", "--out", "a"],
            "--algorithm-option: algorithm_kwargs: PPO takes no option 'n_step'; its options: "
            "learning_rate, n_steps,",
        ),
        (["train", "--observation-noise", "-0.1", "--out", "a"], "--observation-noise"),
        (["train", "--effort-rate-weight", "ramp:1", "--out", "a"], "--effort-rate-weight:"),
        (["train", "--delay", "wobble:0.2", "--out", "a"], "--delay: a parameter value must"),
    ],
)
def test_user_errors_exit_2_with_a_message_and_no_traceback(
    capsys, tmp_path, monkeypatch, argv, message
):
    monkeypatch.chdir(tmp_path)
    code, _, err = run(capsys, *argv)
    assert code == EXIT_USAGE
    assert message in err and "Traceback" not in err
    assert err.startswith(f"manualcontrol {argv[0]}: error:")
    assert not (tmp_path / "a").exists() and not (tmp_path / "x.npz").exists()


def test_train_and_evaluate_commands(tmp_path, capsys):
    agent = tmp_path / "agent"
    code, out, _ = run(
        capsys,
        "train", "--steps", "200", "--delay", "0.1", "--hide-queue", "--algorithm", "ppo",
        "--env", "measurement_time=2.0", "--env", "forcing=\"plaetinck2018\"",
        "--envs", "2", "--algorithm-option", "n_steps=50", "--algorithm-option",
        "batch_size=25", "--net-arch", "8", "8", "--out", str(agent), "--quiet",
    )  # fmt: skip
    assert code == EXIT_OK and (agent / "policy.pt").is_file()
    config = json.loads((agent / "config.json").read_text())
    assert config["algorithm_kwargs"] == {"n_steps": 50, "batch_size": 25}
    assert config["policy_kwargs"] == {"net_arch": [8, 8]} and config["n_envs"] == 2
    assert config["wrappers"] == [{"kind": "action_delay", "delay": 0.1, "observe_queue": False}]
    code, out, _ = run(
        capsys,
        "train", "--steps", "100", "--delay", "ramp:0.1,0.2,0,1", "--observation-noise", "0.01",
        "--effort-rate-weight", "0.05", "--history", "3", "--algorithm", "ppo",
        "--env", "measurement_time=2.0", "--algorithm-option", "n_steps=50",
        "--algorithm-option", "batch_size=25", "--net-arch", "8", "--out", str(tmp_path / "b"),
        "--quiet",
    )  # fmt: skip
    scheduled = json.loads((tmp_path / "b" / "config.json").read_text())
    assert code == EXIT_OK and scheduled["wrappers"][0]["delay"]["kind"] == "ramp"
    assert scheduled["observation_noise_ratio"] == 0.01
    assert scheduled["effort_rate_weight"] == 0.05 and scheduled["history_length"] == 3
    code, out, err = run(capsys, "evaluate", str(agent), "--out", str(tmp_path / "eval"))
    assert code == EXIT_OK and "RMS error" in out
    for stage in ("flying the agent", "identifying with the DEKF", "writing the report"):
        assert f"evaluate: {stage}" in err  # a line per stage of a minute's work
    assert (tmp_path / "eval" / "evaluation.md").is_file()


def test_a_reader_that_leaves_early_is_no_error(tmp_path):
    # `manualcontrol suites | head -1`: the pipe closes under the listing
    listing = subprocess.run(
        f"'{sys.executable}' -m manualcontrol.bench.cli suites | head -c 10",
        shell=True,
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert len(listing.stdout) == 10
    assert "error" not in listing.stderr and "Traceback" not in listing.stderr
