"""The issue's accuracy targets on simulated pilots (scenarios.py), one realisation each.

Two configurations are checked wherever the papers' settings fall short:

* FAITHFUL: the defaults, Popovici et al. (2017) as printed: generic initial values
  (eqs. 27-31), eqs. 32-33 for P_0, eqs. 25-26 for Q, r^2 = 0.7, q^2 = 0.4, eq. 49 as
  printed; Table I limits (the union of the SI and DI columns for Popovici's CE).
* improved options beside it, each a documented setting:
  - REMNANT_FREE: eq. 49 with dt on df/dtheta (``total_derivative="dimensional"``,
    thesis Part II eq. 5.5) and the thesis's initial variances P_0 = (p theta_0)^2
    (Sec. V-B-1), Popovici's Q;
  - REMNANT: the thesis preset (P_0 = (p theta_0)^2, Q 5 %/2.5 %) with a slower
    parameter filter, its own measurement variance ``r2_parameter = 100`` (a separate
    R for the parameter filter, thesis App. I / Sec. VII-B-1): the parameters then
    average over the remnant instead of following it.

Why the default total derivative is eq. 49 as printed: with 30 % remnant the
dimensional form loses the parameters (they run to their limits and the one-step
VAF falls below 70 % in the time-varying case), the printed form does not; without
remnant the dimensional form is the more accurate one
(test_eq_49_forms_with_and_without_remnant).

Constant parameters with remnant are scored on their mean over the converged part
(t >= 30 s): the estimate of a random-walk filter fluctuates with the remnant, and its
last sample is one draw of that fluctuation. benchmarks/bench_dekf.py prints every
figure of these runs (final values too) and the sweep over realisations.
"""

import sys
from pathlib import Path

import numpy as np
import pytest

from manualcontrol.estimators import DEKF, evaluate, nrmse

sys.path.insert(0, str(Path(__file__).parent))
from scenarios import (
    ANTICIPATION,
    PREVIEW_START,
    compensatory,
    compensatory_tv,
    preview,
    preview_initial,
)

THESIS_P0 = {"K_p": 0.5, "K_v": 0.5, "tau_v": 0.5, "omega_nms": 0.1, "zeta_nms": 0.5}
FAITHFUL: dict = {}
REMNANT_FREE = {"total_derivative": "dimensional", "P0_fraction": THESIS_P0}
REMNANT = {"preset": "vertregt2020", "r2_parameter": 100.0}
START = 15.0  # Popovici Sec. IV-A: VAF ignoring the first 15 s


def run(recording, **settings):
    result = DEKF(model="precision", **settings).estimate(recording)
    return result, evaluate(result, recording, start=START)


def final_errors(result, recording):
    return {
        name: result.final()[name] / recording.parameters[name][-1] - 1.0
        for name in result.parameter_names
    }


def converged_errors(result, recording, start=30.0):
    mask = recording.t >= start
    return {
        name: float(np.mean(result.mean_of(name)[mask])) / recording.parameters[name][-1] - 1.0
        for name in result.parameter_names
    }


@pytest.mark.parametrize("settings", [FAITHFUL, REMNANT_FREE], ids=["faithful", "improved"])
def test_constant_compensatory_remnant_free(settings):
    recording = compensatory(remnant=False)
    result, metrics = run(recording, **settings)
    assert metrics.one_step_vaf >= 99.5  # paper: 99.87 %
    errors = final_errors(result, recording)
    assert abs(errors["K_p"]) <= 0.05 and abs(errors["K_v"]) <= 0.05
    for name in ("omega_nms", "zeta_nms", "tau_v"):
        assert abs(errors[name]) <= 0.15, (name, errors[name])
    assert not result.health.diverged


def test_constant_compensatory_with_remnant():
    recording = compensatory(remnant=True)
    assert recording.metadata["remnant_power_ratio"] == pytest.approx(0.30)
    # the faithful filter keeps going but is biased: the quick version's ~90 % VAF,
    # K_v and zeta_nms off by about half or more
    result, metrics = run(recording, **FAITHFUL)
    assert 80.0 < metrics.one_step_vaf < 90.0
    assert not result.health.stopped
    errors = converged_errors(result, recording)
    assert errors["zeta_nms"] > 0.5 and errors["tau_v"] < -0.3
    # the improved option meets the target
    result, metrics = run(recording, **REMNANT)
    assert metrics.one_step_vaf >= 90.0
    errors = converged_errors(result, recording)
    assert abs(errors["K_p"]) <= 0.15 and abs(errors["K_v"]) <= 0.15, errors


