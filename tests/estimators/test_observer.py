"""EstimatorObserver: online estimates inside an environment equal the offline run."""

import re
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import manualcontrol.envs  # noqa: F401
from manualcontrol.agents.wrappers import ActionDelay
from manualcontrol.estimators import DEKF
from manualcontrol.estimators.observer import EstimatorObserver
from manualcontrol.pilots import Pilot

DI_PREVIEW = dict(K_f=0.9, omega_f=1.0, K_p=0.24, K_v=0.36, omega_nms=8.0, zeta_nms=0.45, tau_v=0.3)
CASES = {
    "compensatory": (
        "Compensatory",
        "popovici2017",
        Pilot("precision", remnant="popovici2017"),
        dict(model="precision", initial_variance="causal", initial={"K_p": 1.0}),
    ),
    "preview": (
        "Preview",
        "DI",
        Pilot("preview", DI_PREVIEW),
        dict(
            model="preview",
            ce="DI",
            anticipation_time=1.5,
            initial_variance="causal",
            initial={"K_p": 0.24},
        ),
    ),
}


def fly(case, append=False):
    task, element, pilot, settings = CASES[case]
    inner = gym.make(
        f"ManualControl/{task}Tracking-v0",
        controlled_element=element,
        run_in=5.0,
        measurement_time=25.0,
    )
    env = EstimatorObserver(inner, DEKF(**settings), append_to_observation=append)
    observation, _ = env.reset(seed=0)
    pilot.reset(seed=3, env=env)
    width = inner.observation_space.shape[0]
    means, done = [], False
    while not done:
        observation, _, terminated, truncated, info = env.step(pilot.act(observation[:width]))
        means.append(info["estimates"]["mean"])
        done = terminated or truncated
    return env, means, observation, info


@pytest.mark.parametrize("case", ["compensatory", "preview"])
def test_online_estimates_equal_the_offline_estimate_of_the_episode(case):
    env, means, _, _ = fly(case)
    recording = env.unwrapped.recording(include_run_in=True)
    offline = DEKF(**CASES[case][3]).estimate(recording)
    for name in offline.parameter_names:
        online = np.array([mean[name] for mean in means])
        np.testing.assert_array_equal(online, offline.mean_of(name), err_msg=name)


def test_a_causal_rml_online_equals_its_estimate_of_the_episode():
    # estimate() hands a causal start no first-window variances, as the observer's reset
    # has none: the RML's start reads them, so the two would differ from the first sample
    from manualcontrol.estimators import RML

    settings = dict(model="precision", initial_variance="causal", initial={"K_p": 1.0})
    inner = gym.make(
        "ManualControl/CompensatoryTracking-v0",
        controlled_element="popovici2017",
        run_in=2.0,
        measurement_time=20.0,
    )
    env = EstimatorObserver(inner, RML(**settings))
    observation, _ = env.reset(seed=0)
    pilot = Pilot("precision", remnant="popovici2017")
    pilot.reset(seed=3, env=env)
    means, done = [], False
    while not done:
        observation, _, terminated, truncated, info = env.step(pilot.act(observation))
        means.append(info["estimates"]["mean"])
        done = terminated or truncated
    offline = RML(**settings).estimate(env.unwrapped.recording(include_run_in=True))
    for name in offline.parameter_names:
        online = np.array([mean[name] for mean in means])
        np.testing.assert_array_equal(online, offline.mean_of(name), err_msg=name)


def test_appended_estimates_and_info():
    env, _, observation, info = fly("compensatory", append=True)
    estimated = ("K_p", "K_v", "tau_v", "omega_nms", "zeta_nms")
    assert env.observation_space.shape == (1 + len(estimated),)
    np.testing.assert_array_equal(
        observation[1:], [info["estimates"]["mean"][n] for n in estimated]
    )
    estimates = info["estimates"]
    assert set(estimates) == {
        "t",
        "mean",
        "std",
        "innovation",
        "innovation_variance",
        "prediction",
        "health",
    }
    assert estimates["health"]["finite"] and not estimates["health"]["diverged"]
    assert all(estimates["std"][name] > 0 for name in estimated)


