"""The checks every time-domain identification of a trial gets (estimators.fit_check)."""

import warnings

import numpy as np
import pytest

from manualcontrol.envs.elements import Integrator
from manualcontrol.estimators import DEKF, JointUKF
from manualcontrol.estimators.analysis.fit_check import check_fit, settled_index
from manualcontrol.estimators.analysis.frequency import describing_function
from manualcontrol.pilots import Pilot, simulate

HUMAN_SI = dict(K_p=2.4, K_v=0.0, tau_v=0.25, omega_nms=12.0, zeta_nms=0.5)


@pytest.fixture(scope="module")
def run():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the Levison remnant at this gain: a human-like run
        return simulate(
            Pilot("precision", HUMAN_SI, remnant="vertregt2020-SI"),
            Integrator(1.0),
            "vanderel-bw4",
            seed=1,
        )


def _held(initial):
    # only K_p estimated; the rest held where given: a model right or wrong by construction
    return DEKF(model="precision", ce="SI", initial=initial, estimated=("K_p",))


def test_a_model_far_from_the_measured_pilot_is_flagged(run):
    describing = describing_function(run)
    right = _held(HUMAN_SI).estimate(run)
    wrong = _held({**HUMAN_SI, "tau_v": 0.5, "omega_nms": 6.0}).estimate(run)
    good = check_fit(run, right, describing=describing)
    bad = check_fit(run, wrong, describing=describing)
    assert not any("misses the measured describing function" in w for w in good.warnings)
    assert any("misses the measured describing function" in w for w in bad.warnings)
    assert bad.frequency["phase_error_deg"] > good.frequency["phase_error_deg"] + 10.0
    # the describing function's own fit is the floor both are compared with
    assert good.frequency["best_phase_error_deg"] == bad.frequency["best_phase_error_deg"]
    assert bad.frequency["values"]["tau_v"] == 0.5


def test_start_up_is_left_out_of_the_one_step_vaf(run):
    start = {"K_p": 0.5, "tau_v": 0.5, "omega_nms": 14.0, "zeta_nms": 0.2}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = JointUKF(model="precision", ce="SI", initial=start).estimate(run)
    check = check_fit(run, result)
    index = settled_index(result.innovation_variance)
    assert check.scored_from == pytest.approx(result.t[index])
    assert 0.0 < check.scored_from < 20.0
    assert 50.0 < check.one_step_vaf <= 100.0


def test_settled_index_reads_the_innovation_variance():
    variance = np.r_[np.full(10, 1e6), np.linspace(10.0, 1.0, 10), np.ones(100)]
    assert settled_index(variance) == 18  # the first within a factor 2 of the median 1
    assert settled_index(np.full(5, np.nan)) == 0


def test_a_control_that_never_moves_is_flagged(run):
    still = run.with_signals(u=np.full(len(run), 0.2))
    result = _held(HUMAN_SI).estimate(still)
    check = check_fit(still, result)
    assert any("the control u never moves (constant 0.2)" in w for w in check.warnings)
    barely = run.with_signals(y=run.y * 1e-4, e=run.ft - run.y * 1e-4)
    message = " ".join(check_fit(barely, result).warnings)
    assert "the output y barely moves" in message


def test_no_describing_function_leaves_the_note(run):
    result = _held(HUMAN_SI).estimate(run)
    check = check_fit(run, result, frequency_note="not checked: no forcing known")
    assert check.frequency is None
    assert check.to_dict()["frequency_note"] == "not checked: no forcing known"


def test_coloured_innovations_are_warned_only_where_nothing_vouches(run):
    describing = describing_function(run)
    vouched = check_fit(run, _held(HUMAN_SI).estimate(run), describing=describing)
    alone = check_fit(run, _held(HUMAN_SI).estimate(run))
    assert vouched.innovation_outside > 0.2 and alone.innovation_outside > 0.2
    assert not any("not white" in w for w in vouched.warnings)  # the true pilot's model
    assert any("no describing function to check them by" in w for w in alone.warnings)
