"""A lab's raw trial file through `manualcontrol describe` and `manualcontrol identify`.

The trial is generated here: a human-like precision pilot (K_p 3 on 1/s, delay 0.28 s,
remnant) at 60 Hz, the disturbance entering at the element's input, written with a lab's
own column names and a '#'-led header, as a laboratory's logger writes it.
"""

import json
import re
import warnings

import numpy as np
import pytest

from manualcontrol.bench.cli import EXIT_OK, EXIT_USAGE, IDENTIFY_ESTIMATOR, cli_words, main
from manualcontrol.envs.elements import parse_element
from manualcontrol.envs.signals import ForcingPair, Multisine, forcing_preset
from manualcontrol.human.report import DEFAULT_ESTIMATOR
from manualcontrol.pilots import Pilot, simulate

LAB_COLUMNS = ["--column", "u=stick", "--column", "y=output", "--column", "ft=target"]
LAB_COLUMNS += ["--column", "fd=disturbance"]
HUMAN_SI = dict(K_p=3.0, K_v=0.0, tau_v=0.28, omega_nms=11.0, zeta_nms=0.6)


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def trial(tmp_path_factory):
    fd = forcing_preset("vanderel-bw4").disturbance
    through = 1.0 / (1j * fd.frequencies)  # the element 1/s: fd at its input, seen at y
    at_output = Multisine(
        fd.frequencies,
        fd.amplitudes * np.abs(through),
        fd.phases + np.angle(through),
        fd.measurement_time,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # K_p 3: above thesis Table I, where humans put it
        pilot = Pilot(
            "precision",
            HUMAN_SI,
            remnant="vertregt2020-SI",
        )
        recording = simulate(
            pilot, parse_element("1/s"), ForcingPair(None, at_output), dt=1 / 60, seed=4
        )
    t = recording.t
    table = np.column_stack([t, np.zeros_like(t), fd(t), recording.u, recording.y, t * 0])
    path = tmp_path_factory.mktemp("lab") / "trial.csv"
    np.savetxt(
        path,
        table,
        delimiter=",",
        fmt="%.6f",
        header="time,target,disturbance,stick,output,trigger",
    )
    return path


def test_describe_prints_crossover_and_the_fitted_model(trial, tmp_path, capsys):
    out_dir = tmp_path / "d"
    code, out, err = run(
        capsys, "describe", str(trial), *LAB_COLUMNS, "--element", "1/s",
        "--disturbance-at", "input", "--period", "120", "--out", str(out_dir),
    )  # fmt: skip
    assert code == EXIT_OK, err
    assert "ignored columns: trigger" in out
    assert "describing function at 10 forcing frequencies (disturbance 10) over 1 period" in out
    assert "open loop (element given): crossover" in out
    assert "fitted precision model: K_p" in out and "K_v 0 (held)" in out
    summary = json.loads((out_dir / "summary.json").read_text())
    described = summary["describing_function"]
    spread, margin_spread = described["crossover_frequency_sd_log"], described["phase_margin_sd"]
    assert 0.0 < spread < 0.5 and 0.0 < margin_spread < 30.0
    crossover, margin = described["crossover_frequency"], described["phase_margin"]
    assert (
        f"crossover {crossover:.2f} rad/s, phase margin {margin:.0f} deg (within one standard "
        f"deviation of the remnant: {crossover * np.exp(-spread):.2f}-"
        f"{crossover * np.exp(spread):.2f} rad/s, {margin - margin_spread:.0f} to "
        f"{margin + margin_spread:.0f} deg)"
    ) in out
    crossover = summary["describing_function"]["crossover_frequency"]
    assert 2.0 < crossover < 4.5  # a human's crossover on 1/s
    assert summary["fit"]["values"]["K_p"] == pytest.approx(3.0, rel=0.25)
    assert (out_dir / "bode.png").stat().st_size > 10_000
    # the wrong entry point shows as an element that does not match the file
    code, _, err = run(
        capsys, "describe", str(trial), *LAB_COLUMNS, "--element", "1/s",
        "--period", "120", "--out", str(tmp_path / "wrong"),
    )  # fmt: skip
    assert code == EXIT_OK
    assert "the element given differs from the one measured" in err
    assert "--disturbance-at (now output)" in err


def test_describe_counts_a_harmonic_both_forcings_drive_once(
    tmp_path, capsys, shared_harmonic_forcing
):
    # the target and the disturbance on the same ten harmonics: ten lines, not twenty,
    # and no remnant share below zero from power counted twice
    pilot = Pilot.typical("precision", "SI")
    run_ = simulate(pilot, "SI", shared_harmonic_forcing, seed=0)
    path = tmp_path / "shared.csv"
    table = np.column_stack([run_.t, run_.u, run_.y, run_.ft, run_.fd])
    np.savetxt(path, table, delimiter=",", header="t,u,y,ft,fd", comments="")
    code, out, err = run(
        capsys, "describe", str(path), "--element", "SI", "--period", "120", "--no-plot",
        "--out", str(tmp_path / "d"),
    )  # fmt: skip
    assert code == EXIT_OK, err
    assert "at 10 forcing frequencies (target and disturbance 10)" in out
    assert "remnant: 0 % of u's variance" in out


def test_identify_cross_checks_in_the_frequency_domain(trial, tmp_path, capsys):
    out_dir = tmp_path / "i"
    code, out, err = run(
        capsys, "identify", str(trial), *LAB_COLUMNS, "--element", "1/s",
        "--disturbance-at", "input", "--period", "120", "--out", str(out_dir),
    )  # fmt: skip
    assert "frequency domain: the identified model (second-half medians) misses" in out
    assert "crossover" in out and "measured" in out and "identified" in out
    assert "one-step VAF" in out and "when the filter had settled" in out
    summary = json.loads((out_dir / "summary.json").read_text())
    check = summary["fit"]["frequency_check"]
    assert check["gain_error_db"] is not None and check["best_gain_error_db"] is not None
    # unless told, the member the family recommends for a lab's trial, as a session's report
    assert summary["estimator"] == IDENTIFY_ESTIMATOR == DEFAULT_ESTIMATOR == "rml"
    assert summary["closed_loop"]["stable"] is True  # the element given, not Table I's 1.5/s
    assert "on a pure gain" not in err  # the lag's warning is for a gain's trials alone
    for warning in summary["fit"]["warnings"]:  # the library's words, printed as flags
        assert f"manualcontrol identify: warning: {cli_words(warning, 'identify')}" in err
    assert code == EXIT_OK


def test_identify_without_forcing_says_why_there_is_no_check(trial, tmp_path, capsys):
    code, out, _ = run(capsys, "identify", str(trial), *LAB_COLUMNS, "--out", str(tmp_path / "n"))
    assert code == EXIT_OK
    assert (
        "frequency domain: not checked: the forcing frequencies are unknown (give --forcing" in out
    )


def test_describe_shows_a_remnant_free_runs_ratios_as_beyond_measure(tmp_path, capsys):
    # off the lines such a run holds rounding alone: its ratios' digits mean nothing
    path = tmp_path / "run.npz"
    simulate(Pilot.typical("precision", "SI"), "SI", measurement_time=120.0).save(path)
    code, out, err = run(capsys, "describe", str(path), "--out", str(tmp_path / "described"))
    assert code == EXIT_OK, err
    rows = [line.split() for line in out.splitlines() if line.strip().endswith("target")]
    assert rows and all(row[3] == ">1e+06" and row[4] == ">1e+06" for row in rows)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--element", "1/(s"], "--element: element '1/(s' cannot be read"),
        (["--element", "1/s", "--period", "50"], "does not repeat over the period given"),
        (["--element", "1/s"], "give --forcing PRESET or --period SECONDS"),
        (["--period", "120", "--forcing", "vanderel-bw4"], "give --forcing or --period, not both"),
        (["--period", "120", "--fix", "K_d=1"], "--fix K_d=: the precision model has no parameter"),
        (["--period", "120", "--fix", "K_v=lots"], "--fix K_v= needs a number, got 'lots'"),
        (["--period", "120", "--model", "preview"], "--model preview: the preview model"),
    ],
)
def test_describe_bad_inputs(trial, tmp_path, capsys, extra, message):
    out_dir = tmp_path / "bad"
    code, _, err = run(capsys, "describe", str(trial), *LAB_COLUMNS, *extra, "--out", str(out_dir))
    assert code == EXIT_USAGE
    assert message in err
    assert not (out_dir / "summary.json").exists()


