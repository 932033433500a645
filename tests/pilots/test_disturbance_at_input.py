"""The disturbance at the controlled element's input, against independent answers.

``disturbance_at="input"`` makes ``y = H_c (u + fd)`` instead of ``y = H_c u + fd``.
The references are computed here from the elements' polynomials, written out by hand
(not parsed), with scipy.signal. Tolerances, and why:

- Sampled loop against the same loop with the disturbance's *held* image at the
  output: the held disturbance reaches the element's output at the samples exactly
  through the zero-order-hold element ``H_d(z)`` (scipy's ``cont2discrete``), so a
  multisine line ``A sin(w t + p)`` at the input equals the line ``A |H_d| sin(w t +
  p + arg H_d)``, ``z = e^{j w dt}``, at the output. Both runs start at rest; their
  transients (a constant offset of the integrator included) die with the closed
  loop's poles during the 60 s run-in. What is left is rounding: 1e-9 of the
  signal's standard deviation (measured 1.3e-12 for 1/(s(s+1)), 3e-14 for 1/s).
- Continuous loop against the image through ``H_c(jw)`` itself: the held disturbance
  lags its continuous image by half a sample (the hold's ``e^{-j w dt/2}``), an
  error of about ``A |H_c(jw)| w dt/2`` per line before the loop acts on it, which
  the loop's sensitivity ``1/(1 + H_p H_c)`` shapes. Tolerance: the sum over the lines
  times the sensitivity's peak (1.0e-2 for 1/(s(s+1)), measured 4.3e-3; 2.1e-2 for
  1/s, measured 5.8e-3).
- Padé delay, continuous loop: the simulation is the exact zero-order-hold solution
  of the closed loop, equal to lsim(interp=False) of the analytic closed-loop transfer
  functions ``fd -> y = H_c/(1 + H_p H_c)``, ``fd -> u = -H_p H_c/(1 + H_p H_c)`` up to
  rounding: 1e-9 of the signal's standard deviation, as for the output (measured
  under 2e-12).
- The element alone, lsim from rest over the recording's own ``u`` and ``fd``: in the
  sampled loop both are held, so lsim(interp=False) of ``u + fd`` is exact (1e-9,
  measured 6e-13). In the continuous loop ``u`` varies within each sample: a
  first-order hold of its samples leaves an error second order in dt (measured 4.0e-3,
  9.9e-4, 2.5e-4 for 1/(s(s+1)) at dt = 0.02, 0.01, 0.005 s, the same size as for
  the disturbance at the output; 1.5e-4 for 1/s at 0.01 s): tolerance 2e-3 at
  dt = 0.01 s.
- A time-varying element in the sampled loop, stepped here from ``u + fd`` with
  scipy's ZOH discretisation frozen at each sample: 1e-9 (rounding).
"""

import re
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.signal

from manualcontrol.bench.cli import EXIT_OK, EXIT_USAGE, main
from manualcontrol.envs.elements import make_element
from manualcontrol.envs.recording import Recording
from manualcontrol.envs.signals import ForcingPair, Multisine, forcing_preset
from manualcontrol.pilots import Pilot, SimulationSetup, simulate

sys.path.insert(0, str(Path(__file__).parent))
from closed_loop_reference import pilot_polynomials

DT = 0.01
# the elements as polynomials in s (descending powers), written out by hand
LAGGED = ([1.0], [1.0, 1.0, 0.0])  # 1/(s(s+1))
SINGLE = ([1.0], [1.0, 0.0])  # 1/s
# pilots that close stable loops on them (the lagged one needs the lead)
PILOTS = {
    "1/(s(s+1))": dict(K_p=1.2, K_v=0.6, tau_v=0.28, omega_nms=10.0, zeta_nms=0.4),
    "1/s": dict(K_p=2.0, K_v=0.0, tau_v=0.26, omega_nms=10.5, zeta_nms=0.35),
}
CASES = [("1/(s(s+1))", LAGGED), ("1/s", SINGLE)]
FORCING = forcing_preset("vanderel-bw4")


def _image(disturbance, response):
    """The multisine ``disturbance`` seen through a frequency response at its lines."""
    return Multisine(
        disturbance.frequencies,
        disturbance.amplitudes * np.abs(response),
        disturbance.phases + np.angle(response),
        disturbance.measurement_time,
    )


def _zoh_response(ce, omega):
    """``H_d(e^{j w dt})``: the element's zero-order-hold discretisation (scipy)."""
    num, den, _ = scipy.signal.cont2discrete(ce, DT, method="zoh")
    z = np.exp(1j * omega * DT)
    return np.polyval(np.ravel(num), z) / np.polyval(den, z)


