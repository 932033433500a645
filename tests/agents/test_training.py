"""Training plumbing with tiny runs: saving, weights-only reloading, evaluation report."""

import dataclasses
import json
import os
import re
import shutil
import sys
import tempfile

import gymnasium as gym
import numpy as np
import pytest
import torch

from manualcontrol.agents.evaluation import REFERENCE_PILOTS, evaluate, write_report
from manualcontrol.agents.training import (
    VALIDATION_SEED,
    TrainingConfig,
    _BackgroundValidation,
    _validate_in_background,
    _ValidationWorkerError,
    load_agent,
    make_env,
    train,
    validation_score,
)

DELAY = ({"kind": "action_delay", "delay": 0.2},)
#: PPO on 2-s episodes, two updates of 64 steps: for what a training does around PPO.
TINY_PPO = dict(
    env_kwargs={"measurement_time": 2.0},
    algorithm="ppo",
    total_timesteps=128,
    n_envs=2,
    algorithm_kwargs={"n_steps": 32, "batch_size": 32, "n_epochs": 1},
)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    folder = tmp_path_factory.mktemp("agent")
    config = TrainingConfig(
        task="compensatory",
        env_kwargs={"measurement_time": 5.0, "forcing": "plaetinck2018"},
        wrappers=DELAY,
        algorithm="sac",
        total_timesteps=300,
        algorithm_kwargs={"learning_starts": 100, "batch_size": 32},
        policy_kwargs={"net_arch": [16, 16]},
        checkpoint_every=100,
    )
    lines = []
    agent = train(config, folder, report=lines.append, report_every=100)
    return config, agent, folder, lines


def test_training_writes_weights_config_and_checkpoints(trained):
    config, _, folder, lines = trained
    assert json.loads((folder / "config.json").read_text()) == config.to_dict()
    assert (folder / "policy.pt").is_file() and (folder / "model.zip").is_file()
    assert sorted(p.name for p in (folder / "checkpoints").iterdir()) == [
        "policy_100.pt",
        "policy_200.pt",
        "policy_300.pt",
    ]
    assert len(lines) == 3 and "300/300 steps" in lines[-1]
    assert not list(folder.glob(".*part*"))


def test_reloaded_agent_acts_identically(trained):
    config, agent, folder, _ = trained
    env = make_env(config)
    observations = [env.reset(seed=1)[0]]
    for _ in range(20):
        observations.append(env.step(agent.act(observations[-1]))[0])
    weights_only = load_agent(folder)
    pickled = load_agent(folder, trust_pickle=True)
    for observation in observations:
        expected = agent.act(observation)
        np.testing.assert_array_equal(weights_only.act(observation), expected)
        np.testing.assert_array_equal(pickled.act(observation), expected)
    assert weights_only.config == config


def test_ppo_trains_too_and_writes_nothing_outside_its_folder(tmp_path, monkeypatch):
    # stable-baselines3's default logger makes a folder in the temporary directory on
    # every learn(); the training's own logger must not
    scratch = tmp_path / "system-temp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    monkeypatch.delenv("SB3_LOGDIR", raising=False)
    config = TrainingConfig(**TINY_PPO)
    agent = train(config, tmp_path / "agent", report=None)
    action = agent.act(np.zeros(1))
    assert action.shape == (1,) and np.isfinite(action).all()
    # (torch may keep a cache folder there; the logger's folders are stable-baselines3's)
    assert list(scratch.glob("SB3-*")) == []
    assert (tmp_path / "agent" / "policy.pt").is_file()