def test_a_trial_without_a_target_column_is_read_as_target_zero(trial, tmp_path, capsys):
    table = np.loadtxt(trial, delimiter=",")
    bare = tmp_path / "bare.csv"
    # time, joystick, cursor, dist: a lab's own names, no target logged
    np.savetxt(bare, table[:, [0, 3, 4, 2]], delimiter=",", header="time,joystick,cursor,dist")
    code, out, err = run(
        capsys, "describe", str(bare), "--column", "u=joystick", "--column", "y=cursor",
        "--column", "fd=dist", "--element", "1/s", "--disturbance-at", "input",
        "--period", "120", "--out", str(tmp_path / "d"),
    )  # fmt: skip
    assert code == EXIT_OK, err
    assert "no target or error column: the target is taken as zero (e = -y)" in out
    summary = json.loads((tmp_path / "d" / "summary.json").read_text())
    assert 2.0 < summary["describing_function"]["crossover_frequency"] < 4.5


@pytest.mark.parametrize("command", ["describe", "identify"])
def test_a_trial_without_a_target_column_and_a_forcing_that_moves_it_is_refused(
    trial, tmp_path, capsys, command
):
    table = np.loadtxt(trial, delimiter=",")
    bare = tmp_path / "bare.csv"
    np.savetxt(bare, table[:, [0, 3, 4, 2]], delimiter=",", header="time,joystick,cursor,dist")
    columns = ["--column", "u=joystick", "--column", "y=cursor", "--column", "fd=dist"]
    columns += ["--element", "1/s", "--disturbance-at", "input"]
    out_dir = tmp_path / "refused"
    code, out, err = run(
        capsys, command, str(bare), *columns, "--forcing", "vanderel-bw4", "--out", str(out_dir)
    )
    assert code == EXIT_USAGE
    assert f"{bare}: --forcing vanderel-bw4 moves the target" in err
    assert "--column ft=COLUMN or --column e=COLUMN" in err
    assert "taken as zero" not in out and not out_dir.exists()
    # the same trial's disturbance alone, as a forcing file: read with the target at zero
    alone = tmp_path / "disturbance.json"
    disturbance = forcing_preset("vanderel-bw4").disturbance.to_dict()
    alone.write_text(json.dumps({"disturbance": disturbance}))
    code, out, err = run(
        capsys, "describe", str(bare), *columns, "--forcing", str(alone), "--out", str(out_dir)
    )
    assert code == EXIT_OK, err
    assert "no target or error column: the target is taken as zero (e = -y)" in out
    summary = json.loads((out_dir / "summary.json").read_text())
    assert 2.0 < summary["describing_function"]["crossover_frequency"] < 4.5