def _continuous_response(ce, omega):
    return np.polyval(ce[0], 1j * omega) / np.polyval(ce[1], 1j * omega)


@pytest.mark.parametrize(("element", "ce"), CASES)
def test_sampled_loop_equals_the_held_image_at_the_output(element, ce):
    pilot = Pilot("precision", PILOTS[element])
    fd = FORCING.disturbance
    at_input = simulate(pilot, element, FORCING, loop="sampled", disturbance_at="input")
    image = _image(fd, _zoh_response(ce, fd.frequencies))
    at_output = simulate(pilot, element, ForcingPair(FORCING.target, image), loop="sampled")
    for name in ("y", "u", "e"):
        error = np.max(np.abs(at_input[name] - at_output[name])) / np.std(at_output[name])
        assert error < 1e-9, (name, error)
    # the recording holds the disturbance as injected, not its image
    np.testing.assert_allclose(at_input.fd, fd(at_input.t), rtol=0, atol=1e-12)


@pytest.mark.parametrize(("element", "ce"), CASES)
def test_continuous_loop_equals_the_image_through_the_element_to_half_a_sample(element, ce):
    values = PILOTS[element]
    pilot = Pilot("precision", values)
    fd = FORCING.disturbance
    omega, amplitude = fd.frequencies, fd.amplitudes
    response = _continuous_response(ce, omega)
    at_input = simulate(pilot, element, FORCING, disturbance_at="input")
    image = ForcingPair(FORCING.target, _image(fd, response))
    at_output = simulate(pilot, element, image)
    # the sensitivity 1/(1 + H_p H_c) of the pilot with its exact delay
    s = 1j * omega
    w, z = values["omega_nms"], values["zeta_nms"]
    h_p = (values["K_p"] + values["K_v"] * s) * np.exp(-values["tau_v"] * s) * w**2
    h_p /= s**2 + 2 * z * w * s + w**2
    peak = np.max(np.abs(1.0 / (1.0 + h_p * response)))
    tolerance = peak * np.sum(amplitude * np.abs(response) * omega * DT / 2)
    for name in ("y", "e"):
        assert np.max(np.abs(at_input[name] - at_output[name])) < tolerance, name


@pytest.mark.parametrize(("element", "ce"), [("SI", ([1.5], [1.0, 0.0])), ("1/(s(s+1))", LAGGED)])
def test_pade_loop_equals_lsim_of_the_analytic_closed_loop(element, ce):
    values = PILOTS["1/(s(s+1))"] if element != "SI" else PILOTS["1/s"]
    pilot = Pilot("precision", values, delay_order=5)
    recording = simulate(pilot, element, FORCING, disturbance_at="input", keep_run_in=True)
    np_, dp = pilot_polynomials(values, 5)
    nc, dc = ce
    char = np.polyadd(np.polymul(dp, dc), np.polymul(np_, nc))  # (1 + H_p H_c) D_p D_c
    t = recording.t - recording.t[0]
    ft, fd = recording.ft, recording.fd

    def lsim(num, signal):
        return scipy.signal.lsim((num, char), signal, t, interp=False)[1]

    u = lsim(np.polymul(np_, dc), ft) - lsim(np.polymul(np_, nc), fd)
    y = lsim(np.polymul(np_, nc), ft) + lsim(np.polymul(dp, nc), fd)
    for name, reference in (("u", u), ("y", y)):
        error = np.max(np.abs(recording[name] - reference)) / np.std(reference)
        assert error < 1e-9, (name, error)


@pytest.mark.parametrize(("element", "ce"), CASES)
def test_the_element_driven_by_u_plus_fd_gives_the_recorded_output(element, ce):
    pilot = Pilot("precision", PILOTS[element])
    kwargs = dict(disturbance_at="input", keep_run_in=True)
    sampled = simulate(pilot, element, FORCING, loop="sampled", **kwargs)
    t = sampled.t - sampled.t[0]
    y = scipy.signal.lsim(ce, sampled.u + sampled.fd, t, interp=False)[1]
    assert np.max(np.abs(sampled.y - y)) < 1e-9 * np.std(y)
    # the other hypothesis, the disturbance added at the output, is far off
    y_output = scipy.signal.lsim(ce, sampled.u, t, interp=False)[1] + sampled.fd
    assert np.max(np.abs(sampled.y - y_output)) > 0.1
    continuous = simulate(pilot, element, FORCING, **kwargs)
    y = scipy.signal.lsim(ce, continuous.fd, t, interp=False)[1]  # held
    y += scipy.signal.lsim(ce, continuous.u, t, interp=True)[1]  # continuous
    assert np.max(np.abs(continuous.y - y)) < 2e-3