def test_the_estimates_in_info_are_plain_values_of_their_own_step():
    import copy
    import json
    import pickle

    env, means, _, info = fly("compensatory")
    estimates = info["estimates"]
    assert type(estimates["mean"]) is dict and type(estimates["std"]) is dict
    assert type(estimates["health"]) is dict and estimates["health"]["pinned"] == []
    # a vector env in subprocesses pickles info; logs write it as JSON
    assert pickle.loads(pickle.dumps(info)) == info == copy.deepcopy(info)
    assert json.loads(json.dumps(estimates)) == estimates
    # each step's values are its own: a later step does not change an earlier one
    assert len({means[k]["K_p"] for k in (10, 500, -1)}) == 3
    assert (
        means[10]["K_p"]
        == env.estimator.estimate(env.unwrapped.recording(include_run_in=True)).mean_of("K_p")[10]
    )


@pytest.mark.parametrize("case", ["compensatory", "preview"])
def test_the_filters_plain_path_reports_what_their_estimates_hold(case):
    """The family's filters fill info from their output row, not via an Estimate:
    the same dicts, every step, as the general path through update()."""
    task, element, pilot, settings = CASES[case]
    streams = []
    for plain in (True, False):
        dekf = DEKF(**settings)
        if not plain:
            dekf.update_plain = None  # what an estimator outside the family offers
        env = EstimatorObserver(
            gym.make(
                f"ManualControl/{task}Tracking-v0",
                controlled_element=element,
                run_in=0.0,
                measurement_time=8.0,
            ),
            dekf,
        )
        assert (env._update_plain is not None) is plain
        observation, _ = env.reset(seed=1)
        pilot.reset(seed=2, env=env)
        width = env.env.observation_space.shape[0]
        stream, done = [], False
        while not done:
            observation, _, terminated, truncated, info = env.step(pilot.act(observation[:width]))
            stream.append(info["estimates"])
            done = terminated or truncated
        streams.append(stream)
    assert len(streams[0]) == 800
    assert streams[0] == streams[1]
    assert all(type(e["mean"]) is dict and type(e["health"]["pinned"]) is list for e in streams[0])


def test_a_health_as_plain_values_is_its_own_copy():
    from manualcontrol.estimators.protocol import EstimateHealth

    health = EstimateHealth(
        finite=True, covariance_ok=False, pinned=("K_p",), dropped=True, diverged=False
    )
    plain = health.as_dict()
    assert plain == {
        "finite": True,
        "covariance_ok": False,
        "pinned": ["K_p"],
        "dropped": True,
        "diverged": False,
    }
    plain["pinned"].append("K_v")  # a user's edit of one step's info stays there
    assert health.as_dict()["pinned"] == ["K_p"] and health.pinned == ("K_p",)


def test_an_estimate_pickles_with_its_values():
    import pickle

    dekf = DEKF(**CASES["compensatory"][3])
    dekf.reset(0.01)
    estimate = dekf.update({"e": 0.1, "u": 0.2})
    again = pickle.loads(pickle.dumps(estimate))
    assert again == estimate and dict(again.mean) == estimate.mean.as_dict()


def test_observer_passes_check_env_around_an_agent_wrapper():
    inner = ActionDelay(
        gym.make("ManualControl/CompensatoryTracking-v0", measurement_time=5.0), 0.1
    )
    env = EstimatorObserver(inner, DEKF(**CASES["compensatory"][3]), append_to_observation=True)
    with warnings.catch_warnings():
        warnings.filterwarnings(
            "ignore", message=".*(normalized space|infinity|unwrapped version).*"
        )
        check_env(env, skip_render_check=True)


def test_observer_needs_a_causal_estimator():
    env = gym.make("ManualControl/CompensatoryTracking-v0")
    with pytest.raises(ValueError, match=re.escape("configure it with initial_variance='causal'")):
        EstimatorObserver(env, DEKF(model="precision"))
    with pytest.raises(TypeError, match="must be a manualcontrol tracking environment"):
        EstimatorObserver(gym.make("CartPole-v1"), DEKF(**CASES["compensatory"][3]))
    # restarts pass the whole recording again: nothing an online observer can do
    with pytest.raises(ValueError, match=re.escape("configure it with restarts=0, got restarts=1")):
        EstimatorObserver(env, DEKF(**CASES["compensatory"][3], restarts=1))


