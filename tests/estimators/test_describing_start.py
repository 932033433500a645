"""A filter started from the run's describing function (start="describing-function").

The human-like suite's run that the RML loses from the generic start (delay 0.3 s,
omega_nms 10: it settles in another optimum, tau_v +134 %) is found from the
frequency-domain fit's delay and neuromuscular values.
"""

import re
import warnings

import pytest

from manualcontrol.bench.runner import simulate_scenario
from manualcontrol.bench.scenarios import load_suite
from manualcontrol.estimators import RML
from manualcontrol.estimators.analysis.fit_check import second_half_values


@pytest.fixture(scope="module")
def lost_run():
    suite = load_suite("human-like")
    scenario = next(
        s
        for s in suite.scenarios()
        if s.batch == "SIlag-60Hz-zaal-output-25-fd-input"
        and (s.realisation, s.remnant_seed) == (4, 207)
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return simulate_scenario(scenario)


def test_the_describing_function_start_finds_what_the_generic_start_loses(lost_run):
    truth = 0.22  # the batch's tau_v
    generic = RML(model="precision", element="1/(s(s+1))").estimate(lost_run)
    started = RML(model="precision", element="1/(s(s+1))", start="describing-function").estimate(
        lost_run
    )
    assert second_half_values(generic)["tau_v"] > 1.5 * truth
    assert second_half_values(started)["tau_v"] == pytest.approx(truth, rel=0.1)
    start = started.settings["start"]["describing_function"]
    assert set(start) == {"tau_v", "omega_nms", "zeta_nms"}
    assert started.settings["resolved"]["initial"]["tau_v"] == pytest.approx(start["tau_v"])
    # a value the user gives wins over the fit's
    given = RML(
        model="precision", element="1/(s(s+1))", start="describing-function",
        initial={"tau_v": 0.4},
    ).estimate(lost_run)  # fmt: skip
    assert given.settings["resolved"]["initial"]["tau_v"] == 0.4
    assert "tau_v" not in given.settings["start"]["describing_function"]


def test_the_describing_function_start_is_offline_and_needs_the_forcing(lost_run):
    estimator = RML(model="precision", element="1/(s(s+1))", start="describing-function")
    with pytest.raises(ValueError, match=re.escape("offline only (estimate)")):
        estimator.reset(0.01, var_u0=1.0, var_e0=1.0)
    with pytest.raises(ValueError, match="start='describing-function' needs the describing"):
        estimator.estimate(lost_run.with_metadata(forcing=None))
    with pytest.raises(ValueError, match=re.escape("start must be one of 'generic'")):
        RML(model="precision", start="fitted")
