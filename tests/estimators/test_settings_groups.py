"""Nested settings records: one group per concern, flat keys still accepted everywhere.

The RML's remnant, drift and bank knobs, the pilot filters' noise and every member's
guards are records inside the settings. Suite files, ``--set`` and keyword arguments
wrote them flat for as long as the project exists; these tests pin that both spellings
build the same settings, that a partial table keeps the member's own defaults, and that
a setting given twice or misspelt is refused by name.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pickle

import pytest

from manualcontrol.estimators import make_estimator
from manualcontrol.estimators.members.dekf import DEKFSettings
from manualcontrol.estimators.members.pilot_rules import NoiseSettings
from manualcontrol.estimators.members.rml import DriftSettings, RemnantSettings, RMLSettings
from manualcontrol.estimators.members.schiess_roland import SchiessRolandSettings
from manualcontrol.estimators.members.zhao_ukf import ZhaoUKFSettings
from manualcontrol.estimators.settings import GuardSettings


def test_flat_keys_and_tables_build_the_same_settings():
    flat = RMLSettings(drift_gain=3.0, remnant_break=2.0, remnant="levison", q2=1e-5, jitter=1e-9)
    nested = RMLSettings(
        drift=DriftSettings(gain=3.0),
        remnant=RemnantSettings(break_frequency=2.0),
        noise=NoiseSettings(preset="vertregt2020", q2=1e-5),
        guard=GuardSettings(jitter=1e-9),
    )
    tables = RMLSettings.from_dict(
        {
            "drift": {"gain": 3},
            "remnant": {"break_frequency": 2},
            "noise": {"q2": 1e-5},
            "guard": {"jitter": 1e-9},
        }
    )
    assert flat == nested == tables
    assert flat.drift.gain == 3.0 and flat.remnant.break_frequency == 2.0
    assert (
        RMLSettings.from_dict({"drift_gain": 3, "remnant_break": 2, "q2": 1e-5, "jitter": 1e-9})
        == flat
    )


def test_a_partial_table_keeps_the_members_own_defaults():
    # the RML's noise defaults (its preset, q2 = 1e-6) differ from the record type's own
    settings = RMLSettings.from_dict({"noise": {"window": 3.0}})
    assert settings.noise.window == 3.0
    assert settings.noise.q2 == 1e-6 and settings.noise.preset == "vertregt2020"
    assert NoiseSettings().q2 == 0.4
    # and a flat key changes one field of a group, keeping the rest of it
    changed = settings.replace(drift_window=1.0)
    assert changed.drift == DriftSettings(gain=15.0, window=1.0, threshold=0.3)
    assert changed.noise == settings.noise


def test_to_dict_writes_the_nested_form_and_round_trips_through_json_and_pickle():
    settings = RMLSettings(model="precision", ce="DI", drift_gain=0.0, pinned_time=math.inf)
    data = json.loads(json.dumps(settings.to_dict()))
    assert data["drift"] == {"gain": 0.0, "window": 2.5, "threshold": 0.3}
    assert data["guard"]["pinned_time"] == "inf"
    assert "drift_gain" not in data and "q2" not in data
    assert RMLSettings.from_dict(data) == settings
    assert pickle.loads(pickle.dumps(settings)) == settings


def test_replace_configure_and_dataclasses_replace_take_flat_keys():
    settings = DEKFSettings(model="precision")
    assert settings.replace(q2=0.1).noise.q2 == 0.1
    assert dataclasses.replace(settings, q2=0.1) == settings.replace(q2=0.1)
    estimator = make_estimator({"name": "dekf", "q2": 0.2, "pinned_time": 10.0})
    assert estimator.settings.noise.q2 == 0.2 and estimator.settings.guard.pinned_time == 10.0
    assert estimator.configure(window=4.0).settings.noise.window == 4.0
    assert estimator.configure(window=4.0).settings.noise.q2 == 0.2


def test_the_guards_keep_each_members_defaults():
    assert DEKFSettings().guard == GuardSettings(jitter=0.0, max_covariance=1e8, pinned_time=30.0)
    assert ZhaoUKFSettings().guard.pinned_time == math.inf
    assert SchiessRolandSettings().guard.max_covariance == 1e10


def test_a_setting_given_twice_is_refused_naming_both_spellings():
    with pytest.raises(ValueError, match=r"drift_gain and drift\.gain, one setting given twice"):
        RMLSettings.from_dict({"drift": {"gain": 4}, "drift_gain": 3})


def test_unknown_keys_are_refused_by_name_flat_or_in_a_table():
    with pytest.raises(TypeError, match=r"unknown key\(s\) 'drift_gian'.*'drift_gain'"):
        RMLSettings.from_dict({"drift_gian": 3})
    with pytest.raises(
        TypeError, match=r"RMLSettings\.from_dict drift got unknown key\(s\) 'gian'"
    ):
        RMLSettings.from_dict({"drift": {"gian": 3}})
    with pytest.raises(TypeError, match=r"unknown key\(s\) 'drift_gain'"):
        DEKFSettings(drift_gain=3.0)  # the DEKF has no drift rule


def test_a_group_that_is_neither_a_table_nor_its_record_is_refused():
    with pytest.raises(
        TypeError, match=r"drift must be a table of its settings or a DriftSettings"
    ):
        RMLSettings.from_dict({"drift": 3})
    with pytest.raises(TypeError, match=r"noise must be a NoiseSettings"):
        DEKFSettings(noise=GuardSettings())


def test_errors_inside_a_group_name_the_flat_key_the_user_typed():
    with pytest.raises(ValueError, match=r"drift_gain must be >= 0, got -1"):
        RMLSettings(drift_gain=-1)
    with pytest.raises(ValueError, match=r"remnant_injection must be one of"):
        RMLSettings(remnant_injection="stick")
    with pytest.raises(ValueError, match=r"pinned_time must be > 0 s"):
        ZhaoUKFSettings(pinned_time=0.0)