def test_describe_and_identify_a_pursuit_trial(tmp_path, capsys):
    values = dict(K_f=1.0, omega_f=3.3, tau_f=0.0, K_p=1.3, K_v=0.0, tau_v=0.26)
    values.update(omega_nms=10.5, zeta_nms=0.35)
    run_file = tmp_path / "pursuit.npz"
    simulate(Pilot("preview", values), "SI", "vanderel-bw4", task="pursuit", seed=3).save(run_file)
    code, out, err = run(capsys, "describe", str(run_file), "--out", str(tmp_path / "d"))
    assert code == EXIT_OK, err
    assert "pursuit display: the table holds the disturbance's lines" in out
    assert "fitted preview model:" in out and "tau_f 0 (held)" in out
    fit = json.loads((tmp_path / "d" / "summary.json").read_text())["fit"]
    assert fit["values"]["tau_v"] == pytest.approx(0.26, abs=0.02)
    code, out, err = run(
        capsys, "identify", str(run_file), "--model", "preview", "--set", "anticipation_time=0",
        "--estimator", "rml", "--out", str(tmp_path / "i"),
    )  # fmt: skip
    assert code == EXIT_OK, err
    assert "frequency domain: the identified model (second-half medians) misses" in out


def test_identify_chooses_the_remnant_model_by_the_describing_function(trial, tmp_path, capsys):
    out_dir = tmp_path / "c"
    code, out, err = run(
        capsys, "identify", str(trial), *LAB_COLUMNS, "--element", "1/s",
        "--disturbance-at", "input", "--period", "120", "--estimator", "rml",
        "--set", "remnant_injection=choose", "--out", str(out_dir),
    )  # fmt: skip
    assert code == EXIT_OK, err
    assert "remnant model: at the " in out and "the pass nearer the describing function" in out
    record = json.loads((out_dir / "summary.json").read_text())["remnant_injection"]
    assert record["chosen"] in ("input", "output")
    assert set(record["gain_error_db"]) == {"input", "output"}


