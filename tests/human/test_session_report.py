"""The session report: a precision pilot flown through a whole session gives the very
identification of the pilot flown directly (the play path adds no error of its own),
the report is written whole or not at all, and what cannot be measured says why."""

import json
import math

import numpy as np
import pytest

from manualcontrol.envs.recording import Recording
from manualcontrol.estimators.analysis.identification import build_estimator, identify
from manualcontrol.human import report as report_module
from manualcontrol.human.devices import ScriptedInput
from manualcontrol.human.protocol import load_protocol
from manualcontrol.human.realtime import ManualClock
from manualcontrol.human.report import write_session_report
from manualcontrol.human.session import PygameScreen, ScriptedKeys, SessionError, run_session
from manualcontrol.pilots import Pilot

PERIOD = 4.0
FREQUENCIES = [2.0 * math.pi * k / PERIOD for k in (1, 2, 3, 5, 8, 13, 21)]
PROTOCOL = f"""
name = "play-path"
practice = 1
measurement_runs = 4

[[condition]]
name = "SI"
task = "compensatory"
element = "SI"
measurement_time = {PERIOD}
scale = 8.0

[condition.forcing]
name = "fast"

[condition.forcing.target]
frequencies = {FREQUENCIES!r}
amplitudes = [1.0, 0.8, 0.6, 0.4, 0.25, 0.15, 0.1]
phases = [0.0, 1.1, 2.3, 0.4, 5.0, 3.3, 1.7]
measurement_time = {PERIOD}
"""
SCALE = 8.0  # a power of two: scale * (u / scale) is u, bit for bit


def simulated(condition, run):
    """The typical precision pilot (remnant included) flying the condition's env directly."""
    env = condition.make_env().unwrapped
    observation, _ = env.reset(seed=run.seed, options={"realisation": run.realisation})
    pilot = Pilot.typical("precision", "SI", remnant="popovici2017")
    pilot.reset(run.index, env=env)
    done = False
    while not done:
        observation, _, terminated, truncated, _ = env.step(pilot.act(observation))
        done = terminated or truncated
    return env.recording()


def test_the_play_path_adds_no_error_over_a_whole_session(tmp_path, pygame):
    path = tmp_path / "protocol.toml"
    path.write_text(PROTOCOL)
    protocol = load_protocol(path)
    condition = protocol.condition("SI")
    plan = protocol.runs("P01")
    direct = {run.number: simulated(condition, run) for run in plan if run.kind == "measurement"}

    def device(run):
        if run.kind == "practice":
            return ScriptedInput(np.zeros(400))
        sticks = direct[run.number].u / SCALE
        assert np.max(np.abs(sticks)) < 1.0  # within the stick's travel
        return ScriptedInput(sticks)

    out = tmp_path / "out"
    result = run_session(
        protocol,
        "P01",
        out,
        device_factory=device,
        clock=ManualClock(),
        show=PygameScreen(ScriptedKeys()),
    )
    assert result.complete and len(result.files) == 5
    for number, recording in direct.items():
        flown = Recording.load(result.folder / plan[number - 1].file_name)
        for name in ("t", "u", "e", "y", "ft", "fd"):
            np.testing.assert_array_equal(flown[name], recording[name])
    report = write_session_report(out, "P01")
    identification = report.data["conditions"]["SI"]["identification"]
    assert identification["estimator"] == "rml" and identification["model"] == "precision"
    assert [run["run"] for run in identification["runs"]] == sorted(direct)
    finals = []
    for entry in identification["runs"]:
        theirs = identify(
            direct[entry["run"]],
            build_estimator("rml", model="precision", element="SI"),
            element="SI",
            forcing=condition.forcing_pair(0),
        )
        summary = entry["summary"]
        assert summary["final"] == theirs.final  # the same numbers
        assert all(math.isfinite(value) for value in theirs.final.values())
        assert summary["closed_loop"] == theirs.closed_loop
        assert summary["fit"] == json.loads(json.dumps(report_module._clean(theirs.summary["fit"])))
        finals.append(theirs.final)
    for name, value in identification["mean"].items():
        assert value == pytest.approx(np.mean([final[name] for final in finals]), rel=1e-12)
    describing = report.data["conditions"]["SI"]["describing_function"]
    assert describing["mean"]["runs"] == sorted(direct)
    assert len(describing["runs"]) == 4
    assert "| 2 | SI | measurement | 1 |" in report.markdown.read_text()


