"""Experiment sessions headless: scripted sticks and keys, a manual clock and SDL's dummy
driver. A whole session saved and reported, the orders, an interruption and its resume
(the same files, bit for bit), practice to a criterion, refusals, and the command."""

import argparse
import json
import math
import subprocess
import sys

import numpy as np
import pytest

from manualcontrol.envs.recording import Recording
from manualcontrol.human.devices import NoInputDevice, ScriptedInput
from manualcontrol.human.protocol import load_protocol
from manualcontrol.human.realtime import ManualClock
from manualcontrol.human.report import write_session_report
from manualcontrol.human.session import (
    PygameScreen,
    ScriptedKeys,
    SessionAborted,
    SessionError,
    load_manifest,
    run_session,
)
from manualcontrol.human.session_cli import add_session_arguments, main, run_session_command

PERIOD = 4.0
HARMONICS = (1, 2, 3, 5, 8, 13, 21)
AMPLITUDES = (1.0, 0.8, 0.6, 0.4, 0.25, 0.15, 0.1)
FREQUENCIES = [2.0 * math.pi * k / PERIOD for k in HARMONICS]
FORCING = f"""
[condition.forcing]
name = "fast"

[condition.forcing.target]
frequencies = {FREQUENCIES!r}
amplitudes = {list(AMPLITUDES)!r}
phases = [0.0, 1.1, 2.3, 0.4, 5.0, 3.3, 1.7]
measurement_time = {PERIOD}
"""
STEPS = 400  # measurement_time 4 s at dt 0.01


def protocol_text(order="as-listed", practice="2", measurement_runs=4, time=PERIOD):
    return f"""
name = "session-test"
order = "{order}"
practice = {practice}
measurement_runs = {measurement_runs}

[breaks]
between_runs = 2
between_conditions = "key"

[[condition]]
name = "SI"
task = "compensatory"
element = "SI"
measurement_time = {time}
scale = 8.0
{FORCING}
[[condition]]
name = "DI"
task = "compensatory"
element = "DI"
measurement_time = {time}
{FORCING}
"""


def protocol_file(folder, **options):
    path = folder / "protocol.toml"
    path.write_text(protocol_text(**options))
    return path


def stick(number, steps=STEPS):
    rng = np.random.default_rng(number)
    return np.clip(np.cumsum(rng.normal(0.0, 0.05, steps)), -1.0, 1.0)


def scripted(run):
    return ScriptedInput(stick(run.number))


def screen(*keys):
    return PygameScreen(ScriptedKeys(keys))


class ClosesTheWindow(ScriptedInput):
    """A stick whose window is closed at step ``at`` (the participant clicks the cross)."""

    def __init__(self, values, at):
        super().__init__(values)
        self.at = at

    def read(self):
        if self.position == self.at:
            import pygame

            pygame.event.post(pygame.event.Event(pygame.QUIT))
        return super().read()


class PressesCtrlC(ScriptedInput):
    def read(self):
        if self.position == 30:
            raise KeyboardInterrupt
        return super().read()


def signals_equal(a, b):
    return (
        a.dt == b.dt
        and set(a.signals) == set(b.signals)
        and all(np.array_equal(a[name], b[name]) for name in a.signals)
        and dict(a.parameters).keys() == dict(b.parameters).keys()
    )


def without_timing(recording):
    metadata = json.loads(recording.metadata_json())
    del metadata["timing"]
    return metadata


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    """P01's whole session, as listed, through the screens."""
    folder = tmp_path_factory.mktemp("uninterrupted")
    protocol = load_protocol(protocol_file(folder))
    events = []
    result = run_session(
        protocol,
        "P01",
        folder / "out",
        device_factory=scripted,
        clock=ManualClock(),
        show=screen(),
        on_event=events.append,
    )
    return protocol, result, events


# ------------------------------------------------------------------ a whole session


