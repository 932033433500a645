"""A lane-keeping agent evaluated beside the cybernetic driver on the same random roads."""

import json

import gymnasium as gym
import numpy as np
import pytest

import manualcontrol.envs  # noqa: F401
from manualcontrol.agents.evaluation import (
    evaluate_lane_keeping,
    fly,
    write_lane_keeping_report,
)
from manualcontrol.agents.recipes import recipe
from manualcontrol.agents.training import train
from manualcontrol.bench.cli import EXIT_OK, main
from manualcontrol.pilots.driver import Driver


@pytest.fixture(scope="module")
def agent(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lane")
    return train(recipe("lane-angle", total_timesteps=256), folder, report=None), folder


def test_each_road_is_scored_whole_beside_the_driver_on_the_same_road(agent):
    trained, _ = agent
    evaluation = evaluate_lane_keeping(trained, roads=(1003, 1004))
    assert evaluation.roads == (1003, 1004)
    # the driver's figures are those of an independent run on the same road
    for index, road in enumerate(evaluation.roads):
        env = gym.make(
            "ManualControl/LaneKeeping-v0", road="random", steering="angle", loss_of_control=False
        )
        driven = fly(Driver(), env, road)
        offset = np.asarray(driven["y_L"])
        assert evaluation.driver_rms_offset[index] == pytest.approx(
            np.sqrt(np.mean(offset**2)), rel=1e-12
        )
    # an untrained agent leaves its lane, and is still driven to the road's end
    whole = evaluation.recording
    assert whole.duration == pytest.approx(evaluation.driver_recording.duration, abs=0.02)
    assert evaluation.left_lane[0] == (evaluation.max_offset[0] > evaluation.lane_limit)
    expected = np.sqrt(np.mean(np.square(evaluation.rms_offset))) / np.sqrt(
        np.mean(np.square(evaluation.driver_rms_offset))
    )
    assert evaluation.rms_ratio == pytest.approx(expected, rel=1e-12)


def test_the_report_and_the_command(agent, tmp_path, capsys):
    trained, folder = agent
    evaluation = evaluate_lane_keeping(trained, roads=(1000,))
    path = write_lane_keeping_report(evaluation, tmp_path / "report")
    summary = json.loads((tmp_path / "report" / "evaluation.json").read_text())
    assert summary["roads"] == [1000] and summary["task"] == "lane-keeping"
    assert (tmp_path / "report" / "lane_offset.png").read_bytes().startswith(b"\x89PNG")
    assert "kept the lane on" in path.read_text()
    code = main(["evaluate", str(folder), "--seed", "2", "--out", str(tmp_path / "cli")])
    out = capsys.readouterr().out
    assert code == EXIT_OK
    # five roads from 1000 + seed, each a line beside the driver's figures
    assert [line.split()[0] for line in out.splitlines()[1:6]] == [
        "1002",
        "1003",
        "1004",
        "1005",
        "1006",
    ]
    assert "times the driver's" in out


def test_a_tracking_agent_is_refused(agent):
    import dataclasses

    trained, _ = agent
    tracking = dataclasses.replace(trained, config=recipe("si", total_timesteps=64))
    with pytest.raises(ValueError, match="takes a lane-keeping agent, got task 'compensatory'"):
        evaluate_lane_keeping(tracking)
    with pytest.raises(ValueError, match="roads must name at least one road seed"):
        evaluate_lane_keeping(trained, roads=())


def test_the_wrappers_noise_is_on_unless_deterministic(agent):
    import dataclasses

    trained, _ = agent
    noisy_config = dataclasses.replace(
        trained.config,
        wrappers=(*trained.config.wrappers, {"kind": "motor_noise", "power_ratio": 0.3}),
    )
    noisy = dataclasses.replace(trained, config=noisy_config)
    bare = evaluate_lane_keeping(trained, roads=(1000,))
    silenced = evaluate_lane_keeping(noisy, roads=(1000,), deterministic=True)
    heard = evaluate_lane_keeping(noisy, roads=(1000,))
    # the motor noise, silenced, leaves the agent's own run; on, it moves the car
    assert silenced.rms_offset == bare.rms_offset
    assert heard.rms_offset != bare.rms_offset
    with pytest.raises(TypeError, match="deterministic must be True, False or None"):
        evaluate_lane_keeping(trained, roads=(1000,), deterministic="yes")
