"""`manualcontrol play` and `manualcontrol compile` as commands of the `manualcontrol` CLI.

Flying a run through the play command's own entry point (a scripted stick, a manual
clock) is tested in tests/human; here: the commands are wired in, list their flags,
refuse a bad flag naming it, and load nothing of theirs until they run.
"""

import subprocess
import sys
import textwrap

import pytest

from manualcontrol.bench import cli
from manualcontrol.bench.cli import EXIT_OK, EXIT_RUNS_FAILED, EXIT_USAGE, main


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_the_command_lists_play_and_compile(capsys):
    code, out, _ = run(capsys, "--help")
    out = " ".join(out.split())  # argparse wraps the lines
    assert code == EXIT_OK
    assert "fly a task yourself with a mouse, keyboard or joystick" in out
    assert "compile the kernels into numba's cache and build the C ports now" in out
    assert "130 interrupted (Ctrl-C)" in out


def test_play_help_lists_its_flags(capsys):
    code, out, _ = run(capsys, "play", "--help")
    out = " ".join(out.split())
    assert code == EXIT_OK
    assert out.startswith("usage: manualcontrol play")
    for flag in ("--task", "--element", "--forcing", "--input", "--dead-zone", "--out"):
        assert flag in out
    assert "--overwrite" in out and "Exit codes: 0 saved, 1 aborted" in out


def test_play_refuses_a_bad_flag_naming_it(capsys):
    code, _, err = run(capsys, "play", "--task", "nope")
    assert code == EXIT_USAGE
    assert "manualcontrol play: error: argument --task: invalid choice: 'nope'" in err
    assert "compensatory" in err and "Traceback" not in err


def test_play_runs_run_play_with_the_parsed_flags(capsys, monkeypatch):
    import manualcontrol.human.cli as play

    seen = {}

    def fake(args):
        seen.update(vars(args))
        return 7

    monkeypatch.setattr(play, "run_play", fake)
    assert main(["play", "--task", "pursuit", "--input", "keyboard"]) == 7
    assert seen["task"] == "pursuit" and seen["input"] == "keyboard"


def test_compile_help_lists_its_flag(capsys):
    code, out, _ = run(capsys, "compile", "--help")
    out = " ".join(out.split())
    assert code == EXIT_OK
    assert "--workers" in out and "numba's on-disk cache" in out


@pytest.mark.parametrize(("ok", "expected"), [(True, EXIT_OK), (False, EXIT_RUNS_FAILED)])
def test_compile_runs_compile_kernels_on_the_workers_asked(capsys, monkeypatch, ok, expected):
    import manualcontrol.bench.compile_kernels as compiling

    calls = []

    def fake(workers, report, numba_reference):
        calls.append((workers, numba_reference))
        report("  compiled: dekf (1 CPU-s)")
        return ok

    monkeypatch.setattr(compiling, "compile_kernels", fake)
    code, out, err = run(capsys, "compile", "--workers", "3")
    assert code == expected and calls == [(3, False)]
    assert "compiling the kernels into the kernel cache" in out and "compiled: dekf" in out
    assert ("did not compile" in err) is not ok
    assert not cli._QUIET_CHILDREN
    code, out, _ = run(capsys, "compile", "--numba-reference")
    assert code == expected and calls[-1] == (None, True)
    assert "compiling the numba kernels the C ports replace" in out


def test_compile_refuses_zero_workers(capsys):
    code, _, err = run(capsys, "compile", "--workers", "0")
    assert code == EXIT_USAGE and "--workers: must be >= 1, got 0" in err


def test_help_and_the_other_commands_load_nothing_of_play():
    script = textwrap.dedent(
        """
        import contextlib, io, sys
        from manualcontrol.bench.cli import main

        for command in ("", "identify", "compile", "suites"):
            with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
                main([command, "--help"] if command else ["--help"])
        print(sorted(m for m in sys.modules if m.startswith("manualcontrol.human")))
        with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
            main(["play", "--help"])
        print("manualcontrol.human.cli" in sys.modules, "pygame" in sys.modules)
        """
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    before, after = result.stdout.splitlines()
    assert before == "[]"
    assert after == "True False"


def test_experiment_is_a_command_that_plans_the_documented_protocol(capsys, tmp_path):
    from pathlib import Path

    text = (Path(__file__).parents[2] / "docs" / "experiments.md").read_text()
    protocol = tmp_path / "si-di.toml"
    protocol.write_text(text.split("```toml\n", 1)[1].split("```", 1)[0])
    code, out, _ = run(capsys, "experiment", protocol, "--participant", "P02", "--plan")
    assert code == EXIT_OK
    assert "06-DI-measurement-1.npz" in out


def test_experiment_names_a_missing_protocol_file(capsys, tmp_path):
    code, _, err = run(capsys, "experiment", tmp_path / "nope.toml")
    assert code == EXIT_USAGE
    assert "nope.toml" in err
