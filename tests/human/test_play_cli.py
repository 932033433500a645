"""``manualcontrol play`` headless: a scripted stick and a manual clock through the
whole command (file written, refused, reported), its flags' errors and its exit codes."""

import argparse
import re
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest

from manualcontrol.envs.recording import Recording
from manualcontrol.human.cli import add_play_arguments, main, run_play
from manualcontrol.human.devices import ScriptedInput
from manualcontrol.human.realtime import ManualClock
from manualcontrol.human.tasks import TASKS


def parse(*argv):
    parser = argparse.ArgumentParser()
    add_play_arguments(parser)
    return parser.parse_args(["--measurement-time", "2", *argv])


def play(*argv, values=None, **hooks):
    device = ScriptedInput(np.full(200, 0.1) if values is None else values)
    return run_play(parse(*argv), device=device, clock=ManualClock(), **hooks)


def test_a_run_is_flown_saved_and_reported(tmp_path, capsys, pygame):
    out = tmp_path / "run.npz"
    assert play("--out", str(out), "--element", "DI", "--seed", "3") == 0
    printed = capsys.readouterr().out
    recording = Recording.load(out)
    assert len(recording) == 200
    np.testing.assert_allclose(recording.u, 0.1 * recording.metadata["action_scale"]["scale"])
    assert recording.metadata["input"]["device"] == "scripted"
    assert recording.metadata["timing"]["steps"] == 200
    assert recording.metadata["controlled_element"]["kind"] == "double_integrator"
    assert "flew compensatory (DoubleIntegrator(K=5)" in printed
    rms = float(np.sqrt(np.mean(recording.e**2)))
    assert f"RMS error {rms:.3g}" in printed
    assert "timing: 200 steps, 0 late" in printed
    assert f"wrote {out}" in printed
    assert not pygame.display.get_init()  # the window is closed


@pytest.mark.parametrize("task", ["pursuit", "preview", "postview", "lane-keeping"])
def test_every_task_can_be_played(tmp_path, capsys, task):
    out = tmp_path / f"{task}.csv"
    assert play("--task", task, "--out", str(out)) == 0
    assert Recording.load(out).metadata["task"] == task
    if task == "lane-keeping":
        assert "RMS lateral offset" in capsys.readouterr().out


def test_the_default_file_is_new_and_under_results_play(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert play() == 0
    assert play() == 0  # in the same second: a second name, not a replaced file
    files = sorted((tmp_path / "results" / "play").glob("compensatory-*.npz"))
    assert len(files) == 2
    assert re.fullmatch(r"compensatory-\d{8}-\d{6}(-2)?\.npz", files[0].name)


def test_an_existing_file_is_refused_unless_overwrite(tmp_path, capsys):
    out = tmp_path / "run.npz"
    out.write_bytes(b"earlier run")
    assert play("--out", str(out)) == 2
    assert f"--out '{out}': the file exists; pass --overwrite to replace it" in (
        capsys.readouterr().err
    )
    assert out.read_bytes() == b"earlier run"
    assert play("--out", str(out), "--overwrite") == 0
    assert len(Recording.load(out)) == 200


def flying_with(monkeypatch, on_step):
    """The command's fly() with ``on_step`` added (what happens during the run)."""
    from manualcontrol.human import realtime

    original = realtime.fly
    monkeypatch.setattr(realtime, "fly", lambda *a, **k: original(*a, on_step=on_step, **k))


def test_a_file_that_appears_during_the_run_is_not_replaced(tmp_path, capsys, monkeypatch):
    out = tmp_path / "run.npz"

    def meanwhile(report):
        if report.index == 1:
            out.write_bytes(b"someone else's")

    flying_with(monkeypatch, meanwhile)
    assert play("--out", str(out)) == 2
    assert "appeared during the run" in capsys.readouterr().err
    assert out.read_bytes() == b"someone else's"
    assert [p.name for p in tmp_path.iterdir()] == ["run.npz"]  # no temporary left


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--task", "bogus"], "argument --task: invalid choice: 'bogus' (choose from"),
        (["--input", "trackball"], "argument --input: invalid choice: 'trackball'"),
        (["--dead-zone", "1.5"], "argument --dead-zone: must be a number in [0, 1), got '1.5'"),
        (["--measurement-time", "0"], "argument --measurement-time: must be a number of seconds"),
        (["--joystick-axis", "-1"], "argument --joystick-axis: must be a whole number >= 0"),
        (["--element", "1/(s"], "--element '1/(s': controlled element must be one of"),
        (["--forcing", "nope"], "--forcing 'nope': forcing preset must be one of"),
        (["--realisation", "99"], "--realisation must lie in [0, 9] for this forcing, got 99"),
        (["--out", "run.txt"], "--out 'run.txt': the name must end in .npz, .csv, .mat"),
        (["--task", "lane-keeping", "--forcing", "x"], "--forcing applies to the tracking"),
        (["--input", "keyboard", "--range", "2"], "--range applies to --input mouse or joystick"),
        (
            ["--task", "lane-keeping", "--measurement-time", "1000"],
            "--measurement-time must fit the road",
        ),
    ],
)
def test_bad_flags_name_the_flag_the_value_and_what_is_allowed(argv, message, capsys):
    assert main(argv) == 2
    assert message in capsys.readouterr().err


