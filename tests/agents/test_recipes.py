"""Training recipes: the configurations `manualcontrol train --recipe` gives."""

import functools
import json

import gymnasium as gym
import numpy as np
import pytest

import manualcontrol.envs  # noqa: F401
from manualcontrol.agents import training
from manualcontrol.agents.recipes import (
    human_problem,
    optimal_control_effort_weight,
    recipe,
    typical_stick_rms,
)
from manualcontrol.agents.training import VALIDATION_SEED, make_env
from manualcontrol.agents.wrappers import ObservationScale
from manualcontrol.bench.cli import main
from manualcontrol.estimators.analysis.human_likeness import reference_model, reference_pilot


@pytest.mark.parametrize("element", ["gain", "1/s", "1/s^2", "1/(s(s+1))"])
def test_the_human_problem_imposes_the_typical_pilots_own_limitations(element):
    config = human_problem(element, seed=3)
    assert config.seed == 3 and config.algorithm == "ppo"
    typical = reference_pilot(element)
    specs = {spec["kind"]: spec for spec in config.limitations}
    # the agent acts through the typical pilot's delay, its queue hidden, and limb
    assert specs["action_delay"] == {
        "kind": "action_delay",
        "delay": typical["tau_v"],
        "observe_queue": False,
    }
    assert specs["neuromuscular"]["omega_nms"] == typical["omega_nms"]
    assert specs["neuromuscular"]["zeta_nms"] == typical["zeta_nms"]
    # the OCM's -20 dB, band-limited where the limb stops passing it, innermost
    assert config.limitations[0] == {
        "kind": "observation_noise",
        "ratio": 0.01,
        "omega_r": typical["omega_nms"],
    }
    assert "effort_cost" in specs
    # the OCM's -25 dB motor noise: with the observation noise, its whole remnant source
    ratio = specs["motor_noise"]["power_ratio"]
    assert ratio == pytest.approx(10**-2.5, rel=0.02)
    # PPO explores with that noise's spread at the typical stick, not a whole stick unit
    spread = np.sqrt(ratio / (1 - ratio)) * typical_stick_rms(element)
    assert np.exp(config.policy_kwargs["log_std_init"]) == pytest.approx(spread)
    assert config.env_kwargs["forcing"] == "popovici2017"
    assert config.env_kwargs["action_bound"] == pytest.approx(4 * typical_stick_rms(element))
    # the policy reads the last 0.2 s, 20 frames (e, e_dot and the limb's stick and its
    # rate), newest first, at a learning rate below PPO's default 3e-4 (the frames move
    # Adam's steps together)
    assert config.algorithm_kwargs["learning_rate"] < 3e-4
    # the kept weights are the best validated ones, chosen on episodes apart from those
    # from VALIDATION_SEED up, where the results page measures every agent's return
    assert config.select_every is not None and config.select_every < config.total_timesteps
    chosen_on = range(config.select_seed, config.select_seed + config.select_episodes)
    assert not set(chosen_on) & set(range(VALIDATION_SEED, VALIDATION_SEED + 100))
    env = make_env(config)
    observation, _ = env.reset(seed=0)
    assert env.observation_space.contains(observation)
    # on a pure gain the policy also reads its own last command, outside the frames
    assert config.efference_copy == (element == "gain")
    assert env.actor_inputs == 20 * 4 + config.efference_copy
    frames = [observation[:4].copy()]
    for _ in range(25):
        observation, *_ = env.step(np.full(1, 0.1))
        frames.insert(0, observation[:4].copy())
    np.testing.assert_array_equal(observation[:80].reshape(20, 4), frames[:20])
    env.close()


@pytest.mark.parametrize("element", ["gain", "1/s", "1/s^2", "1/(s(s+1))"])
def test_the_typical_stick_is_the_simulated_typical_pilots(element):
    from manualcontrol.agents.evaluation import fly
    from manualcontrol.pilots import Pilot

    env = gym.make(
        "ManualControl/CompensatoryTracking-v0",
        controlled_element=element,
        forcing="popovici2017",
        run_in=30.0,
    )
    values = reference_pilot(element)
    recording = fly(Pilot(reference_model(values), values), env, 0)
    # one whole 90-s period after a 30-s run-in: the steady state at the lines, which the
    # Parseval sum computes without simulating; the simulation's zero-order hold (half a
    # sample of extra lag, felt most by the least damped loop, the double integrator's:
    # 2.2 %) and the run-in's leftovers stay under 3 %
    simulated = float(np.sqrt(np.mean(np.asarray(recording.u) ** 2)))
    assert typical_stick_rms(element) == pytest.approx(simulated, rel=0.03)


