"""Batched online estimation: every copy equals a single observer's filter, bit for bit.

The reference is the single-environment path: an :class:`EstimatorObserver` around the
single environment with seed ``seed + i``, fed the same actions, reset where the
batched environment autoresets its copy. Equality is exact (``array_equal``): the
batched kernel calls the member's own compiled step on views of the stacked records,
so any difference at all means a copy read another copy's state or a wrong sample.
"""

import gymnasium as gym
import numpy as np
import pytest

import manualcontrol.envs  # noqa: F401
from manualcontrol.estimators import DEKF, RDI, RML, DualUKF, JointUKF
from manualcontrol.estimators.batch import FilterBatch
from manualcontrol.estimators.observer import EstimatorObserver
from manualcontrol.estimators.vector_observer import VectorEstimatorObserver

COMPENSATORY = dict(model="precision", initial_variance="causal", initial={"K_p": 1.0})
PREVIEW = dict(
    model="preview", ce="DI", anticipation_time=1.5, initial_variance="causal",
    initial={"K_p": 0.24},
)  # fmt: skip
TASKS = {
    "compensatory": ("ManualControl/CompensatoryTracking-v0", "popovici2017"),
    "preview": ("ManualControl/PreviewTracking-v0", "DI"),
}


def env_kwargs(element, seconds):
    # each copy draws its forcing realisation from its own generator at every reset
    return dict(controlled_element=element, run_in=0.0, measurement_time=seconds, realisation=None)


def actions_for(steps, n, seed=5):
    """A stick that moves (the estimates move with it), the same for both paths."""
    rng = np.random.default_rng(seed)
    return rng.normal(0.0, 0.5, size=(steps, n, 1))


def fly_batched(env_id, element, seconds, estimator, actions, append=False):
    n = actions.shape[1]
    env = gym.make_vec(env_id, num_envs=n, **env_kwargs(element, seconds))
    observer = VectorEstimatorObserver(env, estimator, append_to_observation=append)
    observations, _ = observer.reset(seed=10)
    means, times, firsts = [], [], [observations]
    for action in actions:
        observations, _, _, _, info = observer.step(action)
        means.append(info["estimates"]["mean"])
        times.append(info["estimates"]["t"])
        firsts.append(observations)
    return observer, np.array(means), np.array(times), firsts


def fly_single(env_id, element, seconds, estimator, actions, i, append=False):
    """Copy ``i`` of the batch, flown alone; NaN rows where the batch feeds no sample."""
    inner = gym.make(env_id, **env_kwargs(element, seconds))
    observer = EstimatorObserver(
        inner, estimator.configure(), append_to_observation=append, estimates_in_info="arrays"
    )
    observation, _ = observer.reset(seed=10 + i)
    means, observations, restart = [], [observation], False
    for action in actions[:, i]:
        if restart:  # the batched env resets this copy now and ignores its action
            observation, _ = observer.reset()
            means.append(np.full(len(observer.parameter_names), np.nan))
            observations.append(observation)
            restart = False
            continue
        observation, _, terminated, truncated, info = observer.step(action)
        means.append(info["estimates"]["mean"])
        observations.append(observation)
        restart = terminated or truncated
    return np.array(means), observations


def test_every_copy_equals_its_single_observer_across_autoresets():
    # 1.5-s episodes, 400 steps: each copy ends twice and restarts its filter, on a
    # realisation its own generator draws
    env_id, element = TASKS["compensatory"]
    estimator = DEKF(**COMPENSATORY)
    actions = actions_for(400, 3)
    observer, means, times, _ = fly_batched(env_id, element, 1.5, estimator, actions)
    assert len(set(observer.env.unwrapped.realisations.tolist())) > 1
    restarts = np.isnan(times[:, 0])
    assert restarts.sum() == 2  # the two steps on which copy 0 was reset, unfed
    for i in range(3):
        single, _ = fly_single(env_id, element, 1.5, estimator, actions, i)
        fed = ~np.isnan(single[:, 0])
        np.testing.assert_array_equal(fed, ~np.isnan(times[:, i]))
        np.testing.assert_array_equal(means[fed, i], single[fed])
    # the copies flew different forcings, so their estimates differ
    assert not np.array_equal(means[-1, 0], means[-1, 1])