def test_a_session_is_flown_saved_in_order_and_reported(uninterrupted):
    protocol, result, events = uninterrupted
    folder = result.folder
    assert result.complete
    names = sorted(p.name for p in folder.glob("*.npz"))
    assert names == [run.file_name for run in protocol.runs("P01")]
    assert names[:3] == ["01-SI-practice-1.npz", "02-SI-practice-2.npz", "03-SI-measurement-1.npz"]
    assert names[-1] == "12-DI-measurement-4.npz"
    for number, name in enumerate(names, 1):
        recording = Recording.load(folder / name)
        assert len(recording) == STEPS  # complete
        np.testing.assert_allclose(np.diff(recording.t), 0.01, rtol=0, atol=1e-12)  # uniform
        session = recording.metadata["session"]
        assert session["number"] == number and session["participant"] == "P01"
        assert session["protocol_digest"] == protocol.digest
        assert recording.metadata["timing"]["clock"] == "ManualClock"
        scale = recording.metadata["action_scale"]["scale"]
        np.testing.assert_array_equal(recording.u, scale * stick(number))
    assert not list(folder.glob(".*"))  # no temporary left
    manifest = load_manifest(folder)
    assert manifest["status"] == "complete" and manifest["participant"] == "P01"
    assert manifest["protocol_digest"] == protocol.digest
    assert manifest["protocol"] == protocol.to_dict()
    assert manifest["protocol_text"] == protocol.text
    assert manifest["order"]["conditions"] == ["SI", "DI"]
    assert [r["file"] for r in manifest["runs"]] == names
    assert [p["file"] for p in manifest["plan"]] == names
    first = manifest["runs"][0]
    recording = Recording.load(folder / names[0])
    assert first["rms_error"] == pytest.approx(float(np.sqrt(np.mean(recording.e**2))), rel=1e-12)
    assert first["timing"]["good_enough_for_identification"] is True
    assert first["timing_warning"] is None and "400 steps, 0 late" in first["timing_summary"]
    assert first["input"]["device"] == "scripted" and first["action_scale"]["scale"] == 8.0
    assert manifest["skipped"] == [] and manifest["interruptions"] == []
    assert manifest["sittings"][0]["software"]["manualcontrol"]
    kinds = [event.kind for event in events]
    assert kinds.count("finished") == 12 and kinds[-1] == "complete"
    assert kinds.count("break") == 11  # before every run but the first
    assert "RMS error" in events[kinds.index("finished")].message
    # the report, its figures and its numbers
    report = write_session_report(folder.parent, "P01")
    assert report.markdown.is_file()
    assert sorted(p.name for p in report.folder.iterdir()) == [
        "DI-describing-function.png",
        "DI-traces.png",
        "SI-describing-function.png",
        "SI-traces.png",
        "report.json",
        "report.md",
        "rms.png",
    ]
    text = report.markdown.read_text()
    assert "## Condition SI" in text and "## Condition DI" in text
    assert text.count("| measurement |") == 8 and text.count("| practice |") == 4
    assert report.data["conditions"]["SI"]["describing_function"]["mean"]["frequencies"] == (
        pytest.approx(FREQUENCIES)
    )
    assert len(report.data["conditions"]["DI"]["identification"]["runs"]) == 4
    assert json.loads((report.folder / "report.json").read_text()) == report.data


def test_counterbalanced_participants_fly_the_two_orders(tmp_path):
    protocol = load_protocol(protocol_file(tmp_path, order="counterbalanced"))
    orders = {}
    for participant in ("P01", "P02"):
        result = run_session(
            protocol,
            participant,
            tmp_path / "out",
            device_factory=scripted,
            clock=ManualClock(),
            show=False,
        )
        names = sorted(p.name for p in result.folder.glob("*.npz"))
        assert len(names) == 12
        orders[participant] = [name.split("-")[1] for name in names]
        assert result.manifest["order"]["why"].startswith("counterbalanced: participant number")
    assert orders["P01"] == ["SI"] * 6 + ["DI"] * 6
    assert orders["P02"] == ["DI"] * 6 + ["SI"] * 6


# ------------------------------------------------------------------ interruptions