def test_the_training_envs_pass_no_step_info_and_train_as_with_it(tmp_path, monkeypatch):
    """SB3 deep-copies every env's info each step; training reads none of ours, so it goes.

    The same PPO run with the info passed on (the wrapper made a no-op) ends in the same
    weights, bit for bit, and what PPO reads (the Monitor's episodes) is still there.
    """
    from stable_baselines3.common.env_util import make_vec_env

    from manualcontrol.agents import training

    config = TrainingConfig(**TINY_PPO)
    vec_env = make_vec_env(lambda: training._NoStepInfo(make_env(config)), n_envs=1, seed=0)
    vec_env.reset()
    infos = []
    for _ in range(250):  # past the end of a 2-s episode
        infos += vec_env.step(np.zeros((1, 1)))[3]
    vec_env.close()
    assert set().union(*infos) <= {"episode", "terminal_observation", "TimeLimit.truncated"}
    assert any("episode" in info for info in infos)

    def weights(folder):
        state = train(config, folder, report=None).policy.state_dict()
        return {name: value.numpy().tobytes() for name, value in state.items()}

    slim = weights(tmp_path / "slim")
    monkeypatch.setattr(training, "_NoStepInfo", lambda env: env)
    assert weights(tmp_path / "full") == slim


def test_training_computes_on_one_torch_thread_and_restores_the_count(tmp_path):
    # the same seed must train the same weights whatever the machine's core count
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        during = []
        config = TrainingConfig(**{**TINY_PPO, "total_timesteps": 64})
        train(
            config,
            tmp_path,
            report=lambda _: during.append(torch.get_num_threads()),
            report_every=32,
        )
        assert during and set(during) == {1}
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_evaluation_report(trained, tmp_path):
    _, agent, _, _ = trained
    evaluation = evaluate(agent, run_in=2.0)
    summary = evaluation.summary()
    recording = evaluation.recording
    assert recording.duration == pytest.approx(81.92)
    assert summary["rms_error"] == pytest.approx(float(np.sqrt(np.mean(recording.e**2))))
    assert summary["reference_rms_error"] > 0
    assert set(summary["identified"]) == {"K_p", "K_v", "tau_v", "omega_nms", "zeta_nms"}
    assert set(summary["dekf"]) == {"K_p", "tau_v", "omega_nms", "zeta_nms"}  # SI: K_v held
    # the output-error fit holds the lead at 0 on K/s too, and the report says so
    assert summary["identified"]["K_v"] == 0.0 and "K_v" not in evaluation.identified.fitted
    assert summary["limitations"] == [{"kind": "action_delay", "delay": 0.2}]
    path = write_report(evaluation, tmp_path)
    text = path.read_text()
    assert "RMS tracking error" in text and "tau_v" in text and "DEKF" in text
    assert "| K_v | 0 (held at 0: no lead on this element) |" in text
    assert (tmp_path / "open_loop.png").read_bytes().startswith(b"\x89PNG")
    assert (
        json.loads((tmp_path / "evaluation.json").read_text())["rms_error"] == summary["rms_error"]
    )
    # measured as a human is: figures, verdict and the Bode plot beside open_loop.png
    human = evaluation.human
    assert evaluation.noise and summary["noise"]  # the wrappers' noise on by default
    assert set(summary["human_likeness"]["figures"]) == {
        "crossover_frequency",
        "phase_margin",
        "effective_delay",
        "pilot_gain_flatness",
        "lead",
        "remnant_fraction",
        "rms_ratio",
    }
    assert human.rms_error == pytest.approx(summary["rms_error"])
    assert human.reference == pytest.approx(REFERENCE_PILOTS["SI"])
    # the frequency-domain reference and the env's reference run agree (one period each)
    assert human.reference_rms_error == pytest.approx(summary["reference_rms_error"], rel=0.02)
    assert summary["bare_task_rms_ratio"] == pytest.approx(
        summary["rms_error"] / summary["reference_rms_error"]
    )
    assert "## Human-likeness" in text and "verdict:" in text
    assert (tmp_path / "human_likeness.png").read_bytes().startswith(b"\x89PNG")


def test_evaluation_plots_further_models_and_runs_deterministically(trained, tmp_path):
    _, agent, _, _ = trained
    evaluation = evaluate(agent, run_in=2.0, deterministic=True)
    assert not evaluation.noise
    calls = []

    def model(omega):
        calls.append(omega)
        return 1.3 * np.exp(-0.3j * omega)

    write_report(evaluation, tmp_path, models={"a gain-delay pilot": model})
    assert calls and (tmp_path / "human_likeness.png").is_file()