@pytest.mark.parametrize("estimator", ["dekf", "rml-choosing"])
def test_the_thin_forms_report_the_same_estimates(estimator):
    # "arrays" and "none" leave the estimate in the filter's row (no per-step dicts):
    # the same numbers as the dicts, bit for bit, the appended observation included
    from manualcontrol.estimators import RML

    task, element, pilot, settings = CASES["compensatory"]

    def make():
        if estimator == "dekf":
            return DEKF(**settings)
        return RML(**settings, remnant_injection="choose-causal")

    runs = {}
    for form in ("dicts", "arrays", "none"):
        env = EstimatorObserver(
            gym.make(
                f"ManualControl/{task}Tracking-v0",
                controlled_element=element,
                forcing="popovici2017",  # a 90-s period: the choice decides from 45 s on
                run_in=0.0,
                measurement_time=50.0,
            ),
            make(),
            append_to_observation=True,
            estimates_in_info=form,
        )
        observation, _ = env.reset(seed=1)
        pilot.reset(seed=2, env=env)
        width = env.env.observation_space.shape[0]
        observations, reports, done = [], [], False
        while not done:
            observation, _, terminated, truncated, info = env.step(pilot.act(observation[:width]))
            observations.append(observation)
            reports.append(info.get("estimates"))
            done = terminated or truncated
        runs[form] = (np.array(observations), reports, env.last_estimate())
    dicts, arrays, none = runs["dicts"], runs["arrays"], runs["none"]
    np.testing.assert_array_equal(arrays[0], dicts[0])
    np.testing.assert_array_equal(none[0], dicts[0])
    names = tuple(dicts[1][0]["mean"])
    for plain, array in zip(dicts[1], arrays[1], strict=True):
        assert array["t"] == plain["t"]
        np.testing.assert_array_equal(array["mean"], [plain["mean"][n] for n in names])
        np.testing.assert_array_equal(array["std"], [plain["std"][n] for n in names])
    assert all(report is None for report in none[1])
    assert none[2] == dicts[2] == dicts[1][-1]


@pytest.mark.parametrize("case", ["compensatory", "preview", "rml-input"])
def test_the_none_form_steps_kept_samples_when_read_and_equals_the_dicts(case):
    """Read mid-block, at the block's edge, after it, at the episode's end, in two episodes.

    The "none" form keeps the samples and steps the filter through them when an
    estimate is read: every read equals the "dicts" report of that step, bit for bit.
    """
    from manualcontrol.estimators import RML
    from manualcontrol.estimators.observer import BLOCK_SAMPLES

    task, element, pilot, settings = CASES["preview" if case == "preview" else "compensatory"]

    def make():
        if case == "rml-input":
            return RML(**settings, remnant_injection="input")
        return DEKF(**settings)

    reads = {3, BLOCK_SAMPLES - 1, BLOCK_SAMPLES, BLOCK_SAMPLES + 1, 600}
    runs = {}
    for form in ("dicts", "none"):
        env = EstimatorObserver(
            gym.make(
                f"ManualControl/{task}Tracking-v0",
                controlled_element=element,
                run_in=1.0,
                measurement_time=6.0,
            ),
            make(),
            estimates_in_info=form,
        )
        if form == "none":
            assert env._keeps  # the kept-samples path, not a step per sample
        width = env.observation_space.shape[0]
        seen = []
        for episode in range(2):
            observation, _ = env.reset(seed=episode)
            pilot.reset(seed=3 + episode, env=env)
            done, k = False, 0
            while not done:
                observation, _, terminated, truncated, _ = env.step(pilot.act(observation[:width]))
                k += 1
                done = terminated or truncated
                if k in reads or done:
                    seen.append(env.last_estimate())
            # the estimator itself is up to date when handed out
            seen.append(env.estimator.latest()[0].copy())
        runs[form] = seen
    assert len(runs["none"]) == len(runs["dicts"]) == 2 * (len(reads) + 2)
    for kept, stepped in zip(runs["none"], runs["dicts"], strict=True):
        if isinstance(kept, dict):
            assert kept == stepped
        else:
            np.testing.assert_array_equal(kept, stepped)


