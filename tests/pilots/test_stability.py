"""Typical pilots per element, and diverging loops detected, not simulated to 1e36."""

import math
import re
import warnings

import numpy as np
import pytest
from scipy.optimize import brentq

from manualcontrol.envs.schedules import Sigmoid
from manualcontrol.pilots import Pilot, simulate
from manualcontrol.pilots.models import PrecisionModel
from manualcontrol.pilots.simulation import SimulationSetup
from manualcontrol.pilots.stability import (
    UnstableLoopError,
    UnstableLoopWarning,
    check_stable,
    typical_parameters,
)


def critical_gain_si(tau, omega, zeta, k_element=1.5):
    """K_p at which a proportional pilot with NMS and exact delay on K/s reaches -180 deg.

    Independent of the code under test: the open loop's frequency response written out
    with the exact exp(-j w tau), the phase crossover found by root bracketing.
    """

    def loop(w):
        s = 1j * w
        return (
            np.exp(-s * tau) * omega**2 / (s**2 + 2 * zeta * omega * s + omega**2) * k_element / s
        )

    # unwrapped phase: -w tau - atan2(2 zeta omega w, omega^2 - w^2) - pi/2 = -pi
    w180 = brentq(
        lambda w: w * tau + np.arctan2(2 * zeta * omega * w, omega**2 - w**2) - np.pi / 2,
        0.1,
        30.0,
    )
    return 1.0 / abs(loop(w180))


def test_pole_check_agrees_with_the_exact_delay_gain_margin():
    tau, omega, zeta = 0.26, 10.5, 0.35
    critical = critical_gain_si(tau, omega, zeta)
    parameters = {"K_v": 0.0, "tau_v": tau, "omega_nms": omega, "zeta_nms": zeta}
    # Padé-6 against the exact delay: the stability boundary within 2 %
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        below = SimulationSetup.create(Pilot("precision", {**parameters, "K_p": 0.98 * critical}))
        above = SimulationSetup.create(Pilot("precision", {**parameters, "K_p": 1.02 * critical}))
    assert check_stable(below) is True
    with pytest.raises(UnstableLoopError, match="close an unstable loop: closed-loop pole at"):
        check_stable(above)


@pytest.mark.parametrize("element", ["SI", "DI", "popovici2017", "gain", "schiess-roland1975"])
@pytest.mark.parametrize("model", ["precision", "preview"])
def test_typical_pilots_are_stable_and_track(model, element):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        recording = simulate(Pilot.typical(model, element), element, measurement_time=30.0)
    # bounded: the error stays of the order of the forcing (no divergence, no drift)
    assert np.std(recording.e) < 2.0 * (np.std(recording.ft) + np.std(recording.fd))


def test_typical_values_follow_the_thesis_and_scale_with_the_element_gain():
    assert typical_parameters("precision", "DI") == pytest.approx(
        {"K_p": 0.24, "K_v": 0.36, "tau_v": 0.3, "omega_nms": 8.0, "zeta_nms": 0.45}
    )
    assert typical_parameters("precision", {"kind": "double_integrator", "K": 10.0})[
        "K_p"
    ] == pytest.approx(0.12)
    assert typical_parameters("preview", "SI")["K_p"] == pytest.approx(1.3)


def test_the_issue_case_raises_instead_of_reaching_1e36():
    with pytest.raises(
        UnstableLoopError,
        match=re.escape(
            "the precision pilot (K_p=1.5, K_v=0.5, tau_v=0.2, omega_nms=8, zeta_nms=0.3)"
        )
        + ".*double_integrator \\(K=5\\).*Pilot.typical",
    ):
        simulate(Pilot("precision"), "DI", measurement_time=10.0)


def test_warn_keeps_the_run_and_flags_it():
    with pytest.warns(UnstableLoopWarning, match="unstable loop"):
        recording = simulate(Pilot("precision"), "DI", measurement_time=10.0, on_unstable="warn")
    assert "unstable loop" in recording.metadata["diverging"]
    assert np.abs(recording.y).max() > 1e3


def test_a_varying_pilot_that_diverges_is_caught_by_the_growth_check():
    from manualcontrol.envs.schedules import Sigmoid

    # stable at first (thesis DI pilot), the lead drops away mid-run: unstable on 5/s^2
    pilot = Pilot.typical("precision", "DI", {"K_v": Sigmoid(0.36, 0.0, 20.0, 5.0)})
    with pytest.raises(UnstableLoopError, match=r"the closed loop diverges: .* at t = "):
        simulate(pilot, "DI", measurement_time=90.0)
    with pytest.warns(UnstableLoopWarning):
        recording = simulate(pilot, "DI", measurement_time=90.0, on_unstable="warn")
    assert "diverges" in recording.metadata["diverging"]


def test_stable_runs_carry_no_flag():
    recording = simulate(Pilot.typical("precision", "SI"), "SI", measurement_time=10.0)
    assert "diverging" not in recording.metadata


