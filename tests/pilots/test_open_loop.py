"""The open-loop ARMAX simulation of Boer & Kenyon's Sec. IV against independent answers.

- Constant delay: scipy.signal.lfilter of the same system written with ``z^-40`` (the
  15-Hz shift at 600 Hz) on the 600-Hz input, sampled at 60 Hz: 1e-12 (rounding).
- Time-varying delay: every 15-Hz sample obeys the ARMA difference equation with the
  input read from the forcing function at the recorded delay: 1e-12.
"""

import re

import numpy as np
import pytest
import scipy.signal

from manualcontrol.envs.schedules import BandLimitedRandomWalk
from manualcontrol.envs.signals import forcing_preset
from manualcontrol.pilots.open_loop import ARMAXSystem, simulate_open_loop

A = (0.5924,)
B = (1.5119, -1.1043)


def test_a_constant_delay_equals_lfilter_of_the_15_hz_system_at_600_hz():
    system = ARMAXSystem(A, B, 0.125)  # 75 samples at 600 Hz
    recording = simulate_open_loop(system, "boer-kenyon1998", run_in=5.0, measurement_time=10.0)
    r = forcing_preset("boer-kenyon1998", 0).target
    fine = -5.0 + np.arange(9000) / 600
    b = np.zeros(41 + 75)
    b[75], b[75 + 40] = B
    a = np.zeros(41)
    a[0], a[40] = 1.0, -A[0]
    reference = scipy.signal.lfilter(b, a, r(fine))[::10][300:]
    np.testing.assert_allclose(recording.u, reference, rtol=0, atol=1e-12 * np.abs(reference).max())
    np.testing.assert_allclose(recording.ft, r(recording.t), rtol=0, atol=1e-12)
    assert np.all(recording.parameters["d"] == 0.125)
    assert recording.metadata["task"] == "open-loop"


def test_a_wandering_delay_obeys_the_arma_equation_at_every_15_hz_sample():
    walk = BandLimitedRandomWalk(0.3, 0.1 / 600, 0.3, 30.0, 11)
    system = ARMAXSystem(A, B, walk)
    recording = simulate_open_loop(system, "boer-kenyon1998", realisation=2, measurement_time=20.0)
    r = forcing_preset("boer-kenyon1998", 2).target
    t, u, d = recording.t, recording.u, recording.parameters["d"]
    # the delay applied is the walk rounded to the 600-Hz grid
    np.testing.assert_allclose(d, np.rint(walk(t) * 600) / 600, rtol=0, atol=1e-15)
    assert np.ptp(d) > 0.2
    k = np.arange(4, len(t))
    expected = A[0] * u[k - 4] + B[0] * r(t[k] - d[k]) + B[1] * r(t[k] - 1 / 15 - d[k])
    np.testing.assert_allclose(u[k], expected, rtol=0, atol=1e-12 * np.abs(u).max())


def test_output_noise_is_band_limited_with_the_given_spread():
    system = ARMAXSystem(A, B, 0.2, noise_std=0.01, noise_cutoff_hz=3.0)
    noisy = simulate_open_loop(system, "boer-kenyon1998", seed=4, measurement_time=60.0)
    clean = simulate_open_loop(ARMAXSystem(A, B, 0.2), "boer-kenyon1998", measurement_time=60.0)
    np.testing.assert_allclose(noisy.u - noisy["u_n"], clean.u, rtol=0, atol=1e-12)
    assert np.std(noisy["u_n"]) == pytest.approx(0.01, rel=0.05)  # a 60-Hz subsample of it
    again = simulate_open_loop(system, "boer-kenyon1998", seed=4, measurement_time=60.0)
    assert again == noisy


def test_systems_save_and_bad_ones_are_refused():
    system = ARMAXSystem(A, B, BandLimitedRandomWalk(0.1, 1e-4, 0.3, 60.0, 1), noise_std=0.01)
    assert ARMAXSystem.from_dict(system.to_dict()) == system
    with pytest.raises(ValueError, match=re.escape("step must be a whole number of simulation")):
        ARMAXSystem(A, B, 0.1, step=0.001)
    with pytest.raises(ValueError, match=re.escape("b must have at least 1 entries, got 0")):
        ARMAXSystem(A, (), 0.1)
    with pytest.raises(TypeError, match=re.escape("ARMAXSystem got unknown key(s) 'c'")):
        ARMAXSystem.from_dict({"a": [], "b": [1.0], "delay": 0.1, "c": [0.5]})
    with pytest.raises(TypeError, match=re.escape("ARMAXSystem is missing key(s) delay")):
        ARMAXSystem.from_dict({"a": [], "b": [1.0]})
    with pytest.raises(ValueError, match=re.escape("dt must be a whole number of simulation")):
        simulate_open_loop(system, dt=0.01234)
    with pytest.raises(ValueError, match="has no target to drive the system with"):
        simulate_open_loop(system, "boer-kenyon1998-critical")
