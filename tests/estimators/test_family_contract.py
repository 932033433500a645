"""The contract every registered estimator keeps, checked over the whole registry.

Each member is built by name as the bench and the CLI build it, then: it pickles and
configures as a fresh estimator with the same settings, its settings survive the
``to_dict``/``from_dict`` round trip (through JSON) and refuse an unknown key by name,
``estimate`` returns a result of the recording's length under the member's name, an
online member's ``update`` replays ``estimate`` sample by sample (bit for bit: both call
the same compiled step), refuses a sample it cannot read with a message naming the key,
marks a sample of NaN dropped, and a member that declares a smoother smooths. A new
member is checked as soon as it registers; the offline members (smoothed twins,
cross-validated and schedule fits) must refuse to run online.
"""

import functools
import json
import pickle
import warnings

import numpy as np
import pytest

from manualcontrol.estimators import ESTIMATORS, EstimationResult, make_estimator, smooth
from manualcontrol.pilots import Pilot, SchiessRolandRemnant, simulate
from manualcontrol.pilots.driving import Driver, simulate_driving

#: Members that never run online: their estimate needs the whole run.
OFFLINE_KINDS = ("-smoothed", "-cv")


def _is_offline(name):
    return name.endswith(OFFLINE_KINDS) or name == "sigmoid-fit"


def _base_name(name):
    for suffix in OFFLINE_KINDS:
        if name.endswith(suffix):
            return name[: -len(suffix)]
    return name


@functools.cache
def _compensatory(seconds):
    pilot = Pilot(
        "precision",
        {"K_p": 1.5, "K_v": 0.5, "tau_v": 0.2, "omega_nms": 8.0, "zeta_nms": 0.3},
        remnant="popovici2017",
    )
    recording = simulate(
        pilot, "popovici2017", "popovici2017", run_in=0.0, measurement_time=seconds, seed=3
    )
    return recording


@functools.cache
def _schiess_roland():
    pilot = Pilot("schiess-roland", remnant=SchiessRolandRemnant(noise_variance=25.0))
    return simulate(
        pilot,
        "schiess-roland1975",
        "schiess-roland1975",
        run_in=0.0,
        measurement_time=4.0,
        seed=0,
        measurement_noise={"u": 0.00092, "y": 0.00092},
    )


@functools.cache
def _drive():
    return simulate_driving(Driver(), measurement_time=4.0)


def recording_for(name):
    """A short recording of the kind the member reads."""
    base = _base_name(name)
    if base.startswith("zhao"):
        return _drive()
    if base == "schiess-roland":
        return _schiess_roland()
    # cross-validation needs 2 x 5 folds of 4 s after the first window
    return _compensatory(50.0 if name.endswith("-cv") else 15.0)


#: Settings that keep a member's run short here (its defaults are tested elsewhere).
QUICK_SETTINGS = {"sigmoid-fit": {"starts": 1}}


def build(name):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # generic-values warnings: tested elsewhere
        return make_estimator({"name": name, **QUICK_SETTINGS.get(name, {})})


def online_setup(estimator, recording):
    """The online member reset as ``estimate`` resets it; its sample keys and columns."""
    keys = tuple(estimator.sample_keys)
    signals = estimator.signals(recording)
    if not isinstance(signals, dict):
        signals = dict(zip(keys, signals, strict=True))
    options = {}
    settings = estimator.settings
    if hasattr(getattr(settings, "noise", None), "initial_variance"):
        first = slice(0, round(settings.noise.window / recording.dt) + 1)
        options = {
            "var_u0": float(np.nanvar(signals["u"][first])),
            "var_e0": float(np.nanvar(signals["e"][first])),
        }
    elif hasattr(estimator, "initial_states_of"):
        options = {"initial_states": estimator.initial_states_of(recording)}
    elif "speed" in recording.metadata and hasattr(settings, "speed"):
        options = {"speed": recording.metadata["speed"]}
    estimator.reset(recording.dt, t0=float(recording.t[0]), **options)
    return keys, {key: np.asarray(signals[key], dtype=np.float64) for key in keys}


NAMES = sorted(ESTIMATORS)
ONLINE = [name for name in NAMES if not _is_offline(name)]


def test_the_family_is_registered_with_its_offline_twins():
    smoothable = [name for name, entry in ESTIMATORS.items() if entry.smoothable]
    assert {"dekf", "rml", "rdi", "schiess-roland", "joint-ukf", "zhao-ukf"} <= set(smoothable)
    for name in smoothable:
        assert f"{name}-smoothed" in ESTIMATORS
        assert not ESTIMATORS[f"{name}-smoothed"].smoothable


@pytest.mark.parametrize("name", NAMES)
def test_pickles_and_configures_as_a_fresh_estimator_with_the_same_settings(name):
    estimator = build(name)
    again = pickle.loads(pickle.dumps(estimator))
    assert type(again) is type(estimator)
    assert again.settings == estimator.settings
    assert repr(again) == repr(estimator)
    if hasattr(estimator, "configure"):
        configured = estimator.configure()
        assert type(configured) is type(estimator) and configured is not estimator
        assert configured.settings == estimator.settings
        with pytest.raises(TypeError, match="no_such_setting"):
            estimator.configure(no_such_setting=1)


@pytest.mark.parametrize("name", [n for n in NAMES if n != "sigmoid-fit"])
def test_settings_round_trip_through_json_and_refuse_unknown_keys(name):
    settings = build(name).settings
    data = json.loads(json.dumps(settings.to_dict()))
    assert type(settings).from_dict(data) == settings
    assert make_estimator({"name": name, **data}).settings == settings
    with pytest.raises((TypeError, ValueError), match="no_such_setting"):
        type(settings).from_dict({**data, "no_such_setting": 1})
    with pytest.raises((TypeError, ValueError), match="no_such_setting"):
        make_estimator({"name": name, "no_such_setting": 1})