def test_the_optimal_control_models_optimum_on_the_recipes_forcing_is_human():
    # an agent becomes what its problem's optimum is: on the recipe's forcing the OCM's
    # crossover, phase margin and effective delay are inside the human ranges
    from manualcontrol.estimators.analysis.human_likeness import HUMAN_RANGES
    from manualcontrol.pilots import solve_ocm

    for element, kind in (("1/s", "integrator"), ("1/s^2", "double_integrator")):
        tau_v = reference_pilot(element)["tau_v"]  # the recipe's delay
        crossover, margin, delay = solve_ocm(element, "popovici2017", tau_v=tau_v).crossover()
        ranges = HUMAN_RANGES[kind]
        for name, value in (
            ("crossover_frequency", crossover),
            ("phase_margin", margin),
            ("effective_delay", delay),
        ):
            assert ranges[name].low <= value <= ranges[name].high, (element, name, value)
    # where the wide-band forcing's is not: too much phase margin on 1/s
    _, margin, _ = solve_ocm("1/s", "vanderel-bw4", tau_v=0.26).crossover()
    assert margin > HUMAN_RANGES["integrator"]["phase_margin"].high


def test_a_recipe_takes_a_seed_and_a_length_and_rejects_unknown_names():
    assert recipe("si", total_timesteps=1000).total_timesteps == 1000
    assert recipe("si", seed=4) == human_problem("1/s", seed=4, warm_start="typical-pilot")
    with pytest.raises(ValueError, match="recipe must be one of"):
        recipe("hover")


