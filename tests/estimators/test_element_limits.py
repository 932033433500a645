"""Limits from the experiment's controlled element and human ranges (the "human" limits).

Thesis Table I was set for its pilots on 1.5/s and 5/s^2; on a plant of gain 1 a human's
K_p lies above its 2.5 and a filter held by it reports the limit. Given the element, the
gains may put the crossover anywhere in 0.5-8 rad/s.
"""

import math
import re
import warnings

import numpy as np
import pytest

from manualcontrol.envs.elements import Integrator, IntegratorWithLag
from manualcontrol.envs.schedules import Sigmoid
from manualcontrol.estimators import DEKF
from manualcontrol.estimators.analysis.fit_check import time_at_limits
from manualcontrol.estimators.members.pilot_filter import (
    CROSSOVER_RANGE,
    HUMAN_RANGES,
    PilotFilterSettings,
    element_type,
    human_limits,
)
from manualcontrol.pilots import Pilot, simulate


@pytest.mark.parametrize(
    ("element", "k_p", "k_v"),
    [
        ("1/s", (0.5, 8.0), (0.0, 1.0)),  # |H_c| = 1/w: K_p = w, K_v = 1
        ("SI", (0.5 / 1.5, 8.0 / 1.5), (0.0, 1.0 / 1.5)),
        ("5/s^2", (0.25 / 5.0, 64.0 / 5.0), (0.0, 8.0 / 5.0)),  # K_p = w^2/5, K_v = w/5
    ],
)
def test_gain_limits_let_the_loop_cross_over_where_humans_do(element, k_p, k_v):
    limits = human_limits(element, "precision")
    np.testing.assert_allclose(limits["K_p"], k_p, rtol=1e-9)
    np.testing.assert_allclose(limits["K_v"], k_v, rtol=1e-9)
    for name, pair in HUMAN_RANGES.items():
        assert limits[name] == pair


def test_gain_limits_of_a_general_element_cover_the_crossover_range():
    limits = human_limits("1/(s(s+1))", "precision")
    omega = np.array(CROSSOVER_RANGE)
    proportional = omega * np.sqrt(omega**2 + 1.0)  # 1/|H_c| at the range's ends
    np.testing.assert_allclose(limits["K_p"], proportional, rtol=1e-9)


def test_the_element_sets_the_type_rules_and_the_limits():
    settings = PilotFilterSettings(model="precision", element="1/s")
    assert settings.ce is None and settings.ce_type == "SI"
    assert settings.limits_choice == "human"
    assert element_type("2/s^2") == "DI" and element_type("1/(s(s+1))") is None
    assert PilotFilterSettings(model="precision", ce="SI").limits_choice == "table-I"
    # the round trip keeps the element and its type
    again = PilotFilterSettings.from_dict(settings.to_dict())
    assert again.element == "1/s" and again.ce_type == "SI"
    # another element gives another type: nothing of the first sticks
    dekf = DEKF(model="precision", element="1/s", initial={"K_p": 3.0})
    assert dekf.configure(element="1/s^2").settings.ce_type == "DI"


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        (
            {"ce": "DI", "element": "1/s"},
            "ce='DI' (a thesis element type, Table I limits) and element='1/s'",
        ),
        ({"limits": "human"}, "limits='human' derives the gain limits from the controlled element"),
        ({"element": "1/(s"}, "element '1/(s' cannot be read"),
        ({"limits": "thesis"}, "limits must be one of 'table-I', 'human', 'none', got 'thesis'"),
    ],
)
def test_bad_element_settings_are_named(changes, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        PilotFilterSettings(model="precision", **changes)


def test_a_time_varying_element_is_refused():
    element = IntegratorWithLag(4.0, Sigmoid(3.0, 1.0, 45.0, 10.0))
    with pytest.raises(ValueError, match="element must be constant"):
        PilotFilterSettings(model="precision", element=element)


@pytest.fixture(scope="module")
def human_run():
    # K_p 3 on 1/s: a human's gain on a plant of gain 1, above Table I's 2.5
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pilot = Pilot("precision", dict(K_p=3.0, K_v=0.0, tau_v=0.25, omega_nms=12.0, zeta_nms=0.5))
        return simulate(pilot, Integrator(1.0), "vanderel-bw4")


def test_table_i_pins_a_human_gain_and_the_element_frees_it(human_run):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        thesis = DEKF(model="precision", ce="SI").estimate(human_run)
        plant = DEKF(model="precision", element="1/s").estimate(human_run)
    pinned = time_at_limits(thesis)
    assert pinned["K_p"]["limit"] == 2.5 and pinned["K_p"]["side"] == "upper"
    assert pinned["K_p"]["share"] > 0.5
    assert "K_p" not in time_at_limits(plant)
    half = len(plant) // 2
    assert np.median(plant.mean_of("K_p")[half:]) == pytest.approx(3.0, rel=0.1)
    assert math.isclose(plant.settings["resolved"]["limits"]["K_p"][1], 8.0)
