"""Band-limited noise as a forcing function, the band-limited random walk, the critical task.

The oracles are numpy's FFT on the generated samples (what lies above the cut-off, the
standard deviation) and finite differences; tolerances are rounding (1e-12) except the
bicubic slope, whose error is second order in the grid step (checked at 1e-3 of the
slope's scale for a 1-Hz signal on a 0.01-s grid).
"""

import re

import numpy as np
import pytest

from manualcontrol.envs.elements import critical_task, make_element
from manualcontrol.envs.schedules import BandLimitedRandomWalk, Schedule
from manualcontrol.envs.signals import (
    BandLimitedNoise,
    ForcingPair,
    forcing_preset,
    preset_realisation_count,
)


def spectrum_above(values, dt, cutoff):
    power = np.abs(np.fft.rfft(values)) ** 2
    return power[np.fft.rfftfreq(values.shape[0], dt) > cutoff].sum() / power.sum()


def test_the_walk_increments_are_band_limited_noise_of_the_given_spread():
    walk = BandLimitedRandomWalk(0.25, 0.1 / 600, 0.3, 60.0, 11)
    times, values = walk.grid
    increments = np.diff(values)
    assert times.shape == (36001,) and values[0] == 0.25
    assert np.std(increments) == pytest.approx(0.1 / 600, rel=1e-12)
    assert spectrum_above(increments, 1 / 600, 0.3) < 1e-20
    # between grid points linear, before 0 the initial value, after the end the last
    assert walk(-5.0) == 0.25 and walk(100.0) == values[-1]
    assert walk(times[7] / 2 + times[8] / 2) == pytest.approx((values[7] + values[8]) / 2)
    # the same seed, the same walk; another seed, another
    assert np.array_equal(BandLimitedRandomWalk(0.25, 0.1 / 600, 0.3, 60.0, 11)(times), values)
    assert not np.array_equal(BandLimitedRandomWalk(0.25, 0.1 / 600, 0.3, 60.0, 12)(times), values)


def test_the_walk_reflects_at_its_bounds_and_saves():
    walk = BandLimitedRandomWalk(0.3, 0.1 / 600, 0.3, 60.0, 5, lower=0.05, upper=0.6)
    values = walk.grid[1]
    assert values.min() >= 0.05 and values.max() <= 0.6
    assert np.any(values > 0.55) and np.any(values < 0.1)  # it reaches both sides
    assert Schedule.from_dict(walk.to_dict()) == walk
    assert "band-limited random walk(from 0.3" in walk.describe()


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        ({"cutoff_hz": 0.001}, "cutoff_hz must lie in [0.0166667, 300] Hz"),
        ({"increment_std": -1.0}, "increment_std must be >= 0, got -1.0"),
        ({"dt": 100.0}, "dt must be <= duration = 60.0 s, got dt = 100.0"),
        ({"initial": 1.0, "upper": 0.5}, "initial must lie in [None, 0.5], got 1.0"),
        ({"seed": -2}, "seed must be >= 0, got -2"),
    ],
)
def test_bad_walks_raise_with_the_argument_named(arguments, message):
    base = {"initial": 0.0, "increment_std": 1e-4, "cutoff_hz": 0.3, "duration": 60.0, "seed": 0}
    with pytest.raises(ValueError, match=re.escape(message)):
        BandLimitedRandomWalk(**{**base, **arguments})


