"""RML's remnant_injection="choose": the pass the describing function agrees with.

A human's remnant may enter at the perception or at the stick; the likelihood cannot
tell (a perception remnant bends the modelled delay and neuromuscular system to shape
its spectrum), the forcing frequencies can: there the remnant averages out.
"""

import re
import warnings

import numpy as np
import pytest

from manualcontrol.envs.signals import ForcingPair
from manualcontrol.estimators import RML
from manualcontrol.estimators.analysis.fit_check import second_half_values
from manualcontrol.pilots import Pilot, make_model, simulate
from manualcontrol.pilots.remnant import ZaalRemnant

TRUTH = dict(K_p=2.2, K_v=0.0, tau_v=0.3, omega_nms=10.0, zeta_nms=0.7)


@pytest.fixture(scope="module")
def stick_remnant_run():
    # a resonant remnant at the stick, two forcing periods
    pilot = Pilot("precision", TRUTH, remnant=ZaalRemnant(injection="output", P_r=0.3))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return simulate(pilot, "1/s", "vanderel-bw4", seed=2, measurement_time=240.0, run_in=30.0)


def _gap_to_truth(result, omega):
    model = make_model("precision")
    ratio = model.frequency_response(second_half_values(result), omega, "e") / (
        model.frequency_response(TRUTH, omega, "e")
    )
    return (
        np.mean(np.abs(20 * np.log10(np.abs(ratio)))) / 2
        + np.mean(np.abs(np.degrees(np.angle(ratio)))) / 10
    )


def test_the_pass_nearer_the_describing_function_is_kept(stick_remnant_run):
    run = stick_remnant_run
    chosen = RML(model="precision", element="1/s", remnant_injection="choose").estimate(run)
    record = chosen.settings["remnant_injection"]
    gains, phases = record["gain_error_db"], record["phase_error_deg"]
    scores = {p: gains[p] / 2.0 + phases[p] / 10.0 for p in ("input", "output")}
    assert record["chosen"] == min(scores, key=scores.get) == "output"
    passes = {
        p: RML(model="precision", element="1/s", remnant_injection=p).estimate(run)
        for p in ("input", "output")
    }
    np.testing.assert_array_equal(chosen.mean, passes["output"].mean)  # the pass itself
    # and it is the one nearer the true pilot
    omega = np.geomspace(0.3, 15.0, 30)
    assert _gap_to_truth(passes["output"], omega) < _gap_to_truth(passes["input"], omega)
    assert chosen.settings["settings"]["remnant"]["injection"] == "choose"


def test_choose_is_offline_and_needs_the_forcing(stick_remnant_run):
    estimator = RML(model="precision", element="1/s", remnant_injection="choose")
    with pytest.raises(ValueError, match=re.escape("offline only (estimate)")):
        estimator.reset(0.01, var_u0=1.0, var_e0=1.0)
    bare = stick_remnant_run.with_metadata(forcing=None)
    with pytest.raises(ValueError, match="remnant_injection='choose' needs the describing"):
        estimator.estimate(bare)


def test_causal_choice_follows_the_describing_function_of_the_samples_so_far(stick_remnant_run):
    run = stick_remnant_run
    estimator = RML(model="precision", element="1/s", remnant_injection="choose-causal")
    joined = estimator.estimate(run)
    passes = [
        RML(model="precision", element="1/s", remnant_injection=p).estimate(run)
        for p in ("input", "output")
    ]
    record = joined.settings["remnant_injection"]
    # the stick's resonant remnant is found from the first decision, half a period in
    assert record["chosen"] == "output"
    assert record["decisions"][0] == {"t": pytest.approx(run.t[5999]), "point": "output"}
    first = 6000 - 1  # the decision after 60 s of samples holds from that sample on
    np.testing.assert_array_equal(joined.mean[:first], passes[0].mean[:first])
    np.testing.assert_array_equal(joined.std[:first], passes[0].std[:first])
    np.testing.assert_array_equal(joined.mean[first:], passes[1].mean[first:])
    np.testing.assert_array_equal(joined.innovations[first:], passes[1].innovations[first:])
    assert record["share"]["output"] == pytest.approx(1.0 - first / len(run))
    assert joined.smoother_inputs is None
    # causal: the run cut two thirds in gives the same estimates up to the cut
    cut = 2 * len(run) // 3
    shorter = estimator.estimate(run.slice_samples(0, cut))
    np.testing.assert_array_equal(shorter.mean, joined.mean[:cut])