SHORT = """
name = "short"
measurement_runs = 1

[[condition]]
name = "SI"
task = "compensatory"
element = "SI"
forcing = "vanderel-bw4"
measurement_time = 2.0

[[condition]]
name = "PV"
task = "preview"
element = "SI"
forcing = "popovici2017"
measurement_time = 1.0
"""


@pytest.fixture
def short_session(tmp_path):
    path = tmp_path / "short.toml"
    path.write_text(SHORT)
    protocol = load_protocol(path)
    rng = np.random.default_rng(0)
    run_session(
        protocol,
        "P09",
        tmp_path / "out",
        device_factory=lambda run: ScriptedInput(np.cumsum(rng.normal(0.0, 0.05, 200))),
        clock=ManualClock(),
        show=False,
    )
    return tmp_path / "out"


def test_what_cannot_be_measured_or_identified_says_why(short_session):
    report = write_session_report(short_session, "P09")
    text = report.markdown.read_text()
    assert (
        "Not measured: run 1: the recording (2 s) is shorter than one forcing period (120 s)."
    ) in text
    assert (
        "Not measured: run 2: the recording (1 s) is shorter than one forcing period (90 s)."
    ) in text
    assert "Not identified: run 2: the preview model needs anticipation_time (s)" in text
    assert len(report.data["conditions"]["SI"]["identification"]["runs"]) == 1
    assert report.data["session"]["status"] == "complete"
    assert [p.name for p in report.figures] == ["rms.png", "SI-traces.png"]


def test_the_report_is_replaced_whole_or_left_as_it_was(short_session, monkeypatch):
    first = write_session_report(short_session, "P09")
    before = {p.name: p.read_bytes() for p in first.folder.iterdir()}

    def broken(data, figures):
        raise OSError("disk full")

    monkeypatch.setattr(report_module, "_markdown", broken)
    with pytest.raises(OSError, match="disk full"):
        write_session_report(short_session, "P09")
    assert {p.name: p.read_bytes() for p in first.folder.iterdir()} == before
    folder = short_session / "P09"
    assert sorted(p.name for p in folder.iterdir() if p.name.startswith(".")) == []
    monkeypatch.undo()
    again = write_session_report(short_session, "P09")
    assert again.folder == first.folder and (again.folder / "report.md").is_file()
    assert sorted(p.name for p in folder.iterdir() if p.name.startswith(".")) == []


def test_a_folder_without_a_session_is_refused(tmp_path):
    with pytest.raises(SessionError, match="no session here"):
        write_session_report(tmp_path, "P01")


def test_a_pure_gains_identification_says_the_precision_model_lacks_the_humans_lag(tmp_path):
    path = tmp_path / "gain.toml"
    path.write_text(SHORT.replace('element = "SI"', 'element = "gain"', 1))
    rng = np.random.default_rng(0)
    run_session(
        load_protocol(path),
        "P10",
        tmp_path / "out",
        device_factory=lambda run: ScriptedInput(np.cumsum(rng.normal(0.0, 0.05, 200))),
        clock=ManualClock(),
        show=False,
    )
    report = write_session_report(tmp_path / "out", "P10")
    caution = report.data["conditions"]["SI"]["identification"]["caution"]
    assert caution.startswith("On a pure gain humans equalise with a lag")
    assert caution in report.markdown.read_text()
    # with the lag's model asked for, nothing is missing and nothing is said
    again = write_session_report(
        tmp_path / "out", "P10", estimator_settings={"SI": {"model": "precision-lag"}}
    )
    identification = again.data["conditions"]["SI"]["identification"]
    assert identification["model"] == "precision-lag" and "caution" not in identification