def test_identify_options_reach_only_the_members_that_read_them(trial, tmp_path, capsys):
    # the delay identifier has its own model: --period feeds the cross-check only
    code, out, err = run(
        capsys, "identify", str(trial), *LAB_COLUMNS, "--estimator", "rdi", "--period", "120",
        "--out", str(tmp_path / "r"),
    )  # fmt: skip
    assert code == EXIT_OK, err
    assert "frequency domain: not checked: the rdi model is not a pilot model structure" in out
    # limits from the element asked for by name: the element given on the command line
    code, _, err = run(
        capsys, "identify", str(trial), *LAB_COLUMNS, "--element", "1/s", "--period", "120",
        "--set", "limits=human", "--out", str(tmp_path / "h"),
    )  # fmt: skip
    assert code == EXIT_OK, err
    summary = json.loads((tmp_path / "h" / "summary.json").read_text())
    assert summary["fit"]["frequency_check"]["values"]["K_p"] > 2.5  # past Table I's limit


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--element", "bogus"], "--element: element 'bogus' cannot be read"),
        (["--forcing", "vanderel-bw4", "--period", "120"], "give --forcing or --period, not both"),
        (
            ["--set", "start=describing-function"],
            "--set start=describing-function reads the describing function at the forcing",
        ),
        (
            ["--estimator", "rml", "--set", "remnant_injection=choose"],
            "--set remnant_injection=choose reads the describing function at the forcing",
        ),
    ],
)
def test_identify_bad_inputs_speak_the_command_line(trial, tmp_path, capsys, extra, message):
    out_dir = tmp_path / "bad"
    code, _, err = run(capsys, "identify", str(trial), *LAB_COLUMNS, *extra, "--out", str(out_dir))
    assert code == EXIT_USAGE
    assert message in err
    assert not (out_dir / "summary.json").exists()


def test_a_describing_function_setting_says_why_a_given_forcing_could_not_be_measured(
    trial, tmp_path, capsys
):
    # the period given is no whole number of samples: the reason, not a request for the
    # --period already there
    code, _, err = run(
        capsys, "identify", str(trial), *LAB_COLUMNS, "--element", "1/s", "--period", "119.99",
        "--set", "remnant_injection=choose", "--out", str(tmp_path / "o"),
    )  # fmt: skip
    assert code == EXIT_USAGE
    assert "--set remnant_injection=choose could not measure the describing function: the " in err
    assert "forcing's period 119.99 s is 7199.4000 samples" in err and "method=" not in err
    assert "give --forcing PRESET or --period" not in err
    assert not (tmp_path / "o").exists()