def test_an_interrupted_session_resumes_to_the_same_files(tmp_path, uninterrupted, pygame):
    protocol, complete, _ = uninterrupted

    def closing_in_run_4(run):
        if run.number == 4:
            return ClosesTheWindow(stick(run.number), at=150)
        return scripted(run)

    out = tmp_path / "out"
    with pytest.raises(SessionAborted) as error:
        run_session(
            protocol,
            "P01",
            out,
            device_factory=closing_in_run_4,
            clock=ManualClock(),
            show=screen(),
        )
    aborted = error.value
    assert aborted.reason == "the window was closed" and aborted.run.number == 4
    assert aborted.kept == (1, 2, 3)
    assert "during run 4 of 12 (SI measurement 2 of 4)" in str(aborted)
    assert "kept runs 1-3 in" in str(aborted)
    folder = out / "P01"
    assert sorted(p.name for p in folder.iterdir()) == [
        "01-SI-practice-1.npz",
        "02-SI-practice-2.npz",
        "03-SI-measurement-1.npz",
        "session.json",
    ]
    manifest = load_manifest(folder)
    assert manifest["status"] == "in progress" and len(manifest["runs"]) == 3
    (interruption,) = manifest["interruptions"]
    assert interruption["run"] == 4 and interruption["reason"] == "the window was closed"
    assert interruption["steps_flown"] == 151 and interruption["during_run"] is True

    events = []
    resumed = run_session(
        protocol,
        "P01",
        out,
        device_factory=scripted,
        clock=ManualClock(),
        show=screen(),
        on_event=events.append,
    )
    assert resumed.complete
    resume = next(event for event in events if event.kind == "resume")
    assert "kept runs 1-3" in resume.message and "continuing at run 4" in resume.message
    assert [e.run.number for e in events if e.kind == "finished"] == list(range(4, 13))
    assert sorted(p.name for p in folder.glob("*")) == sorted(
        p.name for p in complete.folder.glob("*") if p.name != "report"
    )
    for name in (run.file_name for run in protocol.runs("P01")):
        ours, theirs = Recording.load(folder / name), Recording.load(complete.folder / name)
        assert signals_equal(ours, theirs), name  # bit for bit
        assert without_timing(ours) == without_timing(theirs), name
    ours = [r["rms_error"] for r in resumed.runs]
    assert ours == [r["rms_error"] for r in complete.runs]
    assert len(resumed.manifest["sittings"]) == 2
    assert resumed.manifest["sittings"][1]["from_run"] == 4


def test_escape_between_runs_aborts_before_the_next_and_a_lost_file_is_flown_again(tmp_path):
    protocol = load_protocol(protocol_file(tmp_path, practice="0", measurement_runs=2, time=1.0))
    out = tmp_path / "out"
    # waits: SI's instructions, run 1's start, run 2's start (Escape)
    with pytest.raises(SessionAborted) as error:
        run_session(
            protocol,
            "P07",
            out,
            device_factory=lambda run: ScriptedInput(stick(run.number, 100)),
            clock=ManualClock(),
            show=screen("space", "space", "escape"),
        )
    assert error.value.reason == "Escape was pressed" and error.value.kept == (1,)
    assert "Escape was pressed before run 2 of 4" in str(error.value)
    folder = out / "P07"
    assert load_manifest(folder)["interruptions"][0]["during_run"] is False
    (folder / "01-SI-measurement-1.npz").unlink()  # lost meanwhile
    events = []
    result = run_session(
        protocol,
        "P07",
        out,
        device_factory=lambda run: ScriptedInput(stick(run.number, 100)),
        clock=ManualClock(),
        show=False,
        on_event=events.append,
    )
    assert result.complete and len(result.files) == 4
    (redo,) = [event for event in events if event.kind == "redo"]
    assert "run 1 of 4 (SI measurement 1 of 2): its file is missing; it is flown again" in (
        redo.message
    )