def test_no_joystick_says_so_before_any_window(no_joystick, capsys, tmp_path, pygame):
    assert main(["--input", "joystick", "--out", str(tmp_path / "x.npz")]) == 2
    assert capsys.readouterr().err.strip() == (
        "manualcontrol play: error: no joystick or gamepad found (pygame sees 0); plug one "
        "in or use --input mouse/keyboard"
    )
    assert not pygame.display.get_init()
    assert not (tmp_path / "x.npz").exists()


def test_a_closed_window_saves_nothing_and_exits_1(tmp_path, capsys, pygame, monkeypatch):
    out = tmp_path / "run.npz"

    def close_at_50(report):
        if report.index == 50:
            pygame.event.post(pygame.event.Event(pygame.QUIT))

    flying_with(monkeypatch, close_at_50)
    assert play("--out", str(out)) == 1
    assert capsys.readouterr().err.strip() == (
        "manualcontrol play: the window was closed after 0.5 s; nothing was saved"
    )
    assert not out.exists()


class Interrupting(ScriptedInput):
    def read(self):
        if self.position == 30:
            raise KeyboardInterrupt
        return super().read()


def test_ctrl_c_exits_130_with_one_line(tmp_path, capsys):
    out = tmp_path / "run.npz"
    args = parse("--out", str(out))
    assert run_play(args, device=Interrupting(np.zeros(200)), clock=ManualClock()) == 130
    assert capsys.readouterr().err.strip() == (
        "manualcontrol play: interrupted (Ctrl-C); nothing was saved"
    )
    assert not out.exists()


def test_the_start_screen_waits_for_space(tmp_path, capsys, pygame):
    pygame.display.init()
    pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_SPACE))
    assert play("--out", str(tmp_path / "a.npz"), wait_for_start=True) == 0
    pygame.display.init()
    pygame.event.post(pygame.event.Event(pygame.QUIT))
    assert play("--out", str(tmp_path / "b.npz"), wait_for_start=True) == 1
    assert "the window was closed before the start; nothing was saved" in capsys.readouterr().err
    assert not (tmp_path / "b.npz").exists()


def test_the_task_choices_are_the_task_table_and_each_env_is_registered():
    parser = argparse.ArgumentParser()
    add_play_arguments(parser)
    (task,) = [action for action in parser._actions if action.dest == "task"]
    assert tuple(task.choices) == tuple(TASKS)
    for env_id in TASKS.values():
        assert env_id in gym.registry


def test_the_commands_modules_load_no_kernels_plots_or_pygame():
    # their flags and --help need none: what a run needs is imported when it runs
    script = """
import sys
import manualcontrol.human.cli, manualcontrol.human.session_cli
heavy = ("numba", "scipy", "matplotlib", "torch", "pygame")
print(sorted({m.split(".")[0] for m in sys.modules} & set(heavy)))
"""
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


def test_runs_as_a_module():
    result = subprocess.run(
        [sys.executable, "-m", "manualcontrol.human.cli", "--dead-zone", "2"],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 2
    assert "argument --dead-zone" in result.stderr
