"""Offline output-error fit and forcing-frequency responses against known pilots."""

import re
import warnings

import numpy as np
import pytest
import scipy.optimize
import scipy.signal

from manualcontrol.estimators.analysis.frequency import forcing_frequency_response
from manualcontrol.estimators.offline.output_error import fit_pilot
from manualcontrol.pilots import Pilot, make_model, simulate

DI_PILOT = dict(K_p=0.24, K_v=0.36, tau_v=0.3, omega_nms=8.0, zeta_nms=0.45)


def test_frequency_response_recovers_the_pilot_and_open_loop():
    # Sampled loop with a Padé pilot: u[k] is the zero-order-hold discretisation of
    # H_p driven by the sampled e[k], so U/E at the target bins equals that discrete
    # system's response at z = exp(j w dt), up to the transient left after the run-in.
    dt = 0.01
    pilot = Pilot("precision", DI_PILOT, delay_order=6)
    recording = simulate(pilot, "DI", "vanderel-bw4", loop="sampled", run_in=120.0)
    response = forcing_frequency_response(recording)
    model = make_model("precision")
    num, den = model.transfer_function(DI_PILOT, "e", delay_order=6)
    with warnings.catch_warnings():
        # the product polynomial's leading numerator term is ~1e-17: scipy warns, harmlessly
        warnings.simplefilter("ignore", scipy.signal.BadCoefficients)
        pilot_d = scipy.signal.cont2discrete(scipy.signal.tf2ss(num, den), dt)
    element_d = scipy.signal.cont2discrete(scipy.signal.tf2ss([5.0], [1.0, 0.0, 0.0]), dt)
    z = np.exp(1j * response.frequencies * dt)

    def discrete_response(system):
        phi, gamma, c, d, _ = system
        eye = np.eye(phi.shape[0])
        return np.array([(c @ np.linalg.solve(zi * eye - phi, gamma) + d)[0, 0] for zi in z])

    expected_pilot = discrete_response(pilot_d)
    np.testing.assert_allclose(response.pilot, expected_pilot, rtol=1e-6)
    np.testing.assert_allclose(
        response.open_loop, expected_pilot * discrete_response(element_d), rtol=1e-6
    )

    # crossover and phase margin of the continuous open loop, interpolated between
    # forcing frequencies (log spaced about a factor 1.5 apart): a few percent
    def gain_minus_one(w):
        return abs(model.frequency_response(DI_PILOT, [w], "e")[0] * 5.0 / (1j * w) ** 2) - 1.0

    crossover = scipy.optimize.brentq(gain_minus_one, 0.5, 5.0)
    h = model.frequency_response(DI_PILOT, [crossover], "e")[0] * 5.0 / (1j * crossover) ** 2
    margin = np.degrees(np.angle(h)) + 180.0
    assert response.crossover_frequency == pytest.approx(crossover, rel=0.05)
    assert response.phase_margin == pytest.approx(margin, abs=5.0)


def test_frequency_response_needs_whole_periods():
    recording = simulate(Pilot("precision", DI_PILOT), "DI", "vanderel-bw4", measurement_time=50.0)
    with pytest.raises(
        ValueError, match=re.escape("recording must span a whole number of target periods")
    ):
        forcing_frequency_response(recording)


def test_offline_fit_recovers_a_noise_free_pilot_exactly():
    recording = simulate(Pilot("precision", DI_PILOT), "DI", "vanderel-bw4", loop="sampled")
    fit = fit_pilot(recording, "precision", delay_grid=(0.2, 0.4))
    for name, value in DI_PILOT.items():
        assert fit.parameters[name] == pytest.approx(value, rel=1e-4), name
    assert fit.vaf > 99.999 and fit.success


def test_offline_fit_with_remnant_stays_close():
    pilot = Pilot("precision", DI_PILOT, remnant="popovici2017")
    recording = simulate(pilot, "DI", "vanderel-bw4", loop="sampled", seed=2)
    fit = fit_pilot(recording, "precision")
    assert fit.parameters["tau_v"] == pytest.approx(0.3, abs=0.02)
    assert fit.parameters["K_v"] == pytest.approx(0.36, rel=0.1)
    assert 70.0 < fit.vaf < 99.0  # 30 % remnant power cannot be explained


def test_offline_fit_of_a_preview_pilot_with_fixed_parameters():
    values = {"tau_f": 0.5, "K_f": 0.9}
    recording = simulate(
        Pilot("preview", values), "SI", "vanderel-bw4", loop="sampled", run_in=10.0
    )
    fixed = {"omega_f": 3.3, "K_v": 0.0, "omega_nms": 10.5, "zeta_nms": 0.35}
    fit = fit_pilot(recording, "preview", fixed=fixed, delay_grid=(0.26,))
    assert fit.fitted == ("K_f", "tau_f", "K_p", "tau_v")
    assert fit.parameters["tau_f"] == pytest.approx(0.5, abs=5e-3)
    assert fit.parameters["K_f"] == pytest.approx(0.9, rel=1e-2)


def test_offline_fit_rejects_unknown_parameters():
    recording = simulate(Pilot("precision", DI_PILOT), "DI", run_in=0.0, measurement_time=10.0)
    with pytest.raises(ValueError, match=re.escape("precision model has no parameter(s) ['T_L']")):
        fit_pilot(recording, "precision", fixed={"T_L": 0.3})