def test_ctrl_c_keeps_what_was_finished(tmp_path):
    protocol = load_protocol(protocol_file(tmp_path, practice="0", measurement_runs=2, time=1.0))

    def device(run):
        values = stick(run.number, 100)
        return PressesCtrlC(values) if run.number == 2 else ScriptedInput(values)

    with pytest.raises(KeyboardInterrupt):
        run_session(
            protocol,
            "P01",
            tmp_path / "out",
            device_factory=device,
            clock=ManualClock(),
            show=False,
        )
    folder = tmp_path / "out" / "P01"
    assert sorted(p.name for p in folder.iterdir()) == ["01-SI-measurement-1.npz", "session.json"]
    manifest = load_manifest(folder)
    assert manifest["interruptions"][0]["reason"] == "interrupted (Ctrl-C)"
    assert manifest["interruptions"][0]["run"] == 2


# ------------------------------------------------------------------ practice


CRITERION = """
name = "practice"
measurement_runs = 1
practice = {{until_rms_below = {threshold}, max_runs = 4, min_runs = {least}}}

[[condition]]
name = "SI"
task = "compensatory"
element = "SI"
measurement_time = 1.0
forcing = "vanderel-bw4"
"""


def practice_session(tmp_path, threshold, least=1):
    path = tmp_path / "practice.toml"
    path.write_text(CRITERION.format(threshold=threshold, least=least))
    protocol = load_protocol(path)

    def device(run):
        # practice runs get better: a stick pushed hard, then ever less
        return ScriptedInput(np.full(100, [0.8, 0.4, 0.0, 0.0][run.index - 1]))

    events = []
    result = run_session(
        protocol,
        "P01",
        tmp_path / f"out-{threshold}-{least}",
        device_factory=device,
        clock=ManualClock(),
        show=False,
        on_event=events.append,
    )
    return result, events


def test_practice_ends_when_its_criterion_is_met(tmp_path):
    result, events = practice_session(tmp_path, threshold=1.5)
    rms = [r["rms_error"] for r in result.runs]
    assert rms[0] >= 1.5 and rms[1] >= 1.5 and rms[2] < 1.5
    assert [p.name for p in result.files] == [
        "01-SI-practice-1.npz",
        "02-SI-practice-2.npz",
        "03-SI-practice-3.npz",
        "05-SI-measurement-1.npz",
    ]
    assert result.manifest["skipped"] == [
        {"number": 4, "file": None, "reason": "practice ended on its criterion"}
    ]
    (message,) = [e.message for e in events if e.kind == "practice"]
    assert message.startswith("SI: practice criterion met after 3 run(s) (RMS ")
    assert message.endswith("< 1.5); the other 1 practice slot(s) skipped")
    assert result.complete
    # min_runs holds practice on although the first run would do
    result, _ = practice_session(tmp_path, threshold=100.0, least=2)
    assert [p.name for p in result.files][:2] == ["01-SI-practice-1.npz", "02-SI-practice-2.npz"]
    assert len(result.files) == 3


def test_practice_stops_at_its_cap_when_the_criterion_is_not_met(tmp_path):
    result, events = practice_session(tmp_path, threshold=0.01)
    assert [r["kind"] for r in result.runs] == ["practice"] * 4 + ["measurement"]
    assert result.manifest["skipped"] == []
    (message,) = [e.message for e in events if e.kind == "practice"]
    assert "practice stopped at its cap of 4 runs without meeting the criterion" in message


# ------------------------------------------------------------------ refusals