def test_time_varying_element_is_driven_by_u_plus_fd_at_every_sample():
    # Popovici's 4/(s(s + omega_b)), omega_b falling from 3 to 1 rad/s around 45 s; the
    # element is stepped here in scipy's canonical form (the same state coordinates,
    # rate and position, so the frozen-per-sample stepping is the same LPV system)
    pilot = Pilot("precision", dict(K_p=1.5, K_v=0.5, tau_v=0.28, omega_nms=10.0, zeta_nms=0.4))
    run = simulate(
        pilot,
        "popovici2017-tv",
        FORCING,
        loop="sampled",
        disturbance_at="input",
        run_in=10.0,
        measurement_time=80.0,
        keep_run_in=True,
    )
    omega_b = make_element("popovici2017-tv").parameters_at(run.t)["omega_b"]
    assert omega_b[0] == pytest.approx(3.0, abs=1e-3) and omega_b[-1] < 1.01
    drive = run.u + run.fd
    x = np.zeros(2)
    y = np.empty(len(run))
    steps = {}
    for k, value in enumerate(omega_b):
        if value not in steps:
            A, B, C, D = scipy.signal.tf2ss([4.0], [1.0, value, 0.0])
            steps[value] = scipy.signal.cont2discrete((A, B, C, D), DT, method="zoh")[:3]
        phi, gamma, c = steps[value]
        y[k] = (c @ x)[0]
        x = phi @ x + gamma[:, 0] * drive[k]
    assert np.max(np.abs(run.y - y)) < 1e-9 * np.std(y)
    assert np.std(run.fd) > 0.1  # the disturbance really drove it


def test_metadata_say_where_the_disturbance_entered():
    pilot = Pilot("precision", PILOTS["1/s"])
    short = dict(run_in=5.0, measurement_time=10.0)
    assert simulate(pilot, "1/s", **short).metadata["disturbance_at"] == "output"
    at_input = simulate(pilot, "1/s", disturbance_at="input", **short)
    assert at_input.metadata["disturbance_at"] == "input"
    assert at_input.metadata["controlled_element"]["kind"] == "integrator"


def test_a_remnant_at_the_input_disturbance_keeps_its_parts_apart():
    # the remnant part y_n and the remnant-free rest still add up to the run
    pilot = Pilot("precision", PILOTS["1/(s(s+1))"], remnant="popovici2017")
    run = simulate(pilot, "1/(s(s+1))", seed=3, disturbance_at="input")
    free = simulate(pilot.with_remnant(None), "1/(s(s+1))", disturbance_at="input")
    np.testing.assert_allclose(run.y - run["y_n"], free.y, rtol=0, atol=1e-9)
    assert run.metadata["remnant_power_ratio"] == pytest.approx(0.30, rel=1e-6)


@pytest.mark.parametrize(
    "build",
    [
        lambda: simulate(Pilot("precision"), "SI", disturbance_at="inlet"),
        lambda: SimulationSetup.create(Pilot("precision"), "SI", disturbance_at="inlet"),
    ],
)
def test_an_unknown_disturbance_point_is_refused(build):
    message = "disturbance_at must be one of 'output', 'input', got 'inlet'"
    with pytest.raises(ValueError, match=re.escape(message)):
        build()


# ---------------------------------------------------------- `manualcontrol simulate`


def test_the_simulate_command_takes_a_written_element_and_the_disturbance_point(tmp_path, capsys):
    out = tmp_path / "run.npz"
    code = main(
        [
            "simulate",
            "--element",
            "1/(s(s+1))",
            "--disturbance-at",
            "input",
            "--run-in",
            "5",
            "--measurement-time",
            "10",
            "--out",
            str(out),
        ]
    )
    assert code == EXIT_OK, capsys.readouterr().err
    recording = Recording.load(out)
    assert recording.metadata["disturbance_at"] == "input"
    element = recording.metadata["controlled_element"]
    assert element["kind"] == "integrator_with_lag" and element["omega_b"]["value"] == 1.0


def test_the_simulate_command_refuses_an_unknown_disturbance_point(tmp_path, capsys):
    out = tmp_path / "run.npz"
    code = main(["simulate", "--disturbance-at", "inlet", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == EXIT_USAGE
    assert err.strip() == (
        "manualcontrol simulate: error: --disturbance-at must be one of 'output', 'input', "
        "got 'inlet'"
    )
    assert not out.exists()