def test_too_few_forcing_lines_leave_the_check_without_its_floor(tmp_path, capsys):
    # three disturbance lines cannot fit four parameters: the check says so, no crash
    full = forcing_preset("vanderel-bw4").disturbance
    three = Multisine(full.frequencies[3:6], full.amplitudes[3:6], full.phases[3:6], 120.0)
    pilot = Pilot("precision", dict(K_p=1.5, K_v=0.0, tau_v=0.25, omega_nms=12.0, zeta_nms=0.5))
    path = tmp_path / "three.npz"
    simulate(pilot, "SI", ForcingPair(None, three)).save(path)
    code, out, err = run(capsys, "identify", str(path), "--out", str(tmp_path / "o"))
    assert code == EXIT_OK, err
    assert "(the model fitted to it: n/a: too few forcing lines for its parameters)" in out


def test_identify_is_the_library_function_the_command_prints(trial, tmp_path, capsys):
    """The command reads the file and prints; the analysis is identify()'s, number for number."""
    from manualcontrol.envs.recording import Recording
    from manualcontrol.estimators.analysis.identification import build_estimator, identify

    out_dir = tmp_path / "i"
    code, _, _ = run(
        capsys, "identify", str(trial), *LAB_COLUMNS, "--element", "1/s",
        "--disturbance-at", "input", "--period", "120", "--out", str(out_dir),
    )  # fmt: skip
    assert code == EXIT_OK
    columns = {"u": "stick", "y": "output", "ft": "target", "fd": "disturbance"}
    recording = Recording.load(trial, columns=columns, require=("u",)).with_error_signal()
    element = parse_element("1/s")
    estimator = build_estimator(IDENTIFY_ESTIMATOR, element="1/s")
    identification = identify(
        recording, estimator, element=element, period=120.0, disturbance_at="input"
    )
    written = json.loads((out_dir / "summary.json").read_text())
    assert json.loads(json.dumps(identification.summary)) == written
    assert identification.closed_loop["stable"] is True
    with pytest.raises(ValueError, match=r"estimator must be one of .*got 'no-such'"):
        build_estimator("no-such")
    with pytest.raises(ValueError, match="model names the pilot structure"):
        build_estimator("rdi", model="precision")


def test_describe_by_least_squares_reads_a_trial_cut_mid_period(trial, tmp_path, capsys):
    whole = tmp_path / "whole"
    code, out, err = run(
        capsys, "describe", str(trial), *LAB_COLUMNS, "--element", "1/s",
        "--disturbance-at", "input", "--period", "120", "--method", "least-squares",
        "--out", str(whole),
    )  # fmt: skip
    assert code == EXIT_OK, err
    assert "over every sample, 120.00 s (the forcing repeats every 120 s), by least squares" in out
    summary = json.loads((whole / "summary.json").read_text())["describing_function"]
    assert summary["method"] == "least-squares"
    assert 2.0 < summary["crossover_frequency"] < 4.5
    # 90 s of the trial: the Fourier method needs a whole period, least squares does not
    cut = tmp_path / "cut.csv"
    lines = trial.read_text().splitlines()
    cut.write_text("\n".join(lines[: 1 + 90 * 60]) + "\n")
    code, _, err = run(
        capsys, "describe", str(cut), *LAB_COLUMNS, "--element", "1/s", "--disturbance-at",
        "input", "--forcing", "vanderel-bw4", "--out", str(tmp_path / "f"),
    )  # fmt: skip
    assert code == EXIT_USAGE and "shorter than one forcing period" in err
    assert "--method least-squares reads a shorter stretch" in err
    code, out, err = run(
        capsys, "describe", str(cut), *LAB_COLUMNS, "--element", "1/s", "--disturbance-at",
        "input", "--period", "120", "--method", "least-squares", "--out", str(tmp_path / "p"),
    )  # fmt: skip
    assert code == EXIT_USAGE
    assert "--method least-squares on a recording shorter than the period" in err