def test_another_protocol_in_the_folder_is_refused(tmp_path):
    path = protocol_file(tmp_path, practice="0", measurement_runs=1, time=1.0)
    protocol = load_protocol(path)
    out = tmp_path / "out"
    run_session(
        protocol,
        "P02",
        out,
        device_factory=lambda run: ScriptedInput(stick(run.number, 100)),
        clock=ManualClock(),
        show=False,
    )
    before = {p.name: p.read_bytes() for p in (out / "P02").iterdir()}
    other = load_protocol(protocol_file(tmp_path, practice="0", measurement_runs=2, time=1.0))
    with pytest.raises(SessionError) as error:
        run_session(other, "P02", out, device_factory=scripted, clock=ManualClock(), show=False)
    message = str(error.value)
    assert "this folder holds a session of another protocol" in message
    assert "condition[SI].measurement_runs: 1 -> 2" in message
    assert "give that protocol, or another --out folder for a new session" in message
    assert {p.name: p.read_bytes() for p in (out / "P02").iterdir()} == before
    counterbalanced = load_protocol(
        protocol_file(tmp_path, order="counterbalanced", practice="0", measurement_runs=1, time=1.0)
    )
    with pytest.raises(SessionError, match="another protocol"):
        run_session(counterbalanced, "P02", out, show=False)
    (tmp_path / "loose").mkdir()
    (tmp_path / "loose" / "P02").mkdir()
    (tmp_path / "loose" / "P02" / "run.npz").write_bytes(b"x")
    with pytest.raises(SessionError, match=r"holds recordings but no session\.json"):
        run_session(protocol, "P02", tmp_path / "loose", show=False)
    with pytest.raises(SessionError, match="no participant"):
        run_session(protocol, None, out, show=False)


def test_no_joystick_is_said_by_the_device(tmp_path, no_joystick):
    path = protocol_file(tmp_path, practice="0", measurement_runs=1, time=1.0)
    path.write_text(
        path.read_text().replace("[breaks]", '[input]\ndevice = "joystick"\n\n[breaks]')
    )
    protocol = load_protocol(path)
    with pytest.raises(NoInputDevice, match="no joystick or gamepad found"):
        run_session(protocol, "P01", tmp_path / "out", clock=ManualClock(), show=False)


# ------------------------------------------------------------------ the command


def parse(*argv):
    parser = argparse.ArgumentParser()
    add_session_arguments(parser)
    return parser.parse_args(list(argv))


def command(path, *argv, device_factory=None, keys=()):
    args = parse(str(path), *argv)
    factory = device_factory or (lambda run: ScriptedInput(stick(run.number, 100)))
    return run_session_command(
        args, device_factory=factory, clock=ManualClock(), show=screen(*keys)
    )


def test_the_command_runs_reports_and_resumes(tmp_path, capsys, pygame):
    path = protocol_file(tmp_path, practice="1", measurement_runs=1, time=1.0)
    out = tmp_path / "out"

    def closing_in_run_3(run):
        if run.number == 3:
            return ClosesTheWindow(stick(run.number, 100), at=20)
        return ScriptedInput(stick(run.number, 100))

    code = command(path, "--participant", "P01", "--out", str(out), device_factory=closing_in_run_3)
    assert code == 1
    captured = capsys.readouterr()
    (line,) = captured.err.strip().splitlines()
    assert line.startswith(
        "manualcontrol experiment: the window was closed during run 3 of 4 (DI practice 1 of 1); "
        f"kept runs 1-2 in {out / 'P01'}; to resume at run 3, run again: manualcontrol "
        f"experiment {path} --participant P01 --out {out}"
    )
    assert "run 2 of 4 (SI measurement 1 of 1): RMS error" in captured.out
    assert command(path, "--participant", "P01", "--out", str(out)) == 0
    printed = capsys.readouterr().out
    assert "resuming: kept runs 1-2" in printed and "continuing at run 3" in printed
    assert f"wrote {out / 'P01' / 'report' / 'report.md'}" in printed
    assert (out / "P01" / "report" / "rms.png").is_file()
    assert command(path, "--participant", "P01", "--out", str(out), "--report-only") == 0
    assert main([str(path), "--participant", "P01", "--plan"]) == 0
    assert "  4  04-DI-measurement-1.npz  (DI measurement 1 of 1, realisation 0)" in (
        capsys.readouterr().out
    )


