"""What the envs accept and refuse, and the conventions users rely on."""

import os
import re
import stat

import gymnasium as gym
import numpy as np
import pytest

import manualcontrol.envs  # noqa: F401  (registers the ids)
from manualcontrol.envs._files import atomic_path, atomic_write
from manualcontrol.envs.tracking import CompensatoryTracking

ID = "ManualControl/CompensatoryTracking-v0"


@pytest.fixture
def env():
    environment = CompensatoryTracking("SI", measurement_time=1.0)
    environment.reset(seed=0)
    return environment


@pytest.mark.parametrize(
    ("action", "error", "found"),
    [
        (np.zeros(3), ValueError, "got shape (3,)"),
        (np.zeros((1, 1)), ValueError, "got shape (1, 1)"),
        (0.5, ValueError, "got shape ()"),
        (np.array([1 + 2j]), TypeError, "got dtype complex128"),
        (np.array([True]), TypeError, "got dtype bool"),
        (True, TypeError, "got True"),
        ("0.5", TypeError, "got '0.5'"),
        (None, TypeError, "got None"),
        ({"u": 1.0}, TypeError, "got dtype object"),
    ],
)
def test_wrong_actions_name_action_and_the_expected_shape_and_dtype(env, action, error, found):
    expected = "action must be a real array of shape (1,) (float64)"
    with pytest.raises(error, match=re.escape(expected) + ".*" + re.escape(found)):
        env.step(action)


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_actions_raise(env, value):
    with pytest.raises(ValueError, match="action must be finite"):
        env.step(np.array([value]))


@pytest.mark.parametrize("action", [[0.5], np.array([0.5], dtype=np.float32), np.array([1])])
def test_real_actions_of_the_right_shape_are_accepted(env, action):
    env.step(action)
    assert env.recording().u[-1] == pytest.approx(float(np.asarray(action)[0]))


def test_vector_env_checks_actions_too():
    vector = gym.make_vec(ID, num_envs=2, measurement_time=1.0)
    vector.reset(seed=0)
    with pytest.raises(ValueError, match=re.escape("actions must be a real array of shape (2, 1)")):
        vector.step(np.zeros((3, 1)))
    with pytest.raises(TypeError, match="got dtype complex128"):
        vector.step(np.zeros((2, 1), dtype=complex))
    vector.step(np.zeros(2))  # one stick per copy, flat, is fine


@pytest.mark.parametrize("options", ["realisation", 3, ["realisation", 1]])
def test_reset_options_must_be_a_dict(env, options):
    with pytest.raises(TypeError, match=re.escape("options must be a dict such as")):
        env.reset(options=options)


def test_switches_refuse_strings():
    with pytest.raises(
        TypeError, match=re.escape("include_rates must be True or False, got 'False'")
    ):
        CompensatoryTracking("SI", include_rates="False")
    with pytest.raises(TypeError, match="include_previous_action must be True or False, got 1"):
        CompensatoryTracking("SI", include_previous_action=1)


def test_measurement_time_must_hold_a_sample():
    with pytest.raises(
        ValueError,
        match=re.escape(
            "measurement_time must hold at least one sample (dt = 0.01 s), got 0.004 s"
        ),
    ):
        CompensatoryTracking("SI", measurement_time=0.004)


def test_render_fps_is_the_sample_rate():
    assert CompensatoryTracking("SI").metadata["render_fps"] == pytest.approx(100.0)
    assert CompensatoryTracking("SI", dt=0.02).metadata["render_fps"] == pytest.approx(50.0)


def test_spec_reports_the_episode_length():
    env = gym.make(ID, measurement_time=2.0, run_in=1.0)
    assert env.spec.max_episode_steps == 300
    assert gym.make(ID, max_episode_steps=10).spec.max_episode_steps == 10


def test_make_vec_native_honours_max_episode_steps():
    vector = gym.make_vec(ID, num_envs=2, max_episode_steps=10)
    vector.reset(seed=0)
    for step in range(10):
        _, _, _, truncated, _ = vector.step(np.zeros((2, 1)))
        assert truncated.all() == (step == 9)
    sync = gym.make_vec(ID, num_envs=2, max_episode_steps=10, vectorization_mode="sync")
    sync.reset(seed=0)
    for _ in range(10):
        _, _, _, truncated_sync, _ = sync.step(np.zeros((2, 1)))
    assert truncated_sync.all()


def test_written_files_respect_the_umask(tmp_path):
    old = os.umask(0o022)
    try:
        path = atomic_write(tmp_path / "a.txt", lambda p: p.write_text("x"))
        assert stat.S_IMODE(path.stat().st_mode) == 0o644
        os.umask(0o077)
        path = atomic_write(tmp_path / "b.txt", lambda p: p.write_text("x"))
        assert stat.S_IMODE(path.stat().st_mode) == 0o600
    finally:
        os.umask(old)


def test_atomic_write_names_the_path_asked_not_the_temporary_file(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(
        NotADirectoryError, match=re.escape(f"cannot write {blocker}/x.png: {blocker} is a file")
    ):
        with atomic_path(blocker / "x.png"):
            pass
    with pytest.raises(OSError, match=re.escape("cannot write /proc/x.png")) as raised:
        with atomic_path("/proc/x.png"):
            pass
    assert ".part" not in str(raised.value)