def test_identify_chooses_the_remnant_model_causally(tmp_path, capsys):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # K_p 3: above thesis Table I, where humans put it
        recording = simulate(
            Pilot("precision", HUMAN_SI, remnant="vertregt2020-SI"),
            parse_element("1/s"),
            "vanderel-bw4",
            measurement_time=120.0,
            seed=3,
        )
    path = recording.save(tmp_path / "run.npz")
    out_dir = tmp_path / "o"
    code, out, err = run(
        capsys, "identify", str(path), "--element", "1/s", "--estimator", "rml",
        "--set", "remnant_injection=choose-causal", "--out", str(out_dir),
    )  # fmt: skip
    assert code == EXIT_OK, err
    assert "remnant model, chosen causally: at the " in out
    assert "before the first decision, half a forcing period in, the perception" in out
    record = json.loads((out_dir / "summary.json").read_text())["remnant_injection"]
    assert record["decisions"][0]["t"] == pytest.approx(60.0, abs=0.02)
    assert sum(record["share"].values()) == pytest.approx(1.0)
    bare = recording.with_metadata(forcing=None).save(tmp_path / "bare.npz")
    code, _, err = run(
        capsys, "identify", str(bare), "--element", "1/s", "--estimator", "rml",
        "--set", "remnant_injection=choose-causal", "--out", str(tmp_path / "b"),
    )  # fmt: skip
    assert code == EXIT_USAGE
    assert "--set remnant_injection=choose-causal measures the describing function" in err
    assert not (tmp_path / "b" / "summary.json").exists()


def test_a_forcing_file_gives_the_lab_forcing_lines(trial, tmp_path, capsys):
    # a lab's own multisine, not a preset: the causal remnant choice needs its lines
    disturbance = forcing_preset("vanderel-bw4").disturbance.to_dict()
    del disturbance["kind"]  # a lab writes the numbers only
    path = tmp_path / "forcing.json"
    path.write_text(json.dumps({"disturbance": disturbance}))
    out_dir = tmp_path / "o"
    code, out, err = run(
        capsys, "identify", str(trial), *LAB_COLUMNS, "--element", "1/s", "--disturbance-at",
        "input", "--forcing", str(path), "--estimator", "rml",
        "--set", "remnant_injection=choose-causal", "--out", str(out_dir),
    )  # fmt: skip
    assert code == EXIT_OK, err
    assert "remnant model, chosen causally" in out
    assert "frequency domain: the identified model (second-half medians) misses" in out


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "no such file; a forcing file is JSON"),
        ("{not json", "not valid JSON"),
        ("[1, 2]", 'a forcing file is JSON {"target": {"frequencies"'),
        ('{"target": {"frequencies": [1.0]}}', "a forcing file is JSON"),
        ('{"target": {"frequencies": [1.0], "amplitudes": [1.0], "phases": [0.0]}, "x": 1}',
         "unknown"),
    ],
)  # fmt: skip
def test_forcing_file_bad_inputs(trial, tmp_path, capsys, content, message):
    path = tmp_path / "forcing.json"
    if content is not None:
        path.write_text(content)
    out_dir = tmp_path / "o"
    code, _, err = run(
        capsys, "describe", str(trial), *LAB_COLUMNS, "--element", "1/s",
        "--forcing", str(path), "--out", str(out_dir),
    )  # fmt: skip
    assert code == EXIT_USAGE
    assert f"--forcing {path}" in err and message in err
    assert not (out_dir / "summary.json").exists()