def test_a_block_of_samples_with_a_dropped_one_equals_the_samples_one_by_one():
    settings = CASES["compensatory"][3]
    rng = np.random.default_rng(4)
    values = rng.normal(size=(40, 2))  # columns e, u
    values[17, 1] = np.nan  # a dropped stick sample
    by_block, by_sample = DEKF(**settings), DEKF(**settings)
    assert by_block.sample_keys == ("e", "u")
    for estimator in (by_block, by_sample):
        estimator.reset(0.01)
    assert by_block.update_block(values[:25]) == pytest.approx(0.24)
    assert by_block.update_block(values[25:], t=7.0) == 7.0
    for e, u in values:
        by_sample.update_quiet({"e": float(e), "u": float(u)})
    np.testing.assert_array_equal(by_block.latest()[0], by_sample.latest()[0])
    np.testing.assert_array_equal(by_block.latest()[1], by_sample.latest()[1])
    assert by_block.latest_plain(7.0)["health"] == by_sample.latest_plain(7.0)["health"]


def test_a_block_of_samples_is_refused_with_the_reason():
    from manualcontrol.estimators import RML

    settings = CASES["compensatory"][3]
    estimator = DEKF(**settings)
    with pytest.raises(RuntimeError, match="has not been reset"):
        estimator.update_block(np.zeros((3, 2)))
    estimator.reset(0.01)
    with pytest.raises(ValueError, match=re.escape("values must be (k, 2): one column per")):
        estimator.update_block(np.zeros((3, 3)))
    bad = np.zeros((3, 2))
    bad[1, 1] = np.inf
    with pytest.raises(ValueError, match="sample 1 of the block has u infinite"):
        estimator.update_block(bad)
    choosing = RML(**settings, remnant_injection="choose-causal")
    with pytest.raises(ValueError, match="remnant_injection='choose-causal' decides"):
        choosing.update_block(np.zeros((3, 2)))


class _InfiniteDisplay(gym.Wrapper):
    """Shows an infinite error at time ``at`` (a broken display or wrapper)."""

    def __init__(self, env, at):
        super().__init__(env)
        self.at = at

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        if info["t"] == self.at:
            info = {**info, "e": float("inf")}
        return observation, reward, terminated, truncated, info


@pytest.mark.parametrize("at", [0.5, 2.99], ids=["mid-run", "the last sample"])
@pytest.mark.parametrize("form", ["dicts", "arrays", "none"])
def test_a_sample_the_filter_refuses_is_left_out_in_every_form_and_the_rest_go_on(form, at):
    # the "none" form dropped its whole kept block (up to 256 samples) and stamped the
    # estimate before it with the latest time; the dicts form raised again at every
    # later step, its pending sample never replaced
    def flown(form):
        inner = gym.make(
            "ManualControl/CompensatoryTracking-v0",
            controlled_element="DI",
            run_in=0.0,
            measurement_time=3.0,
        )
        settings = dict(model="precision", ce="DI", initial_variance="causal")
        env = EstimatorObserver(
            _InfiniteDisplay(inner, at),
            DEKF(**settings, initial={"K_p": 0.24}),
            estimates_in_info=form,
        )
        env.reset(seed=0)
        refusals = []
        for k in range(300):
            try:
                env.step([0.1 * np.sin(0.05 * k)])
            except ValueError as error:
                refusals.append(str(error))
        return env, refusals

    env, refusals = flown(form)
    assert len(refusals) == 1 and "inf" in refusals[0]
    if form == "none":  # refused when its block is stepped, saying which sample
        assert refusals[0].startswith(f"the sample at t = {at:g} s has e infinite")
    assert env.estimator._k == 299  # every other sample went in
    last = env.last_estimate()
    assert last["t"] == pytest.approx(2.98 if at == 2.99 else 2.99)  # the last one taken
    reference, _ = flown("dicts")
    assert last == reference.last_estimate()


def test_an_unknown_estimates_form_is_refused():
    with pytest.raises(ValueError, match="estimates_in_info must be one of 'dicts', 'arrays'"):
        EstimatorObserver(
            gym.make("ManualControl/CompensatoryTracking-v0"),
            DEKF(**CASES["compensatory"][3]),
            estimates_in_info="lists",
        )
