"""The RDI refuses a recording too short for its decimation instead of returning its start.

A run identifies first at a multiple of ``decimation`` once the ``n_a`` past outputs and
the oldest delayed input read (``n_b`` decimated samples and the initial delay back, with
its interpolation stencil) lie in the record; a shorter run used to return the starting
values, healthy (``diverged=False``), as the "final values".
"""

import itertools
import re

import numpy as np
import pytest

from manualcontrol.envs.recording import Recording
from manualcontrol.estimators.members import _rdi_core as core
from manualcontrol.estimators.members.rdi import RDI

DT = 1 / 60


def recording(samples, dt=DT):
    t = np.arange(samples) * dt
    r = np.sin(2.0 * t) + 0.5 * np.sin(5.3 * t) + 0.1
    u = 1.5 * (np.sin(2.0 * (t - 0.25)) + 0.5 * np.sin(5.3 * (t - 0.25))) + 0.1
    return Recording({"t": t, "e": r, "u": u}, dt=dt)


def test_a_huge_decimation_on_a_short_recording_names_decimation_the_length_and_the_limit():
    message = (
        "decimation = 10000 leaves the filter no identification step in a recording of "
        "1200 samples (dt = 0.0166667 s): ARMAX(1, 1) from the initial delay d = 0.2 s "
        "first identifies at sample index 20000, so it needs at least 20001 samples; the "
        "largest decimation this recording allows is 599 (or give a longer recording)"
    )
    with pytest.raises(ValueError, match=re.escape(message) + "$"):
        RDI(decimation=10000).estimate(recording(1200))


def test_the_largest_decimation_named_runs_and_identifies():
    result = RDI(decimation=599).estimate(recording(1200))
    assert result.settings["resolved"]["identification_steps"] == 1
    with pytest.raises(ValueError, match=re.escape("decimation = 600 leaves the filter")):
        RDI(decimation=600).estimate(recording(1200))


def test_the_gain_and_delay_model_needs_fewer_samples():
    with pytest.raises(
        ValueError,
        match=re.escape(
            "ARMAX(0, 0) from the initial delay d = 0.2 s first identifies at sample index "
            "10000, so it needs at least 10001 samples; the largest decimation this "
            "recording allows is 1199"
        ),
    ):
        RDI(n_a=0, n_b=0, decimation=10000).estimate(recording(1200))


def test_a_recording_too_short_for_any_decimation_says_so():
    with pytest.raises(
        ValueError,
        match=re.escape(
            "decimation = 3 leaves the filter no identification step in a recording of 10 "
            "samples (dt = 0.0166667 s): ARMAX(1, 1) from the initial delay d = 0.2 s first "
            "identifies at sample index 18, so it needs at least 19 samples; no decimation "
            "fits this recording: even decimation = 1 needs 15 samples; give a longer "
            "recording (or a smaller initial d)"
        ),
    ):
        RDI(decimation=3).estimate(recording(10))


def test_two_samples_are_still_the_first_floor():
    with pytest.raises(
        ValueError, match=re.escape("the recording must have at least 2 samples, got 1")
    ):
        RDI().estimate(recording(1))


@pytest.mark.parametrize(
    ("n_a", "n_b", "decimation", "d"),
    list(itertools.product([0, 1, 2], [0, 1, 2], [1, 2, 4, 7], [0.0, 0.05, 0.2, 0.33])),
)
def test_first_identification_is_the_compiled_steps_first(n_a, n_b, decimation, d):
    """The minimum agrees with the kernel: one sample fewer never identifies."""
    rdi = RDI(n_a=n_a, n_b=n_b, decimation=decimation, initial={"d": d}, sign_constraints=False)
    first = rdi.first_identification(DT)
    assert first % decimation == 0
    for samples, identifies in ((first + 1, True), (first, False)):
        rdi.reset(DT)
        out = rdi._new_output(samples, store=False)
        data = recording(samples)
        core.rdi_run(*rdi._records, data["e"].copy(), data["u"].copy(), out)
        steps = int(rdi._records[1].sc[core.SC_STEPS])
        assert (steps >= 1) == identifies
    if first + 1 >= 2:
        result = rdi.estimate(recording(first + 1))
        assert result.settings["resolved"]["identification_steps"] == 1
    if first >= 2:
        with pytest.raises(ValueError, match=f"decimation = {decimation} leaves the filter"):
            rdi.estimate(recording(first))


def test_online_updates_are_not_refused_and_hold_the_start_until_the_first_step():
    rdi = RDI(decimation=10)
    first = rdi.first_identification(DT)
    rdi.reset(DT)
    data = recording(first + 1)
    start = rdi.settings.initial_values
    for k in range(first):
        estimate = rdi.update({"e": float(data["e"][k]), "u": float(data["u"][k])})
        assert estimate.mean["d"] == start["d"] and estimate.mean["b_0"] == start["b_0"]
    estimate = rdi.update({"e": float(data["e"][first]), "u": float(data["u"][first])})
    assert estimate.mean["b_0"] != start["b_0"]


@pytest.mark.parametrize(("dt", "decimation"), [(0.0, 1), (DT, 0)])
def test_first_identification_checks_its_arguments(dt, decimation):
    with pytest.raises(ValueError, match="must be"):
        RDI().first_identification(dt, decimation)