@pytest.mark.parametrize(
    ("seed", "error", "message"),
    [
        (-1, ValueError, "seed must be >= 0, got -1"),
        (1.5, TypeError, "seed must be an int, a numpy Generator or None, got 1.5"),
        ("1", TypeError, "seed must be an int"),
    ],
)
def test_bad_seeds_are_named(seed, error, message):
    with pytest.raises(error, match=re.escape(message)):
        simulate(Pilot.typical("precision", "SI"), "SI", seed=seed, measurement_time=1.0)


def test_measurement_time_below_a_sample_is_refused():
    with pytest.raises(
        ValueError, match=re.escape("measurement_time must hold at least one sample")
    ):
        simulate(Pilot.typical("precision", "SI"), "SI", measurement_time=0.001)


@pytest.mark.parametrize("K, omega_b", [(4.0, 3.0), (1.0, 1.0), (2.0, 10.0)])
def test_a_lagged_integrator_gets_lead_cancelling_its_lag_and_crosses_over_at_2(K, omega_b):
    """McRuer & Jex on ``K/(s(s + omega_b))``: ``T_L = 1/omega_b``, ``K_p K/omega_b = 2``.

    On Popovici's 4/(s(s+3)) that is their pilot, K_p 1.5 and K_v 0.5; elsewhere the lead
    follows the lag (a fixed K_v/K_p would leave 1/(s(s+1)) a third of the lead); the
    loop closes stable and bounded.
    """
    element = {"kind": "integrator_with_lag", "K": K, "omega_b": omega_b}
    for model in ("precision", "preview"):
        values = typical_parameters(model, element)
        assert values["K_v"] / values["K_p"] == pytest.approx(1.0 / omega_b)
        assert values["K_p"] * K / omega_b == pytest.approx(2.0)
        assert (values["tau_v"], values["omega_nms"], values["zeta_nms"]) == (0.2, 8.0, 0.3)
    if (K, omega_b) == (4.0, 3.0):
        assert typical_parameters("precision", "popovici2017") == {
            "K_p": 1.5, "K_v": 0.5, "tau_v": 0.2, "omega_nms": 8.0, "zeta_nms": 0.3,
        }  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the gains humans use on this K: tested elsewhere
        pilot = Pilot.typical("precision", element)
    assert check_stable(SimulationSetup.create(pilot, element)) is True
    recording = simulate(pilot, element, measurement_time=30.0)
    assert np.std(recording.e) < 2.0 * (np.std(recording.ft) + np.std(recording.fd))


def test_the_lag_models_typical_pilot_is_mcruers_lag_on_a_gain_and_refused_elsewhere():
    """On ``K``: break a decade below a 3-rad/s asymptotic crossover, ``K_p K/T_I = 3``.

    The loop it closes is stable and bounded; on ``K/s`` and the others no lag is typical
    (humans adopt none there), so the lag model has no typical pilot and says which does.
    """
    lag = PrecisionModel(lag=True)
    on_two = typical_parameters(lag, {"kind": "gain", "K": 2.0})
    assert on_two["T_I"] == pytest.approx(10.0 / 3.0)
    assert on_two["K_p"] * 2.0 / on_two["T_I"] == pytest.approx(3.0)
    assert on_two["K_v"] == 0.0
    si = typical_parameters("precision", "SI")
    assert {name: on_two[name] for name in ("tau_v", "omega_nms", "zeta_nms")} == {
        name: si[name] for name in ("tau_v", "omega_nms", "zeta_nms")
    }
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # inside every human range
        pilot = Pilot.typical(lag, "gain")
    assert check_stable(SimulationSetup.create(pilot, "gain")) is True
    recording = simulate(pilot, "gain", measurement_time=30.0)
    assert np.std(recording.e) < 2.0 * (np.std(recording.ft) + np.std(recording.fd))
    # a gain that doubles over the run: the pilot at each time halves its K_p
    doubling = {"kind": "gain", "K": Sigmoid(1.0, 2.0, 50.0, 1.0).to_dict()}
    assert typical_parameters(lag, doubling)["K_p"] == pytest.approx(10.0)
    assert typical_parameters(lag, doubling, t=100.0)["K_p"] == pytest.approx(5.0)
    assert typical_parameters("precision", {**doubling, "kind": "integrator"}, t=100.0)[
        "K_p"
    ] == pytest.approx(1.3 * 1.5 / 2.0)
    for element in ("SI", "DI", "popovici2017"):
        with pytest.raises(ValueError, match=re.escape(f"element={element!r} humans adopt none")):
            typical_parameters(lag, element)
    # the model's nominal values are its typical pilot on a unit gain: one rule
    assert typical_parameters(lag, "gain") == pytest.approx(
        {name: lag.spec(name).nominal for name in ("K_p", "T_I")}
        | {"K_v": 0.0, "tau_v": 0.26, "omega_nms": 10.5, "zeta_nms": 0.35}
    )


@pytest.mark.parametrize(
    "t, error, message",
    [(math.nan, ValueError, "t must be finite, got nan"), ("1", TypeError, "t must be a real")],
)
def test_a_time_that_is_no_finite_number_is_refused_naming_t(t, error, message):
    with pytest.raises(error, match=re.escape(message)):
        typical_parameters("precision", "SI", t)