def test_observation_scale_divides_each_value_and_checks_its_length():
    env = gym.make("ManualControl/PursuitTracking-v0", measurement_time=1.0)
    scaled = ObservationScale(env, [2.0, 4.0])
    observation, _ = scaled.reset(seed=0)
    raw, _ = env.reset(seed=0)
    np.testing.assert_array_equal(observation, raw / np.array([2.0, 4.0]))
    np.testing.assert_array_equal(
        scaled.observation_space.high, env.observation_space.high / [2, 4]
    )
    with pytest.raises(ValueError, match=r"scale must be one number or 2 \(one per observed"):
        ObservationScale(env, [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="scale must be finite and > 0"):
        ObservationScale(env, 0.0)


def test_the_train_command_refuses_flags_a_recipe_sets(tmp_path, capsys):
    code = main(["train", "--recipe", "si", "--delay", "0.1", "--out", str(tmp_path / "a")])
    err = capsys.readouterr().err
    assert code == 2 and "--recipe si sets the training itself; drop --delay" in err
    code = main(["train", "--recipe", "hover", "--out", str(tmp_path / "a")])
    assert (
        code == 2
        and "--recipe must be one of gain, si, di, lag, lane-angle, lane-torque, got 'hover'"
        in capsys.readouterr().err
    )
    assert not (tmp_path / "a").exists()


def test_the_train_command_trains_a_recipe(tmp_path, monkeypatch):
    # the warm start's fit on two episodes and a hundred steps: the command's wiring is
    # what is tested here (the fit itself in test_warm_start.py), and the recipe's twenty
    # episodes and 3,000 steps were half of this test's time
    clone = training.clone_typical_pilot
    monkeypatch.setattr(
        training, "clone_typical_pilot", functools.partial(clone, episodes=2, iterations=100)
    )
    out = tmp_path / "agent"
    code = main(
        ["train", "--recipe", "si", "--steps", "64", "--seed", "2", "--out", str(out), "--quiet"]
    )
    assert code == 0
    config = json.loads((out / "config.json").read_text())
    assert config["seed"] == 2 and config["total_timesteps"] == 64
    assert config["env_kwargs"]["controlled_element"] == "1/s"
    assert config["warm_start"] == "typical-pilot"
    bound = config["env_kwargs"]["action_bound"]
    weight = optimal_control_effort_weight("1/s", "popovici2017", bound)
    assert config["effort_rate_weight"] == pytest.approx(weight, rel=1e-12)


def test_the_optimal_control_effort_weight_poses_the_ocms_trade_off_in_reward_units():
    from manualcontrol.envs.signals import forcing_preset
    from manualcontrol.pilots import solve_ocm

    weight = optimal_control_effort_weight("1/s", "vanderel-bw4", 5.0)
    target = forcing_preset("vanderel-bw4", 0).target
    g = solve_ocm("1/s", "vanderel-bw4", tau_v=0.2, tau_nms=0.1).g
    assert weight == pytest.approx(g * 25.0 / target.variance, rel=1e-12)
    # the OCM's pilot with that g has the 0.1-s lag it was asked for
    assert solve_ocm("1/s", "vanderel-bw4", g=g).tau_nms == pytest.approx(0.1, rel=1e-6)
    # a double integrator needs more stick rate for the same error: a smaller weight
    assert optimal_control_effort_weight("1/s^2", "vanderel-bw4", 5.0) < weight / 3


@pytest.mark.parametrize("steering", ["angle", "torque"])
def test_the_lane_keeping_recipe_scales_to_the_driver_and_hides_its_delay(steering):
    from manualcontrol.agents.recipes import (
        LANE_KEEPING_DELAY,
        LANE_KEEPING_STEPS,
        driver_statistics,
    )

    config = recipe(f"lane-{steering}", seed=1)
    assert config.task == "lane-keeping" and config.seed == 1
    # the steering's own training length unless one is asked for
    assert config.total_timesteps == LANE_KEEPING_STEPS[steering]
    assert recipe(f"lane-{steering}", total_timesteps=5_000).total_timesteps == 5_000
    assert config.env_kwargs["steering"] == steering and config.env_kwargs["road"] == "random"
    scale, action_rms = driver_statistics(steering)
    assert config.env_kwargs["action_bound"] == pytest.approx(4 * action_rms)
    assert config.policy_kwargs["log_std_init"] == pytest.approx(np.log(action_rms))
    assert config.wrappers[0] == {
        "kind": "action_delay",
        "delay": LANE_KEEPING_DELAY,
        "observe_queue": False,
    }
    assert config.wrappers[1] == {"kind": "observation_scale", "scale": scale}
    # the kept weights are the best validated ones, not the last update's
    assert config.select_every is not None and config.select_every < config.total_timesteps
    assert config.select_episodes > 1
    # on another road the driver's observations, so scaled, are of order one: the policy
    # sees numbers a network learns from
    env = gym.make(
        "ManualControl/LaneKeeping-v0", road="random", steering=steering, measurement_time=60.0
    )
    from manualcontrol.pilots.driver import Driver

    observation, _ = env.reset(seed=7)
    driver = Driver()
    driver.reset(7, env=env)
    seen, done = [], False
    while not done:
        observation, _, terminated, truncated, _ = env.step(driver.act(observation))
        seen.append(observation / np.asarray(scale))
        done = terminated or truncated
    env.close()
    rms = np.sqrt(np.mean(np.square(seen), axis=0))
    assert np.all((rms > 0.25) & (rms < 4.0)), rms


def test_driver_statistics_are_the_drivers_own_rms():
    from manualcontrol.agents.evaluation import fly
    from manualcontrol.agents.recipes import driver_statistics
    from manualcontrol.pilots.driver import Driver

    scale, action_rms = driver_statistics("angle")
    env = gym.make(
        "ManualControl/LaneKeeping-v0", road="random", steering="angle", measurement_time=120.0
    )
    recording = fly(Driver(), env, 0)
    # the recording holds the applied steering angle and the observed angles
    assert action_rms == pytest.approx(np.sqrt(np.mean(recording["delta_d"] ** 2)), rel=0.02)
    assert scale[0] == pytest.approx(np.sqrt(np.mean(recording["theta_far"] ** 2)), rel=0.02)
    assert scale[1] == pytest.approx(np.sqrt(np.mean(recording["theta_near"] ** 2)), rel=0.02)


def test_the_typical_pilots_own_loop_is_human_through_the_human_problem():
    """The problem's noise poses the OCM's remnant, not more: the typical pilot's loop,
    flown through the double integrator's problem, is human in every figure (remnant from
    the loop alone). Counting the remnant twice (motor noise of half the stick's power on
    top of the observation noise) gave this same loop 67 % remnant and 2.6 times its RMS
    error."""
    from manualcontrol.agents.evaluation import evaluate
    from manualcontrol.agents.training import TypicalPilotAgent

    config = human_problem("1/s^2", warm_start="typical-pilot")
    human = evaluate(TypicalPilotAgent(config), seed=0).human
    assert human.verdict.outside == (), human.figures()
    assert 0.1 <= human.figures()["remnant_fraction"] <= 0.4


def test_the_train_command_gives_the_policy_its_efference_copy(tmp_path):
    out = tmp_path / "agent"
    flags = ["--algorithm", "ppo", "--efference-copy", "--steps", "64", "--quiet"]
    assert main(["train", *flags, "--algorithm-option", "n_steps=64", "--out", str(out)]) == 0
    config = json.loads((out / "config.json").read_text())
    assert config["efference_copy"] is True
    assert config["history_length"] == 1


def test_an_operator_on_a_pure_gain_is_identified_with_the_precision_models_lag(tmp_path):
    """The typical pilot's lag law, flown noise-free through the gain's problem, is the
    typical pilot itself (its delay and limb the wrappers', its lag held per sample):
    the output-error fit of the lag's structure finds its values back."""
    from manualcontrol.agents.evaluation import evaluate
    from manualcontrol.agents.training import TypicalPilotAgent

    config = human_problem("gain", warm_start="typical-pilot")
    evaluation = evaluate(TypicalPilotAgent(config), seed=0, deterministic=True)
    fit = evaluation.identified
    typical = reference_pilot("gain")
    assert "T_I" in fit.parameters and "K_v" not in fit.fitted
    # the law's zero-order hold and the fit's own discretisation: a few per cent
    for name in ("K_p", "T_I", "tau_v", "omega_nms"):
        assert fit.parameters[name] == pytest.approx(typical[name], rel=0.05), name
    assert fit.vaf > 99.0
    summary = evaluation.summary()
    assert not [flag for flag in summary["implausible"] if flag.startswith("fit ")]
    # the DEKF's model cannot lag: it is not run, and the report says why
    assert summary["dekf"] == {}
    from manualcontrol.agents.evaluation import write_report

    text = write_report(evaluation, tmp_path / "report").read_text()
    assert "DEKF: not run. Its precision model has no lag" in text
    # the human-likeness reference is the same lagging pilot: its RMS error alike
    assert evaluation.human.rms_ratio == pytest.approx(1.0, abs=0.05)