def test_preview_copies_read_the_target_ahead_of_their_own_realisation():
    env_id, element = TASKS["preview"]
    estimator = DEKF(**PREVIEW)
    actions = actions_for(300, 2, seed=7)
    _, means, _, _ = fly_batched(env_id, element, 3.0, estimator, actions)
    for i in range(2):
        single, _ = fly_single(env_id, element, 3.0, estimator, actions, i)
        np.testing.assert_array_equal(means[:, i], single)


@pytest.mark.parametrize(
    "estimator",
    [
        JointUKF(model="precision", initial_variance="causal", initial={"K_p": 1.0}),
        DualUKF(model="precision", initial_variance="causal", initial={"K_p": 1.0}),
        RML(model="precision", initial_variance="causal", initial={"K_p": 1.0}),
    ],
    ids=["joint-ukf", "dual-ukf", "rml"],
)
def test_each_batched_member_equals_its_single_filter(estimator):
    env_id, element = TASKS["compensatory"]
    actions = actions_for(250, 2, seed=11)
    _, means, _, _ = fly_batched(env_id, element, 2.5, estimator, actions)
    for i in range(2):
        single, _ = fly_single(env_id, element, 2.5, estimator, actions, i)
        np.testing.assert_array_equal(means[:, i], single)
    assert np.all(np.isfinite(means))


def test_appended_means_start_at_the_initial_values_and_follow_the_filters():
    env_id, element = TASKS["compensatory"]
    estimator = DEKF(**COMPENSATORY)
    actions = actions_for(200, 2, seed=3)
    observer, means, _, observations = fly_batched(
        env_id, element, 1.0, estimator, actions, append=True
    )
    shown = observer.env.single_observation_space.shape[0]  # the display: e
    width = shown + len(observer.estimated)  # then the estimated parameters
    assert observer.single_observation_space.shape == (width,)
    assert observer.observation_space.shape == (2, width)
    appended = shown + observer.estimated.index("K_p")
    np.testing.assert_array_equal(observations[0][:, appended], [1.0, 1.0])  # initial K_p
    column = observer.parameter_names.index("K_p")
    np.testing.assert_array_equal(observations[50][:, appended], means[49][:, column])
    _, single_observations = fly_single(env_id, element, 1.0, estimator, actions, 1, append=True)
    for k in (0, 50, 150):
        np.testing.assert_array_equal(observations[k][1], single_observations[k])


def test_the_last_estimate_of_a_copy_is_the_single_observers_dicts():
    env_id, element = TASKS["compensatory"]
    estimator = DEKF(**COMPENSATORY)
    actions = actions_for(60, 2, seed=2)
    env = gym.make_vec(env_id, num_envs=2, **env_kwargs(element, 5.0))
    observer = VectorEstimatorObserver(env, estimator, estimates_in_info="none")
    observer.reset(seed=10)
    assert observer.last_estimate(1) is None
    for action in actions:
        _, _, _, _, info = observer.step(action)
        assert "estimates" not in info
    inner = gym.make(env_id, **env_kwargs(element, 5.0))
    single = EstimatorObserver(inner, estimator.configure())
    single.reset(seed=11)
    for action in actions[:, 1]:
        *_, single_info = single.step(action)
    assert observer.last_estimate(1) == single_info["estimates"]
    np.testing.assert_array_equal(observer.times, [0.59, 0.59])


def test_filter_batch_restarts_only_the_copies_asked():
    estimator = DEKF(**COMPENSATORY)
    batch = FilterBatch(estimator, 3)
    batch.reset(0.01)
    rng = np.random.default_rng(0)
    for _ in range(50):
        batch.step({"e": rng.normal(size=3), "u": rng.normal(size=3)})
    before = batch.latest()[0].copy()
    batch.reset_copies([1])
    batch.step({"e": np.full(3, 0.1), "u": np.full(3, 0.2)}, active=np.array([False, True, False]))
    after = batch.latest()[0]
    np.testing.assert_array_equal(after[[0, 2]], before[[0, 2]])  # not stepped
    fresh = estimator.configure()
    fresh.reset(0.01)
    fresh.update({"e": 0.1, "u": 0.2})
    np.testing.assert_array_equal(after[1], fresh.latest()[0])