def test_the_command_refuses_bad_protocols_and_flags(tmp_path, capsys):
    path = protocol_file(tmp_path, practice="-1")
    assert command(path, "--participant", "P01", "--out", str(tmp_path)) == 2
    assert capsys.readouterr().err.strip() == (
        f"manualcontrol experiment: error: {path}: practice must be a whole number >= 0, got -1"
    )
    good = protocol_file(tmp_path, practice="0", measurement_runs=1, time=1.0)
    assert command(good, "--out", str(tmp_path)) == 2
    assert "no participant: give --participant ID" in capsys.readouterr().err
    assert command(good, "--participant", "P 1", "--out", str(tmp_path)) == 2
    assert "--participant must be letters, digits" in capsys.readouterr().err
    assert command(good, "--participant", "P1", "--input", "keyboard", "--range", "2") == 2
    assert capsys.readouterr().err.strip() == (
        "manualcontrol experiment: error: range applies to the mouse and the joystick, not the "
        "keyboard"
    )
    assert main([str(good), "--dead-zone", "2"]) == 2
    assert "argument --dead-zone: must be a number in [0, 1), got '2'" in capsys.readouterr().err
    assert command(good, "--participant", "P1", "--plan", "--report-only") == 2
    assert "give one of them" in capsys.readouterr().err
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    assert command(good, "--participant", "P1", "--out", str(blocker)) == 2
    assert f"--out {blocker}: a file, not a folder" in capsys.readouterr().err


def test_the_command_says_no_joystick_before_any_window(tmp_path, capsys, no_joystick, pygame):
    good = protocol_file(tmp_path, practice="0", measurement_runs=1, time=1.0)
    argv = [
        str(good),
        "--participant",
        "P01",
        "--out",
        str(tmp_path / "out"),
        "--input",
        "joystick",
    ]
    assert main(argv) == 2
    assert capsys.readouterr().err.strip() == (
        "manualcontrol experiment: error: no joystick or gamepad found (pygame sees 0); plug "
        "one in or use --input mouse/keyboard"
    )
    assert not pygame.display.get_init()
    assert not (tmp_path / "out").exists()


def test_ctrl_c_exits_130_with_one_line(tmp_path, capsys):
    good = protocol_file(tmp_path, practice="0", measurement_runs=2, time=1.0)
    out = tmp_path / "out"

    def device(run):
        values = stick(run.number, 100)
        return PressesCtrlC(values) if run.number == 2 else ScriptedInput(values)

    code = command(good, "--participant", "P01", "--out", str(out), device_factory=device)
    assert code == 130
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == (
        "manualcontrol experiment: interrupted (Ctrl-C) during run 2 of 4 (SI measurement 2 of "
        f"2); kept run 1 in {out / 'P01'}; to resume, run again: manualcontrol experiment "
        f"{good} --participant P01 --out {out}"
    )


def test_runs_as_a_module(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "manualcontrol.human.session_cli", str(tmp_path / "none.toml")],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 2
    assert "none.toml: no such protocol file" in result.stderr


def test_an_unplugged_joystick_stops_the_session_and_keeps_the_runs(
    tmp_path, capsys, fake_joystick, pygame
):
    path = protocol_file(tmp_path, practice="0", measurement_runs=1, time=1.0)
    path.write_text(
        path.read_text().replace("[breaks]", '[input]\ndevice = "joystick"\n\n[breaks]')
    )
    reads = []

    def axis(i):
        reads.append(i)
        if len(reads) == 150:  # during run 2
            pygame.event.post(pygame.event.Event(pygame.JOYDEVICEREMOVED, instance_id=7))
        return 0.1

    fake_joystick.get_axis = axis
    out = tmp_path / "out"
    args = parse(str(path), "--participant", "P01", "--out", str(out), "--no-report")
    assert run_session_command(args, clock=ManualClock(), show=screen()) == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(
        "manualcontrol experiment: the joystick 'Test pad' was unplugged during run 2 of 2 "
        f"(DI measurement 1 of 1); kept run 1 in {out / 'P01'}; to resume at run 2"
    )
    assert sorted(p.name for p in (out / "P01").iterdir()) == [
        "01-SI-measurement-1.npz",
        "session.json",
    ]
    recording = Recording.load(out / "P01" / "01-SI-measurement-1.npz")
    assert recording.metadata["input"]["device"] == "joystick"
    assert recording.metadata["input"]["dead_zone"] == 0.05