def test_band_limited_noise_is_a_periodic_forcing_exact_at_its_samples():
    noise = BandLimitedNoise(1.0, 2.0, 120.0, 3)
    grid = np.arange(12000) * 0.01
    samples = noise(grid)
    assert np.std(samples) == pytest.approx(2.0, rel=1e-12)
    assert noise.variance == 4.0 and noise.measurement_time == 120.0
    assert spectrum_above(samples, 0.01, 1.0) < 1e-20
    # periodic: one period later the same values, and no jump at the wrap
    np.testing.assert_allclose(noise(grid + 120.0), samples, rtol=0, atol=1e-12)
    # the slope against a central difference of the (smooth) interpolant
    t = np.linspace(3.0, 90.0, 500)
    h = 1e-6
    numeric = (noise(t + h) - noise(t - h)) / (2 * h)
    np.testing.assert_allclose(noise.derivative(t), numeric, rtol=0, atol=1e-3 * np.std(numeric))
    # the trigonometric interpolant of the samples is the band-limited signal itself:
    # the bicubic reading between samples agrees with it to the kernel's accuracy
    spectrum = np.fft.rfft(samples)
    omega = 2 * np.pi * np.fft.rfftfreq(12000, 0.01)
    weights = np.where(np.arange(spectrum.shape[0]) == 0, 1.0, 2.0) / 12000
    exact = np.real(np.exp(1j * np.outer(t, omega)) @ (weights * spectrum))
    np.testing.assert_allclose(noise(t), exact, rtol=0, atol=1e-3 * 2.0)


def test_noise_forcing_pairs_save_and_load_and_the_presets_exist():
    for name, cutoff, std, where in (
        ("boer-kenyon1998", 1.0, 2.0, "target"),
        ("boer-kenyon1998-postview", 0.6, 2.0, "target"),
        ("boer-kenyon1998-critical", 1.0, 0.02, "disturbance"),
    ):
        assert preset_realisation_count(name) == 10
        pair = forcing_preset(name, 3)
        signal = getattr(pair, where)
        assert isinstance(signal, BandLimitedNoise)
        assert (signal.cutoff_hz, signal.std, signal.seed) == (cutoff, std, 2001)
        assert ForcingPair.from_dict(pair.to_dict()) == pair
    assert forcing_preset("boer-kenyon1998", 0).target.dt == 1 / 600  # the 600-Hz simulation


@pytest.mark.parametrize(
    ("build", "error", "message"),
    [
        (lambda: BandLimitedNoise(0.001, 1.0, 120.0, 0), ValueError, "cutoff_hz must lie in"),
        (lambda: BandLimitedNoise(1.0, 1.0, 1.005, 0), ValueError, "duration must be a whole"),
        (lambda: BandLimitedNoise(1.0, -1.0, 10.0, 0), ValueError, "std must be >= 0, got -1.0"),
        (
            lambda: BandLimitedNoise.from_dict({"kind": "band_limited_noise", "std": 1.0}),
            TypeError,
            "BandLimitedNoise.from_dict is missing key(s) cutoff_hz, duration, seed",
        ),
        (
            lambda: BandLimitedNoise.from_dict({"kind": "band_limited_noise", "hz": 1.0}),
            TypeError,
            "BandLimitedNoise.from_dict got unknown key(s) 'hz'",
        ),
    ],
)
def test_bad_noise_raises_with_the_argument_named(build, error, message):
    with pytest.raises(error, match=re.escape(message)):
        build()


def test_the_critical_task_may_start_at_zero_instability_and_rise_at_any_rate():
    element = make_element({"kind": "critical_task", "start": 0.0, "rate": 0.11})
    assert element == critical_task(0.0, 0.11)
    values = element.parameters_at(np.array([-1.0, 0.0, 10.0]))["instability"]
    np.testing.assert_allclose(values, [0.0, 0.0, 1.1])
    exact, model = element.discretize(0.01, np.array([0.0]))
    assert exact.phi[0, 0, 0] == 1.0 and model.C[0, 0, 0] == 0.0  # 0/s: the output holds
    with pytest.raises(ValueError, match=re.escape("start must be >= 0, got -1.0")):
        critical_task(-1.0)
    with pytest.raises(TypeError, match=re.escape("critical_task got unknown key(s) 'slope'")):
        make_element({"kind": "critical_task", "slope": 1.0})
    with pytest.raises(
        ValueError, match=re.escape("parameter instability must be >= 0, got minimum -0.5")
    ):
        make_element({"kind": "unstable_first_order", "instability": -0.5})