def test_describe_says_which_fitted_parameter_it_left_on_a_bound(tmp_path, capsys):
    # a damping past the human range ends on the fit's bound 1.2, with no deviation of
    # its own, while the others keep theirs
    forcing = ForcingPair(None, forcing_preset("vanderel-bw4").disturbance, "lab", 0)
    pilot = Pilot("precision", dict(K_p=1.5, K_v=0.0, tau_v=0.25, omega_nms=10.5, zeta_nms=1.6))
    path = tmp_path / "si.npz"
    simulate(pilot, "1/s", forcing, dt=1 / 60, seed=4, disturbance_at="input").save(path)
    code, out, err = run(capsys, "describe", str(path), "--out", str(tmp_path / "d"))
    assert code == EXIT_OK, err
    fitted = next(line for line in out.splitlines() if line.startswith("fitted precision model"))
    assert "zeta_nms 1.2 (on its bound)" in fitted, fitted
    assert re.search(r"tau_v 0\.2[34]\d* \+- 0\.00", fitted), fitted


def test_on_a_pure_gain_the_lag_model_is_described_and_named(trial, tmp_path, capsys):
    # humans lag on a gain (McRuer & Jex 1967): describe fits the precision model with
    # its lag unless told otherwise; identify keeps its filters' model and says so
    forcing = ForcingPair(None, forcing_preset("vanderel-bw4").disturbance, "lab", 0)
    lagging = dict(K_p=8.0, K_v=0.0, T_I=2.5, tau_v=0.25, omega_nms=12.0, zeta_nms=0.5)
    path = tmp_path / "gain.npz"
    simulate(Pilot("precision-lag", lagging), "gain", forcing, dt=1 / 60, seed=4,
             disturbance_at="input").save(path)  # fmt: skip
    code, out, err = run(capsys, "describe", str(path), "--out", str(tmp_path / "d"))
    assert code == EXIT_OK, err
    fitted = next(line for line in out.splitlines() if line.startswith("fitted "))
    assert fitted.startswith("fitted precision-lag model: K_p ") and "K_v 0 (held)" in fitted
    fit = json.loads((tmp_path / "d" / "summary.json").read_text())["fit"]
    assert fit["values"]["T_I"] == pytest.approx(2.5, rel=0.1)
    assert fit["gain_error_db"] < 1.0
    code, out, err = run(
        capsys, "describe", str(path), "--model", "precision", "--out", str(tmp_path / "p")
    )
    assert code == EXIT_OK and "fitted precision model: " in out  # still to be asked for
    # a lab's file names no element: the one measured from it is flat, and describe says
    # to give it, where a single integrator's file hears nothing of the kind
    from manualcontrol.envs.recording import Recording

    recording = Recording.load(path)
    table = np.column_stack([recording.t, recording.u, recording.y, recording["fd"]])
    lab_file = tmp_path / "gain.csv"
    np.savetxt(lab_file, table, delimiter=",", header="t,stick,output,dist", comments="")
    code, out, err = run(
        capsys, "describe", str(lab_file), "--column", "u=stick", "--column", "y=output",
        "--column", "fd=dist", "--period", "120", "--out", str(tmp_path / "f"),
    )  # fmt: skip
    assert code == EXIT_OK, err
    assert "the element measured from the file is flat, as a pure gain's is" in err
    assert "(--element 1 for a unit gain)" in err
    code, out, err = run(
        capsys, "describe", str(trial), *LAB_COLUMNS, "--disturbance-at", "input",
        "--period", "120", "--out", str(tmp_path / "s"),
    )  # fmt: skip
    assert code == EXIT_OK, err
    assert "flat, as a pure gain's is" not in err
    code, out, err = run(
        capsys, "identify", str(path), "--element", "1", "--no-plot", "--out", str(tmp_path / "i")
    )
    assert "on a pure gain humans equalise with a lag" in err
    assert "--model precision-lag gives it to the filters" in err
    code, out, err = run(
        capsys, "identify", str(path), "--element", "1", "--model", "precision-lag",
        "--no-plot", "--out", str(tmp_path / "l"),
    )  # fmt: skip
    summary = json.loads((tmp_path / "l" / "summary.json").read_text())
    assert summary["settings"]["model"] == "precision-lag" and "T_I" in summary["estimated"]
    assert "on a pure gain humans equalise" not in err