@pytest.mark.parametrize("name", NAMES)
def test_estimate_returns_the_whole_run_under_the_members_name(name):
    recording = recording_for(name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = build(name).estimate(recording)
    assert isinstance(result, EstimationResult)
    assert result.estimator in (name, _base_name(name))
    assert len(result) == len(recording)
    assert result.mean.shape == (len(recording), len(result.parameter_names))
    assert result.smoothed == _is_offline(name)
    assert np.isfinite(result.final()[result.estimated[0]])


@pytest.mark.parametrize("name", [n for n in ONLINE if n != "zhao-multi-ukf"])  # no smoother
def test_estimate_refuses_a_smooth_that_is_not_a_bool(name):
    # bool("no") is True: a string would silently smooth
    with pytest.raises(TypeError, match="smooth must be True or False, got 'no'"):
        build(name).estimate(recording_for(name), smooth="no")


@pytest.mark.parametrize("name", ONLINE)
def test_update_replays_estimate_bit_for_bit(name):
    recording = recording_for(name)
    estimator = build(name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = estimator.estimate(recording)
        keys, columns = online_setup(estimator, recording)
        estimates = [
            estimator.update({key: float(columns[key][k]) for key in keys})
            for k in range(len(recording))
        ]
    names = result.parameter_names
    np.testing.assert_array_equal([[e.mean[n] for n in names] for e in estimates], result.mean)
    np.testing.assert_array_equal([[e.std[n] for n in names] for e in estimates], result.std)
    np.testing.assert_array_equal([e.innovations for e in estimates], result.innovations)
    np.testing.assert_array_equal([e.predictions for e in estimates], result.predictions)
    np.testing.assert_array_equal(
        [e.innovation_covariance for e in estimates], result.innovation_covariance
    )
    np.testing.assert_array_equal([e.health.dropped for e in estimates], result.dropped)
    np.testing.assert_array_equal([e.health.diverged for e in estimates], result.diverged)
    assert [e.estimated for e in estimates[-1:]] == [result.estimated]
    assert estimates[-1].t == pytest.approx(recording.t[-1], abs=1e-9)


@pytest.mark.parametrize("name", ONLINE)
def test_update_refuses_what_it_cannot_read_and_drops_a_sample_of_nan(name):
    recording = recording_for(name)
    estimator = build(name)
    with pytest.raises(RuntimeError, match="has not been reset"):
        estimator.update({})
    keys, columns = online_setup(estimator, recording)
    sample = {key: float(columns[key][0]) for key in keys}
    missing = keys[-1]
    with pytest.raises((KeyError, ValueError), match=missing):
        estimator.update({key: value for key, value in sample.items() if key != missing})
    with pytest.raises(TypeError, match=keys[0]):
        estimator.update({**sample, keys[0]: "0.5"})
    with pytest.raises((TypeError, ValueError), match="no_such_signal"):
        estimator.update({**sample, "no_such_signal": 0.0})
    estimate = estimator.update(sample)
    assert estimate.health.finite and not estimate.health.dropped
    # NaN in every signal: each member drops such a sample (some correct with the
    # measurements left when only one is missing)
    dropped = estimator.update(dict.fromkeys(keys, float("nan")))
    assert dropped.health.dropped and np.isnan(dropped.innovation)
    assert all(np.isfinite(value) for value in dropped.mean.values())


@pytest.mark.parametrize("name", [n for n in NAMES if _is_offline(n)])
def test_offline_members_refuse_to_run_online(name):
    estimator = build(name)
    with pytest.raises((TypeError, NotImplementedError)):
        estimator.reset(0.01)
    with pytest.raises((TypeError, NotImplementedError)):
        estimator.update({"e": 0.0, "u": 0.0})


@pytest.mark.parametrize("name", [n for n in NAMES if ESTIMATORS[n].smoothable])
def test_a_smoothable_member_smooths_its_own_run(name):
    recording = recording_for(name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        kept = build(name).estimate(recording, smoother_inputs=True)
        smoothed = build(name).estimate(recording, smooth=True)
        twin = build(f"{name}-smoothed").estimate(recording)
    assert smoothed.smoothed and twin.smoothed and not kept.smoothed
    expected = smooth(kept)
    np.testing.assert_array_equal(smoothed.mean, expected.mean)
    np.testing.assert_array_equal(twin.mean, expected.mean)
    np.testing.assert_array_equal(smoothed.std, expected.std)
    # the smoother uses the samples after each one: the traces differ from the filter's
    assert not np.array_equal(smoothed.mean, kept.mean)


@pytest.mark.parametrize("name", ONLINE)
def test_the_plain_online_report_holds_what_update_returns(name):
    """The observer's entry point (update_plain) reports the numbers update() returns."""
    recording = recording_for(name)
    through_update, plain = build(name), build(name)
    keys, columns = online_setup(through_update, recording)
    online_setup(plain, recording)
    for k in range(0, min(len(recording), 300)):
        sample = {key: float(columns[key][k]) for key in keys}
        estimate = through_update.update(sample)
        reported = plain.update_plain(sample)
        assert reported == {
            "t": estimate.t,
            "mean": dict(estimate.mean),
            "std": dict(estimate.std),
            "innovation": estimate.innovation,
            "innovation_variance": estimate.innovation_variance,
            "prediction": estimate.prediction,
            "health": estimate.health.as_dict(),
        }
        assert type(reported["mean"]) is dict and all(
            type(value) is float for value in reported["mean"].values()
        )