def test_filter_batch_reads_a_list_of_flags_as_a_mask_and_refuses_other_copies():
    # a list of bools was read as indices (False and True: copies 0 and 1)
    batch = FilterBatch(DEKF(**COMPENSATORY), 3)
    batch.reset(0.01)
    batch.step({"e": np.array([0.1, 0.2, 0.3]), "u": np.array([0.4, 0.5, 0.6])})
    stepped = batch.latest()[0].copy()
    batch.reset_copies([False, False, True])
    after = batch.latest()[0]
    np.testing.assert_array_equal(after[:2], stepped[:2])
    fresh = FilterBatch(DEKF(**COMPENSATORY), 3)
    fresh.reset(0.01)
    np.testing.assert_array_equal(after[2], fresh.latest()[0][2])
    assert not np.array_equal(after[2], stepped[2])
    with pytest.raises(ValueError, match=r"copies must lie in 0\.\.2, got \[3\]"):
        batch.reset_copies([3])
    with pytest.raises(ValueError, match=r"one flag per copy \(3\), got shape \(2,\)"):
        batch.reset_copies([True, False])
    with pytest.raises(ValueError, match="copies must be indices or a mask"):
        batch.reset_copies([0.5])


@pytest.mark.parametrize("native", ["1", "0"], ids=["C port", "numba"])
def test_a_strided_mask_steps_the_copies_it_flags(native, monkeypatch):
    # every other flag of a longer mask is a strided view: read as if contiguous, the
    # compiled loop stepped copy 0 alone for [True, False, True]
    monkeypatch.setenv("MANUALCONTROL_NATIVE", native)
    sample = {"e": np.array([0.1, 0.2, 0.3]), "u": np.array([0.4, 0.5, 0.6])}

    def stepped(active):
        batch = FilterBatch(DEKF(**COMPENSATORY), 3)
        batch.reset(0.01)
        batch.step(sample)  # the first step types the loop on contiguous flags
        batch.step(sample, active=active)
        return batch.latest()[0].copy()

    longer = np.array([True, False, False, True, True, False])
    strided = stepped(longer[::2])
    assert not longer[::2].flags.c_contiguous
    np.testing.assert_array_equal(strided, stepped(np.array([True, False, True])))
    idle = stepped(np.zeros(3, dtype=np.bool_))
    assert not np.array_equal(strided[2], idle[2])  # copy 2 was stepped
    np.testing.assert_array_equal(strided[1], idle[1])  # copy 1 was not


def test_bad_inputs_are_named():
    env_id, element = TASKS["compensatory"]
    vector = gym.make_vec(env_id, num_envs=2, **env_kwargs(element, 1.0))
    single = gym.make(env_id, **env_kwargs(element, 1.0))
    sync = gym.make_vec(env_id, num_envs=2, vectorization_mode="sync", **env_kwargs(element, 1.0))
    estimator = DEKF(**COMPENSATORY)
    for env in (single, sync):
        with pytest.raises(TypeError, match="batched manualcontrol tracking environment"):
            VectorEstimatorObserver(env, estimator)
    with pytest.raises(ValueError, match="has no batched step; the batched members are dekf"):
        VectorEstimatorObserver(vector, RDI())
    with pytest.raises(ValueError, match="choose-causal"):
        VectorEstimatorObserver(
            vector,
            RML(model="precision", initial_variance="causal", remnant_injection="choose-causal"),
        )
    with pytest.raises(ValueError, match="initial_variance='causal'"):
        VectorEstimatorObserver(vector, DEKF(model="precision"))
    with pytest.raises(ValueError, match="estimates_in_info must be one of"):
        VectorEstimatorObserver(vector, estimator, estimates_in_info="dicts")
    observer = VectorEstimatorObserver(vector, estimator)
    observer.reset(seed=0)
    with pytest.raises(ValueError, match="i must be <= 1, got 2"):
        observer.last_estimate(2)
    batch = FilterBatch(estimator, 2)
    with pytest.raises(RuntimeError, match="call reset"):
        batch.latest()
    batch.reset(0.01)
    with pytest.raises(ValueError, match=r"signals must hold 2 values each .* got u \(3,\)"):
        batch.step({"e": np.zeros(2), "u": np.zeros(3)})
    with pytest.raises(ValueError, match="signals lack 'u'; the batch needs 'e', 'u'"):
        batch.step({"e": np.zeros(2)})
    with pytest.raises(ValueError, match=r"signal 'e' is infinite for copies \[1\]"):
        batch.step({"e": np.array([0.0, np.inf]), "u": np.zeros(2)})
    # an input as one number was given to every copy unnoticed
    previewing = FilterBatch(DEKF(**PREVIEW), 2)
    previewing.reset(0.01)
    zeros = {key: np.zeros(2) for key in previewing.sample_keys}
    with pytest.raises(ValueError, match=r"signals must hold 2 values each .* got y \(\)"):
        previewing.step({**zeros, "y": 0.3})