def test_evaluate_command_prints_the_human_likeness(trained, tmp_path, capsys):
    from manualcontrol.bench.cli import main

    _, _, folder, _ = trained
    assert main(["evaluate", str(folder), "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    for name in ("crossover_frequency", "phase_margin", "effective_delay", "remnant_fraction"):
        assert name in out
    assert "rms_ratio" in out and "verdict:" in out
    assert (tmp_path / "human_likeness.png").is_file()


def test_evaluation_covers_the_whole_period_despite_loss_of_control(trained):
    """A training-time termination limit must not cut the evaluation short."""
    config, agent, _, _ = trained
    strict = TrainingConfig(
        **{**config.to_dict(), "env_kwargs": {**config.env_kwargs, "loss_of_control": 1e-6}}
    )
    strict_agent = dataclasses.replace(agent, config=strict)
    env = make_env(strict)
    env.reset(seed=0)
    assert env.step(strict_agent.act(np.zeros(env.observation_space.shape)))[2]  # terminates
    evaluation = evaluate(strict_agent, run_in=2.0)
    assert evaluation.recording.duration == pytest.approx(81.92)


def test_evaluation_over_several_periods_reads_them_together(trained):
    """Two periods measured as one: each forcing line is the mean of its two periods."""
    from manualcontrol.envs.signals import ForcingPair

    _, agent, _, _ = trained
    evaluation = evaluate(agent, run_in=2.0, periods=2)
    recording = evaluation.recording
    assert recording.duration == pytest.approx(2 * 81.92)
    assert evaluation.summary()["periods"] == 2 and evaluation.human.describing.periods == 2
    # independent: each period's own Fourier coefficients, averaged over the periods
    n = len(recording.u) // 2
    target = ForcingPair.from_dict(recording.metadata["forcing"]).target
    lines = np.asarray(target.harmonics, dtype=int)
    u = np.fft.rfft(recording.u.reshape(2, n), axis=1).mean(axis=0)[lines]
    e = np.fft.rfft(recording.e.reshape(2, n), axis=1).mean(axis=0)[lines]
    np.testing.assert_allclose(evaluation.frequency_response.pilot, u / e, rtol=1e-9)
    describing = evaluation.human.describing
    at_target = np.array([source == "target" for source in describing.source])
    np.testing.assert_allclose(describing.pilot[at_target], u / e, rtol=1e-9)


def test_evaluation_periods_must_be_whole_and_not_fight_a_measurement_time(trained, capsys):
    from manualcontrol.bench.cli import EXIT_USAGE, main

    _, agent, folder, _ = trained
    with pytest.raises(ValueError, match="periods must be >= 1, got 0"):
        evaluate(agent, periods=0)
    with pytest.raises(ValueError, match="give periods or env_overrides"):
        evaluate(agent, periods=2, env_overrides={"measurement_time": 10.0})
    assert main(["evaluate", str(folder), "--periods", "0"]) == EXIT_USAGE
    assert "argument --periods: must be >= 1, got 0" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("kwargs", "error", "message"),
    [
        ({"algorithm": "dqn"}, ValueError, "algorithm must be one of 'ppo', 'sac', got 'dqn'"),
        (
            {"task": "gap"},
            ValueError,
            "task must be one of 'compensatory', 'pursuit', 'preview', 'lane-keeping', got 'gap'",
        ),
        ({"total_timesteps": 0}, ValueError, "total_timesteps must be >= 1, got 0"),
        ({"wrappers": ({"kind": "fatigue"},)}, ValueError, "wrapper kind must be one of"),
        (
            {"env_kwargs": {"controlled_element": "TI"}},
            ValueError,
            "controlled element must be one of",
        ),
        ({"select_every": 0}, ValueError, "select_every must be >= 1, got 0"),
        ({"select_episodes": 0}, ValueError, "select_episodes must be >= 1, got 0"),
        ({"select_seed": -1}, ValueError, "select_seed must be >= 0, got -1"),
    ],
)
def test_bad_configurations_fail_before_training(kwargs, error, message):
    with pytest.raises(error, match=re.escape(message)):
        TrainingConfig(**kwargs)


def test_loading_a_folder_without_an_agent_fails(tmp_path):
    with pytest.raises(FileNotFoundError, match=re.escape("has no config.json")):
        load_agent(tmp_path)


def test_an_agent_with_scheduled_limitations_and_a_history_trains_and_reloads(tmp_path):
    from manualcontrol.envs.schedules import Ramp, Step

    config = TrainingConfig(
        env_kwargs={"measurement_time": 2.0},
        wrappers=({"kind": "action_delay", "delay": Ramp(0.1, 0.15, 0.0, 2.0)},),
        observation_noise_ratio=Step(0.01, 0.02, 1.0),
        effort_rate_weight=0.05,
        history_length=3,
        algorithm="ppo",
        total_timesteps=64,
        algorithm_kwargs={"n_steps": 32, "batch_size": 32, "n_epochs": 1},
    )
    agent = train(config, tmp_path, report=None)
    saved = json.loads((tmp_path / "config.json").read_text())
    assert saved["observation_noise_ratio"]["kind"] == "step"
    assert saved["wrappers"][0]["delay"]["kind"] == "ramp"
    reloaded = load_agent(tmp_path)
    assert reloaded.config == config
    env = make_env(reloaded.config)
    observation, _ = env.reset(seed=0)
    assert observation.shape == (3 * (1 + 15),)  # history of [e, 15 queued commands]
    np.testing.assert_array_equal(reloaded.act(observation), agent.act(observation))


def test_the_optimal_control_reference_takes_the_agents_task_and_delay():
    from manualcontrol.agents.evaluation import optimal_control_reference

    config = TrainingConfig(
        task="compensatory",
        env_kwargs={"controlled_element": "DI", "forcing": "popovici2017"},
        wrappers=({"kind": "action_delay", "delay": 0.25},),
        algorithm="ppo",
    )
    ocm = optimal_control_reference(config)
    assert ocm.tau_v == 0.25
    # the model is the OCM of that element: on K/s^2 it leads (phase above the delay's)
    omega = np.array([0.5, 1.0])
    lead = np.angle(ocm.frequency_response(omega)) + omega * 0.25
    assert np.all(lead > 0.0)
    pursuit = TrainingConfig(task="pursuit", algorithm="ppo")
    assert optimal_control_reference(pursuit) is None


@pytest.mark.parametrize("damage", ["truncated", "garbage", "foreign"])
def test_corrupt_policy_weights_are_refused_naming_the_file(trained, tmp_path, damage):
    _, _, folder, _ = trained
    copy = tmp_path / "agent"
    shutil.copytree(folder, copy)
    weights = copy / "policy.pt"
    if damage == "truncated":
        weights.write_bytes(weights.read_bytes()[:100])
    elif damage == "garbage":
        weights.write_bytes(b"\x00\x01 not torch at all")
    else:  # a valid torch file of another network
        torch.save({"layer.weight": torch.zeros(3, 3)}, weights)
    with pytest.raises(ValueError, match=re.escape(f"{weights} is not the weights of this agent")):
        load_agent(copy)


@pytest.mark.parametrize(
    ("element", "held"),
    [
        ("1/s", {"K_v": 0.0}),
        ("2.5/s", {"K_v": 0.0}),
        ("1/s^2", {}),
        ("1/(s(s+1))", {}),
        ("gain", {"K_v": 0.0}),
    ],
)
def test_the_output_error_fit_holds_the_lead_on_a_single_integrator_and_a_gain_only(element, held):
    from manualcontrol.agents.evaluation import _fitted_structure, _held_by_rule
    from manualcontrol.pilots import make_model

    env = gym.make(
        "ManualControl/CompensatoryTracking-v0", controlled_element=element, measurement_time=1.0
    )
    env.reset(seed=0)
    env.step(np.zeros(1))
    recording = env.unwrapped.recording()
    env.close()
    structure = _fitted_structure(recording, "precision")
    # on a pure gain the fit identifies the lag's precision model (humans lag there)
    assert structure == make_model("precision", lag=element == "gain")
    assert _held_by_rule(recording, structure) == held
    assert _held_by_rule(recording, make_model("gain-delay")) == {}  # a model without a lead


#: A short PPO training whose policy changes enough between validations to score
#: differently: the starting weights, four validations during training and the final
#: weights.
SELECTED = TrainingConfig(
    env_kwargs={"measurement_time": 2.0},
    wrappers=DELAY,
    algorithm="ppo",
    total_timesteps=256,
    n_envs=2,
    algorithm_kwargs={"n_steps": 32, "batch_size": 32, "n_epochs": 2, "learning_rate": 0.01},
    policy_kwargs={"net_arch": [16, 16]},
    select_every=64,
    select_episodes=3,
)


@pytest.fixture(scope="module")
def selected(tmp_path_factory):
    folder = tmp_path_factory.mktemp("selected")
    lines = []
    train(SELECTED, folder, report=lines.append, report_every=10_000, validate_in_background=True)
    return folder, json.loads((folder / "selection.json").read_text()), lines


def test_selection_keeps_the_weights_that_validate_best(selected):
    folder, selection, lines = selected
    history = selection["history"]
    # the starting weights, four validations during training and the final weights
    assert [entry["step"] for entry in history] == [0, 64, 128, 192, 256, 256]
    assert [entry["final"] for entry in history] == [False] * 5 + [True]
    scores = [entry["score"] for entry in history]
    assert len(set(scores)) > 1  # the weights changed between validations
    best = max(range(len(scores)), key=lambda i: (scores[i], i))  # ties: the later
    assert selection["kept_score"] == scores[best]
    assert selection["kept_step"] == history[best]["step"]
    # policy.pt holds the kept weights: validated again, they score what they scored
    kept = load_agent(folder)
    assert validation_score(kept.policy, SELECTED, 3) == selection["kept_score"]
    final = load_agent(folder)
    final.policy.load_state_dict(torch.load(folder / "policy_final.pt", weights_only=True))
    assert validation_score(final.policy, SELECTED, 3) == scores[-1]
    assert f"kept the weights of step {selection['kept_step']:,d}" in lines[-1]


def test_selection_leaves_the_training_itself_unchanged(selected, tmp_path):
    folder, _, _ = selected
    plain = dataclasses.replace(SELECTED, select_every=None)
    train(plain, tmp_path, report=None)
    assert not (tmp_path / "selection.json").exists()
    expected = torch.load(tmp_path / "policy.pt", weights_only=True)
    final = torch.load(folder / "policy_final.pt", weights_only=True)
    assert expected.keys() == final.keys()
    for key, value in expected.items():
        assert torch.equal(final[key], value), key


def test_validating_in_this_process_keeps_what_the_background_process_kept(selected, tmp_path):
    folder, selection, _ = selected
    # kept weights other than the final ones: a state read at the end instead of when
    # it was validated would show
    assert selection["kept_score"] != selection["history"][-1]["score"]
    train(SELECTED, tmp_path, report=None, validate_in_background=False)
    # the same weights flown on the same episodes score the same, bit for bit
    assert json.loads((tmp_path / "selection.json").read_text()) == selection
    for name in ("policy.pt", "policy_final.pt"):
        here = torch.load(tmp_path / name, weights_only=True)
        there = torch.load(folder / name, weights_only=True)
        assert here.keys() == there.keys()
        for key, value in here.items():
            assert torch.equal(there[key], value), (name, key)


def test_a_validation_the_background_process_cannot_fly_is_reported(selected):
    folder, _, _ = selected
    weights = load_agent(folder).policy.state_dict()
    worker = _BackgroundValidation(SELECTED)
    try:
        worker.submit({**weights, "extra": torch.zeros(1)}, 3)
        with pytest.raises(_ValidationWorkerError, match="validation 1 failed there: ") as e:
            worker.scores()
        assert 'Unexpected key(s) in state_dict: "extra"' in str(e.value)
    finally:
        worker.close()
    worker = _BackgroundValidation(SELECTED)
    try:
        worker.submit(weights, 3)
        worker._process.kill()
        with pytest.raises(_ValidationWorkerError, match=r"stopped \(killed by signal 9\) after 0"):
            worker.scores()
    finally:
        worker.close()
    # gone before the weights are handed over: the pipe refuses them, and closing the
    # worker afterwards does not raise in place of that report
    worker = _BackgroundValidation(SELECTED)
    worker._process.kill()
    worker._process.wait()
    worker.submit(weights, 3)
    worker.submit(weights, 3)
    with pytest.raises(_ValidationWorkerError, match="while validation 1 was handed over"):
        worker.scores()
    worker.close()


def test_where_the_worker_fails_the_training_process_flies_the_validations(
    selected, tmp_path, monkeypatch
):
    folder, selection, _ = selected
    monkeypatch.setattr(
        _BackgroundValidation, "command", (sys.executable, "-c", "raise SystemExit(3)")
    )
    with pytest.warns(RuntimeWarning, match=r"stopped \(exit code 3\).* flown in the training"):
        train(SELECTED, tmp_path, report=None, validate_in_background=True)
    assert json.loads((tmp_path / "selection.json").read_text()) == selection
    here = torch.load(tmp_path / "policy.pt", weights_only=True)
    there = torch.load(folder / "policy.pt", weights_only=True)
    for key, value in here.items():
        assert torch.equal(there[key], value), key


def test_a_training_that_fails_ends_its_worker(tmp_path, monkeypatch):
    workers = []
    original = _BackgroundValidation.__init__

    def keep(self, config):
        original(self, config)
        workers.append(self._process)

    def fail(line):
        raise RuntimeError("the report failed")

    monkeypatch.setattr(_BackgroundValidation, "__init__", keep)
    with pytest.raises(RuntimeError, match="the report failed"):
        train(SELECTED, tmp_path, report=fail, report_every=32, validate_in_background=True)
    assert len(workers) == 1 and workers[0].poll() is not None


@pytest.mark.parametrize(("cores", "expected"), [({0}, False), ({0, 1}, True)])
def test_by_default_validations_go_to_a_second_process_where_there_is_a_second_core(
    monkeypatch, cores, expected
):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: cores, raising=False)
    assert _validate_in_background(None) is expected
    assert _validate_in_background(False) is False


