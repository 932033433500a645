"""The gains humans use depend on the element: checked against it, not one table."""

import re
import warnings

import numpy as np
import pytest

from manualcontrol.envs.elements import Integrator
from manualcontrol.pilots import HumanLimitWarning, Pilot, simulate
from manualcontrol.pilots.models import element_gain_ranges

HUMAN_ON_GAIN_1 = dict(K_p=3.0, K_v=0.0, tau_v=0.25, omega_nms=12.0, zeta_nms=0.5)


def test_gain_ranges_are_the_crossover_range_through_the_element():
    ranges = element_gain_ranges(Integrator(2.0))
    np.testing.assert_allclose(ranges["K_p"], (0.25, 4.0))  # K_p |H_c(j w)| = 1: w / 2
    np.testing.assert_allclose(ranges["K_v"], (0.0, 0.5))
    ranges = element_gain_ranges("5/s^2")
    np.testing.assert_allclose(ranges["K_p"], (0.05, 12.8))


def test_a_humans_gain_on_a_plant_of_gain_1_is_not_flagged():
    with warnings.catch_warnings():
        warnings.simplefilter("error", HumanLimitWarning)
        pilot = Pilot("precision", HUMAN_ON_GAIN_1)  # Table I's 2.5 would have flagged it
        simulate(pilot, "1/s", measurement_time=10.0, run_in=0.0)


def test_a_gain_no_human_uses_on_the_element_is_flagged():
    pilot = Pilot("precision", {**HUMAN_ON_GAIN_1, "K_p": 0.2})
    message = "pilot parameter K_p = 0.2 is outside the gains humans use on the element"
    with pytest.warns(HumanLimitWarning, match=re.escape(message)) as caught:
        simulate(pilot, "1/s", measurement_time=10.0, run_in=0.0)
    assert "[0.5, 8], a crossover between 0.5 and 8 rad/s" in str(caught[0].message)


def test_an_element_that_does_not_integrate_gives_no_crossover_range():
    # a proportional pilot on a pure gain has no crossover to place: humans use a lag
    assert element_gain_ranges("gain") == {}
    assert element_gain_ranges("1/(s+2)") == {}
    with warnings.catch_warnings():
        warnings.simplefilter("error", HumanLimitWarning)
        simulate(Pilot.typical("precision", "gain"), "gain", measurement_time=10.0, run_in=0.0)