def test_causal_choice_refuses_what_it_cannot_do(stick_remnant_run):
    estimator = RML(model="precision", element="1/s", remnant_injection="choose-causal")
    with pytest.raises(ValueError, match="for a smoothed estimate give remnant_injection='choose'"):
        estimator.estimate(stick_remnant_run, smooth=True)
    bare = stick_remnant_run.with_metadata(forcing=None)
    with pytest.raises(ValueError, match="remnant_injection='choose-causal' measures"):
        estimator.estimate(bare)
    with pytest.raises(ValueError, match=r"remnant_injection must be one of .*'choose-causal'"):
        RML(model="precision", remnant_injection="causal")
    # the preview model's samples hold the target ahead, not the target ft the choice's
    # two-channel describing function needs: refused when set, not at the first decision
    preview = dict(model="preview", ce="SI", anticipation_time=0.9)
    with pytest.raises(ValueError, match="on the preview model hold the target ahead"):
        RML(**preview, remnant_injection="choose-causal")
    # its pursuit form reads ft itself, and the offline choice reads the whole recording
    pursuit = {**preview, "anticipation_time": 0.0, "initial": {"tau_f": 0.0}}
    assert "ft" in RML(**pursuit, remnant_injection="choose-causal").sample_keys
    RML(**preview, remnant_injection="choose")


def _stepped(estimator, recording, **reset):
    """Means of ``estimator.update`` over the recording's samples, after ``reset``."""
    estimator.reset(recording.dt, t0=float(recording.t[0]), **reset)
    keys = estimator.sample_keys
    columns = [recording[key] for key in keys]
    means = []
    for i, t in enumerate(recording.t):
        estimate = estimator.update(
            {"t": t, **{k: c[i] for k, c in zip(keys, columns, strict=True)}}
        )
        means.append([estimate.mean[name] for name in estimator.parameter_names])
    return np.array(means)


def test_causal_choice_stepped_equals_the_recordings_estimate(stick_remnant_run):
    run = stick_remnant_run.slice_samples(0, 9000)  # 90 s: decisions from 60 s on
    estimator = RML(model="precision", element="1/s", remnant_injection="choose-causal")
    whole = estimator.estimate(run)
    window = slice(0, round(estimator.settings.noise.window / run.dt) + 1)
    variances = dict(var_u0=float(np.var(run["u"][window])), var_e0=float(np.var(run["e"][window])))
    forcing = ForcingPair.from_dict(run.metadata["forcing"])
    np.testing.assert_array_equal(
        _stepped(estimator, run, forcing=forcing, **variances), whole.mean
    )
    assert whole.settings["remnant_injection"]["decisions"][0]["point"] == "output"
    with pytest.raises(ValueError, match="reset needs forcing="):
        estimator.reset(0.01)


def test_causal_choice_online_in_an_env(stick_remnant_run):
    # the observer hands the env's forcing to reset; both passes run, the one followed
    # answers: the estimates of the episode's recording, bit for bit
    import gymnasium as gym

    import manualcontrol.envs  # noqa: F401
    from manualcontrol.estimators.observer import EstimatorObserver

    settings = dict(
        model="precision",
        element="1/s",
        remnant_injection="choose-causal",
        initial_variance="causal",
        initial={"K_p": 2.0},
    )
    inner = gym.make(
        "ManualControl/CompensatoryTracking-v0",
        controlled_element="1/s",
        forcing="popovici2017",  # a 90-s period: decisions from 45 s on
        run_in=5.0,
        measurement_time=55.0,
    )
    env = EstimatorObserver(inner, RML(**settings))
    observation, _ = env.reset(seed=0)
    pilot = Pilot("precision", TRUTH, remnant=ZaalRemnant(injection="output", P_r=0.3))
    pilot.reset(seed=3, env=env)
    means, done = [], False
    while not done:
        observation, _, terminated, truncated, info = env.step(pilot.act(observation))
        means.append([info["estimates"]["mean"][name] for name in env.estimator.parameter_names])
        done = terminated or truncated
    recording = env.unwrapped.recording(include_run_in=True)
    np.testing.assert_array_equal(np.array(means), RML(**settings).estimate(recording).mean)
    assert len(env.estimator._stepped.choice.decisions) >= 1