def test_time_varying_compensatory_remnant_free():
    recording = compensatory_tv(remnant=False)
    # faithful: no sign flip (Table I limits), the gains within target, the
    # neuromuscular parameters not
    result, metrics = run(recording, **FAITHFUL)
    assert np.all(result.mean_of("K_p") > 0.0) and np.all(result.mean_of("K_v") > 0.0)
    assert metrics.nrmse["K_p"] <= 0.15 and metrics.nrmse["K_v"] <= 0.15
    assert metrics.nrmse["zeta_nms"] > 0.25
    # improved: every parameter within target
    result, metrics = run(recording, **REMNANT_FREE)
    assert metrics.nrmse["K_p"] <= 0.15 and metrics.nrmse["K_v"] <= 0.15, metrics.nrmse
    for name in ("tau_v", "omega_nms", "zeta_nms"):
        assert metrics.nrmse[name] <= 0.25, (name, metrics.nrmse[name])
    assert metrics.one_step_vaf >= 99.0


def test_time_varying_compensatory_with_remnant_runs_without_sign_flips():
    recording = compensatory_tv(remnant=True)
    for settings in (FAITHFUL, REMNANT):
        result, metrics = run(recording, **settings)
        assert not result.health.stopped
        assert np.all(result.mean_of("K_p") > 0.0) and np.all(result.mean_of("K_v") > 0.0)
        assert metrics.one_step_vaf >= 90.0
    assert metrics.nrmse["K_v"] <= 0.15  # the improved option (last in the loop)


def test_eq_49_forms_with_and_without_remnant():
    """Printed eq. 49 survives remnant; the dimensional form is better without it."""
    clean = compensatory_tv(remnant=False)
    noisy = compensatory_tv(remnant=True)
    _, printed_clean = run(clean, total_derivative="printed")
    _, dimensional_clean = run(clean, total_derivative="dimensional")
    assert dimensional_clean.one_step_vaf > printed_clean.one_step_vaf > 99.0
    assert dimensional_clean.nrmse["zeta_nms"] < printed_clean.nrmse["zeta_nms"]
    printed, printed_noisy = run(noisy, total_derivative="printed")
    dimensional, dimensional_noisy = run(noisy, total_derivative="dimensional")
    assert printed_noisy.one_step_vaf > 90.0
    assert dimensional_noisy.one_step_vaf < 70.0
    assert dimensional.health.pinned_fraction["omega_nms"] > 0.3  # run to a limit
    assert printed.health.pinned_fraction["omega_nms"] < 0.1


@pytest.mark.parametrize("ce", ["SI", "DI"])
def test_preview_time_varying_preview_time(ce):
    """Thesis Table II feasibility case: all parameters estimated, remnant-free."""
    recording = preview(ce)
    settings = {
        "model": "preview",
        "ce": ce,
        "anticipation_time": ANTICIPATION[ce],
        "initial": preview_initial(ce),
        "preset": "vertregt2020",
    }
    result = DEKF(**settings, total_derivative="dimensional").estimate(recording)
    mask = recording.t >= PREVIEW_START
    error = nrmse(result.mean_of("tau_f")[mask], recording.parameters["tau_f"][mask])
    assert error < 0.25  # thesis Table II: 0.252 (SI), 0.109 (DI)
    expected = {"SI": ("K_f", "tau_f", "K_p", "tau_v", "omega_nms", "zeta_nms")}
    assert result.estimated == expected.get(ce, result.parameter_names)
    tau_f = result.mean_of("tau_f")
    assert np.all(tau_f >= 0.1 - 1e-12) and np.all(tau_f <= ANTICIPATION[ce] - 0.1 + 1e-12)
    printed = DEKF(**settings).estimate(recording)
    error = nrmse(printed.mean_of("tau_f")[mask], recording.parameters["tau_f"][mask])
    if ce == "DI":
        assert error < 0.25
    else:
        assert error > 0.25  # the printed form trades tau_f* against tau_v here