@pytest.mark.parametrize("select_every", [64, None])
def test_validate_in_background_must_be_a_bool(tmp_path, select_every):
    config = dataclasses.replace(SELECTED, select_every=select_every)
    with pytest.raises(TypeError, match="validate_in_background must be True or False, got 'yes'"):
        train(config, tmp_path, report=None, validate_in_background="yes")
    assert not any(tmp_path.iterdir())


def test_the_validation_score_is_the_mean_return_of_the_episodes_flown_one_by_one(selected):
    folder, _, _ = selected
    agent = load_agent(folder)
    returns = []
    for i in range(3):
        env = make_env(SELECTED)
        observation, _ = env.reset(seed=VALIDATION_SEED + i)
        total, done = 0.0, False
        while not done:
            observation, reward, terminated, truncated, _ = env.step(agent.act(observation))
            total += reward
            done = terminated or truncated
        env.close()
        returns.append(total)
    # the validation asks the network for all episodes in one batch, these one row at a
    # time: float32 matrix products of other shapes may round differently
    assert validation_score(agent.policy, SELECTED, 3) == pytest.approx(np.mean(returns), rel=1e-6)
    assert validation_score(agent.policy, SELECTED, 1) == pytest.approx(returns[0], rel=1e-6)
    # select_seed moves the episodes: from VALIDATION_SEED + 1 they are the last two
    moved = dataclasses.replace(SELECTED, select_seed=VALIDATION_SEED + 1)
    assert validation_score(agent.policy, moved, 2) == pytest.approx(np.mean(returns[1:]), rel=1e-6)
