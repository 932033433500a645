"""envs.signals: multisines (thesis eq. 35, App. H.4.4), presets, sampled signals, noise."""

import importlib.resources
import json
import math
import pickle
import re
import subprocess
import sys
import tracemalloc

import numpy as np
import pytest

from manualcontrol.envs.signals import (
    FORCING_PRESETS,
    ForcingFunction,
    ForcingPair,
    Multisine,
    SampledSignal,
    amplitude_profile,
    band_limited_noise,
    design_multisine,
    forcing_preset,
    interleaved_harmonics,
    multisine_frequencies,
    preset_realisation_count,
    realisations,
)

PLAETINCK_T_M = 81.92


def plaetinck_table():
    path = importlib.resources.files("manualcontrol.envs").joinpath(
        "data/plaetinck2018-multisine.csv"
    )
    with importlib.resources.as_file(path) as file:
        table = np.loadtxt(file, delimiter=",", skiprows=1)
    return {name: table[:, i] for i, name in enumerate(["kf", "nf", "nfwm", "Af", "phi_f"])}


def example(measurement_time=40.0):
    base = 2 * np.pi / measurement_time
    return Multisine(
        np.array([2, 5, 11, 23]) * base,
        [1.0, 0.6, 0.3, 0.1],
        [0.1, -1.2, 2.0, 0.7],
        measurement_time,
    )


# ----------------------------------------------------------------------- multisine


def test_multisine_is_eq_35():
    m = example()
    t = np.linspace(-3.0, 50.0, 1001)
    expected = sum(
        a * np.sin(w * t + p) for w, a, p in zip(m.frequencies, m.amplitudes, m.phases, strict=True)
    )
    np.testing.assert_allclose(m(t), expected, rtol=0, atol=1e-14)
    assert isinstance(m(float(t[17])), float) and m(float(t[17])) == m(t)[17]
    np.testing.assert_allclose(m(t.reshape(7, 143)), expected.reshape(7, 143), atol=1e-14)


def test_a_remembered_evaluation_is_the_evaluation_of_those_very_times():
    import manualcontrol.envs.signals as signals

    m = example()
    t = np.arange(-600, 5000) * 0.01  # long enough to be remembered
    direct = m._sum(t, m.amplitudes, np.sin)
    first = m(t)
    np.testing.assert_array_equal(first, direct)
    first[:] = 0.0  # the caller's copy: what is remembered stays
    np.testing.assert_array_equal(m(t.copy()), direct)
    # times that agree where the lookup key looks (ends and middle) but not elsewhere
    other = t.copy()
    other[1234] += 0.5
    np.testing.assert_array_equal(m(other), m._sum(other, m.amplitudes, np.sin))
    np.testing.assert_array_equal(m(t), direct)
    # the derivative (cosine weights) and another signal are remembered apart
    np.testing.assert_array_equal(m.derivative(t), m._sum(t, m.amplitudes * m.frequencies, np.cos))
    shifted = Multisine(m.frequencies, m.amplitudes, m.phases + 0.3, m.measurement_time)
    np.testing.assert_array_equal(shifted(t), shifted._sum(t, shifted.amplitudes, np.sin))
    for start in range(2 * signals._REMEMBERED_EVALUATIONS):  # bounded memory
        m(t + start)
    assert len(signals._EVALUATIONS) <= signals._REMEMBERED_EVALUATIONS


def test_multisine_is_periodic_over_measurement_time():
    m = example()
    t = np.linspace(0.0, 40.0, 997)
    np.testing.assert_allclose(m(t + m.measurement_time), m(t), rtol=0, atol=1e-12)
    np.testing.assert_allclose(m.derivative(t + 3 * 40.0), m.derivative(t), rtol=0, atol=1e-11)


def test_harmonics_are_the_integer_multiples():
    np.testing.assert_array_equal(example().harmonics, [2, 5, 11, 23])
    assert example().harmonics.dtype == np.int64


def test_variance_formula_equals_sampled_variance_over_one_period():
    m = example()
    samples = m.sample(m.measurement_time, 0.01)
    assert samples.shape == (4000,)
    assert m.variance == pytest.approx(0.5 * (1 + 0.36 + 0.09 + 0.01), rel=1e-15)
    assert np.var(samples) == pytest.approx(m.variance, rel=1e-12)
    assert abs(np.mean(samples)) < 1e-13


def test_derivative_matches_central_difference():
    m = example()
    t = np.linspace(0.0, 40.0, 333)
    h = 1e-5
    numeric = (m(t + h) - m(t - h)) / (2 * h)
    np.testing.assert_allclose(m.derivative(t), numeric, rtol=0, atol=1e-8)


def test_sample_uses_t0_plus_k_dt():
    m = example()
    np.testing.assert_allclose(m.sample(1.0, 0.1, t0=2.0), m(2.0 + np.arange(10) * 0.1), atol=1e-15)


def test_long_evaluation_needs_no_matrix_of_sines():
    # an (n_times, n_sines) matrix would need 10 * 8 bytes per time; this stays O(n_times)
    m = forcing_preset("vanderel-bw4").target
    t = np.arange(1_000_000) * 0.01
    tracemalloc.start()
    try:
        values = m(t)
        m.derivative(t)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 4 * t.nbytes
    np.testing.assert_allclose(values[-3:], m(t[-3:]), atol=1e-12)


def test_crest_factor_of_a_single_sine_is_sqrt_two():
    # 2 pi / 0.001 is not a whole number of samples, hence the 1e-4
    assert Multisine.sine(0.25, 1.0).crest_factor(dt=0.001) == pytest.approx(math.sqrt(2), rel=1e-4)
    m = Multisine([1.0], [2.0], [0.0])  # not periodic over a base frequency
    assert m.crest_factor(duration=2 * np.pi, dt=0.001) == pytest.approx(math.sqrt(2), rel=1e-4)


def test_scaled_to_variance_keeps_the_shape():
    m = example()
    scaled = m.scaled_to_variance(2.5)
    assert scaled.variance == pytest.approx(2.5, rel=1e-14)
    factor = scaled.amplitudes / m.amplitudes
    np.testing.assert_allclose(factor, factor[0], rtol=1e-15)
    np.testing.assert_array_equal(scaled.phases, m.phases)


def test_multisine_is_immutable_hashable_and_round_trips():
    m = example()
    with pytest.raises(ValueError, match="read-only"):
        m.amplitudes[0] = 3.0
    with pytest.raises(AttributeError):
        m.measurement_time = 2.0  # type: ignore[misc]
    rebuilt = Multisine.from_dict(json.loads(json.dumps(m.to_dict())))
    assert rebuilt == m and hash(rebuilt) == hash(m)
    assert pickle.loads(pickle.dumps(m)) == m
    assert {m: 1}[rebuilt] == 1
    assert m != m.with_phases([0, 0, 0, 0])


def test_multisine_copies_its_input():
    amplitudes = np.array([1.0, 2.0])
    m = Multisine([1.0, 2.0], amplitudes, [0.0, 0.0])
    amplitudes[0] = 5.0
    assert m.amplitudes[0] == 1.0


def test_multisine_and_sampled_signal_are_forcing_functions():
    assert isinstance(example(), ForcingFunction)
    assert isinstance(SampledSignal([0.0, 1.0], 0.1), ForcingFunction)
    assert not isinstance(3.0, ForcingFunction)


# -------------------------------------------------------------------------- design


def test_multisine_frequencies_are_distinct_log_spread_harmonics():
    frequencies = multisine_frequencies(10, 81.92, 0.23, 17.6)
    harmonics = frequencies * 81.92 / (2 * np.pi)
    np.testing.assert_allclose(harmonics, np.rint(harmonics), atol=1e-9)
    assert np.all(np.diff(harmonics) >= 1)
    assert frequencies[0] >= 0.23 and frequencies[-1] <= 17.6
    # roughly geometric: successive ratios close to the overall ratio^(1/9)
    ratio = (frequencies[-1] / frequencies[0]) ** (1 / 9)
    np.testing.assert_allclose(frequencies[1:] / frequencies[:-1], ratio, rtol=0.25)
    # Plaetinck's table (3, 5, 8, ... 229) is that kind of spread
    np.testing.assert_allclose(np.rint(harmonics), [3, 5, 8, 13, 21, 33, 54, 87, 141, 229])


def test_multisine_frequencies_nudges_crowded_low_harmonics_apart():
    harmonics = multisine_frequencies(8, 10.0, 0.5, 10.0) * 10.0 / (2 * np.pi)
    h = np.rint(harmonics).astype(int)
    assert len(set(h)) == 8 and np.all(np.diff(h) >= 1)
    assert h[0] >= 1 and h[-1] <= 15


def test_amplitude_profile_formula():
    omega = np.array([0.0, 1.25, 10.0])
    expected = np.abs((1 + 1j * omega / 10) ** 2 / (1 + 1j * omega / 1.25) ** 2)
    np.testing.assert_allclose(amplitude_profile(omega, 1.25), expected, rtol=1e-14)


def test_plaetinck_amplitudes_follow_the_profile_up_to_one_scale():
    table = plaetinck_table()
    profile = amplitude_profile(table["nfwm"], bandwidth=1 / 0.8, lead_frequency=10.0)
    scale = table["Af"] / profile
    np.testing.assert_allclose(scale / np.median(scale), 1.0, rtol=0.02)
    # and the profile is really doing the work: a flat spectrum does not fit
    assert np.ptp(table["Af"]) / np.median(table["Af"]) > 1.0


def test_design_multisine_variance_profile_and_seeded_phases():
    kwargs = dict(n_sines=10, measurement_time=120.0, bandwidth=4.0, variance=1.7, low=0.1)
    m = design_multisine(**kwargs, high=20.0, rng=np.random.default_rng(3))
    assert m.variance == pytest.approx(1.7, rel=1e-14)
    assert m.measurement_time == 120.0 and len(m.harmonics) == 10
    ratio = m.amplitudes / amplitude_profile(m.frequencies, 4.0)
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-14)
    assert np.all((m.phases >= 0) & (m.phases < 2 * np.pi))
    again = design_multisine(**kwargs, high=20.0, rng=np.random.default_rng(3))
    assert again == m
    assert design_multisine(**kwargs, high=20.0, rng=np.random.default_rng(4)) != m


def test_design_multisine_with_explicit_harmonics():
    m = design_multisine(3, 10.0, 1.0, 1.0, 0.5, 5.0, np.random.default_rng(0), harmonics=[1, 4, 7])
    np.testing.assert_array_equal(m.harmonics, [1, 4, 7])


def test_realisations_select_low_crest_factors():
    base = forcing_preset("vanderel-bw4").target
    selected = realisations(base, 10, np.random.default_rng(8), n_candidates=500)
    assert len(selected) == 10 and len(set(selected)) == 10
    for m in selected:
        np.testing.assert_array_equal(m.frequencies, base.frequencies)
        np.testing.assert_array_equal(m.amplitudes, base.amplitudes)
    chosen = np.array([m.crest_factor() for m in selected])
    rng = np.random.default_rng(99)
    candidates = [
        base.with_phases(rng.uniform(0, 2 * np.pi, 10)).crest_factor() for _ in range(300)
    ]
    assert chosen.max() < np.median(candidates)
    assert chosen.max() < np.percentile(candidates, 10)


def test_realisations_can_target_a_crest_factor():
    base = forcing_preset("popovici2017").target
    selected = realisations(base, 5, np.random.default_rng(1), select=3.0)
    chosen = np.array([m.crest_factor(dt=0.05) for m in selected])
    np.testing.assert_allclose(chosen, 3.0, atol=0.05)


def test_realisations_are_reproducible():
    base = forcing_preset("vanderel-bw4").target
    first = realisations(base, 10, np.random.default_rng(5), n_candidates=500)
    assert realisations(base, 10, np.random.default_rng(5), n_candidates=500) == first
    assert realisations(base, 10, np.random.default_rng(6), n_candidates=500) != first


def test_interleaved_harmonics_are_adjacent_and_disjoint():
    target, disturbance = interleaved_harmonics(10, 120.0, 0.1, 20.0)
    assert len(target) == len(disturbance) == 10
    assert not set(target.tolist()) & set(disturbance.tolist())
    np.testing.assert_array_equal(disturbance - target, np.ones(10))
    merged = np.column_stack((target, disturbance)).ravel()
    assert np.all(np.diff(merged) > 0)  # t1 < d1 < t2 < d2 < ...
    base = 2 * np.pi / 120.0
    assert target[0] * base >= 0.1 and disturbance[-1] * base <= 20.0


# -------------------------------------------------------------------- forcing pair


def test_forcing_pair_samples_with_zeros_where_absent():
    pair = forcing_preset("schiess-roland1975")
    ft, fd = pair.sample(10.25, 0.01)
    t = np.arange(1025) * 0.01
    np.testing.assert_allclose(ft, 0.25 * np.sin(t), atol=1e-15)
    np.testing.assert_array_equal(fd, np.zeros(1025))
    both = forcing_preset("vanderel-bw4", 3)
    ft, fd = both.sample(5.0, 0.01, t0=1.0)
    np.testing.assert_allclose(fd, both.disturbance(1.0 + np.arange(500) * 0.01), atol=1e-15)


def test_forcing_pair_round_trip():
    for name in FORCING_PRESETS:
        pair = forcing_preset(name, preset_realisation_count(name) - 1)
        rebuilt = ForcingPair.from_dict(json.loads(json.dumps(pair.to_dict())))
        assert rebuilt == pair and hash(rebuilt) == hash(pair)


# ------------------------------------------------------------------------ presets


def test_plaetinck_preset_is_the_table():
    table = plaetinck_table()
    m = forcing_preset("plaetinck2018").target
    assert forcing_preset("plaetinck2018").disturbance is None
    np.testing.assert_allclose(m.frequencies, table["nf"] * 2 * np.pi / PLAETINCK_T_M, rtol=1e-15)
    # nfwm is nf 2 pi / 81.92 to 3 decimals (0.38350 is printed 0.384: rounded twice)
    np.testing.assert_allclose(m.frequencies, table["nfwm"], rtol=0, atol=5.1e-4)
    assert np.mean(np.round(m.frequencies, 3) == table["nfwm"]) >= 0.9
    np.testing.assert_array_equal(m.amplitudes, table["Af"])
    np.testing.assert_array_equal(m.phases, table["phi_f"])
    np.testing.assert_array_equal(m.harmonics, table["nf"].astype(int))
    t = np.linspace(0.0, PLAETINCK_T_M, 513)
    np.testing.assert_allclose(m(t + PLAETINCK_T_M), m(t), atol=1e-12)
    assert preset_realisation_count("plaetinck2018") == 1


def test_vanderel_preset_has_ten_interleaved_realisations():
    assert preset_realisation_count("vanderel-bw4") == 10
    pairs = [forcing_preset("vanderel-bw4", i) for i in range(10)]
    targets = {p.target for p in pairs}
    assert len(targets) == 10 and len({p.disturbance for p in pairs}) == 10
    for i, pair in enumerate(pairs):
        assert pair.realisation == i and pair.name == "vanderel-bw4"
        assert pair.target.measurement_time == pair.disturbance.measurement_time == 120.0
        assert pair.target.variance == pytest.approx(1.0, rel=1e-12)
        assert pair.disturbance.variance == pytest.approx(0.25, rel=1e-12)
        np.testing.assert_array_equal(pair.disturbance.harmonics, pair.target.harmonics + 1)
        assert pair.target.crest_factor() < 2.8
    target = pairs[0].target
    assert 0.1 <= target.frequencies[0] < 0.2 and 15.0 < target.frequencies[-1] <= 20.0
    shaped = target.amplitudes / amplitude_profile(target.frequencies, 4.0)
    np.testing.assert_allclose(shaped, shaped[0], rtol=1e-12)


def test_popovici_preset():
    assert preset_realisation_count("popovici2017") == 5
    variance = forcing_preset("plaetinck2018").target.variance
    for i in range(5):
        pair = forcing_preset("popovici2017", i)
        assert pair.disturbance is None and pair.target.measurement_time == 90.0
        assert len(pair.target.frequencies) == 10
        assert pair.target.variance == pytest.approx(variance, rel=1e-12)
        shaped = pair.target.amplitudes / amplitude_profile(pair.target.frequencies, 1.25)
        np.testing.assert_allclose(shaped, shaped[0], rtol=1e-12)


def test_schiess_roland_preset_is_a_quarter_sine():
    m = forcing_preset("schiess-roland1975").target
    np.testing.assert_allclose(m.frequencies, [1.0])
    np.testing.assert_allclose(m.amplitudes, [0.25])
    assert m.measurement_time == pytest.approx(2 * np.pi) and m.harmonics.tolist() == [1]


def test_presets_are_cached():
    assert forcing_preset("vanderel-bw4", 2) is forcing_preset("vanderel-bw4", 2)


def test_presets_are_identical_in_a_fresh_process():
    code = (
        "import json; from manualcontrol.envs.signals import forcing_preset as f; "
        "print(json.dumps([f('vanderel-bw4', 7).to_dict(), f('popovici2017', 4).to_dict()]))"
    )
    output = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    here = [
        forcing_preset("vanderel-bw4", 7).to_dict(),
        forcing_preset("popovici2017", 4).to_dict(),
    ]
    assert json.loads(output) == json.loads(json.dumps(here))


# ------------------------------------------------------------------ sampled signal


def test_sampled_signal_interpolates_a_slow_sine():
    dt = 0.01
    t = np.arange(3000) * dt
    signal = SampledSignal(np.sin(t), dt)
    query = np.linspace(1.0, 28.0, 10_007) + 0.0037
    np.testing.assert_allclose(signal(query), np.sin(query), rtol=0, atol=1e-6)
    np.testing.assert_allclose(signal.derivative(query), np.cos(query), rtol=0, atol=1e-4)
    # on the samples it reproduces them exactly
    np.testing.assert_allclose(signal(t[5:-5]), np.sin(t[5:-5]), rtol=0, atol=1e-12)
    assert isinstance(signal(1.234), float)


def test_sampled_signal_clamps_outside_when_not_periodic():
    signal = SampledSignal([1.0, 2.0, 4.0, 8.0], 0.5, t0=10.0)
    np.testing.assert_array_equal(signal([0.0, 9.99, 11.5, 99.0]), [1.0, 1.0, 8.0, 8.0])
    np.testing.assert_array_equal(signal.derivative([0.0, 99.0]), [0.0, 0.0])


def test_periodic_sampled_signal_wraps_around():
    dt, period = 0.01, 10.0
    omega = 2 * np.pi / period
    t = np.arange(round(period / dt)) * dt
    signal = SampledSignal(np.sin(omega * t), dt, t0=0.0, periodic=True)
    query = np.linspace(-25.0, 35.0, 7777)
    np.testing.assert_allclose(signal(query), np.sin(omega * query), rtol=0, atol=1e-6)
    np.testing.assert_allclose(
        signal.derivative(query), omega * np.cos(omega * query), rtol=0, atol=1e-4
    )
    np.testing.assert_allclose(signal(query + period), signal(query), atol=1e-12)


def test_sampled_signal_of_a_multisine_matches_the_multisine():
    m = forcing_preset("plaetinck2018").target
    dt = 0.01
    signal = SampledSignal(m.sample(PLAETINCK_T_M, dt), dt, periodic=True)
    query = np.linspace(0.0, 2 * PLAETINCK_T_M, 5001) + 0.003
    np.testing.assert_allclose(signal(query), m(query), atol=1e-4)
    np.testing.assert_allclose(signal.derivative(query), m.derivative(query), atol=2e-2)


def test_sampled_signal_identity():
    a = SampledSignal([0.0, 1.0, 0.5], 0.1, periodic=True)
    b = SampledSignal(np.array([0.0, 1.0, 0.5]), 0.1, periodic=True)
    assert a == b and hash(a) == hash(b)
    assert a != SampledSignal([0.0, 1.0, 0.5], 0.1)
    assert pickle.loads(pickle.dumps(a)) == a
    with pytest.raises(ValueError, match="read-only"):
        a.values[0] = 2.0


# -------------------------------------------------------------------------- noise


def test_band_limited_noise_has_no_content_above_cutoff_and_exact_std():
    n, dt, cutoff, std = 6000, 1 / 600, 1.0, 2.0  # Boer & Kenyon Sec. IV-A: r_n
    noise = band_limited_noise(n, dt, cutoff, std, np.random.default_rng(0))
    assert noise.shape == (n,) and noise.dtype == np.float64
    assert np.std(noise) == pytest.approx(std, rel=1e-14)
    spectrum = np.abs(np.fft.rfft(noise))
    above = np.fft.rfftfreq(n, dt) > cutoff
    assert spectrum[above].max() < 1e-12 * spectrum.max()
    assert spectrum[~above][1:].min() > 0  # the pass band is not empty
    again = band_limited_noise(n, dt, cutoff, std, np.random.default_rng(0))
    np.testing.assert_array_equal(noise, again)
    other = band_limited_noise(n, dt, cutoff, std, np.random.default_rng(1))
    assert not np.allclose(noise, other)


# ----------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (
            lambda: Multisine([1.0], [1.0], [0.0], measurement_time=-2.0),
            "measurement_time must be > 0, got -2.0",
        ),
        (
            lambda: Multisine([1.0], [1.0], [0.0], measurement_time=0.0),
            "measurement_time must be > 0, got 0.0",
        ),
        (
            lambda: Multisine([1.0, 2.0], [1.0], [0.0, 0.0]),
            "amplitudes must have one entry per frequency (2), got length 1",
        ),
        (
            lambda: Multisine([1.0, 2.0], [1.0, 1.0], [0.0, 0.0, 0.0]),
            "phases must have one entry per frequency (2), got length 3",
        ),
        (
            lambda: Multisine([1.0, 2.0], [1.0, np.nan], [0.0, 0.0]),
            "amplitudes must be finite, found 1 infinite or NaN value(s), the first at index 1",
        ),
        (
            lambda: Multisine([1.0, -2.0], [1.0, 1.0], [0.0, 0.0]),
            "frequencies must be > 0 rad/s, got -2.0 at index 1",
        ),
        (
            lambda: Multisine([1.0, 1.0], [1.0, 1.0], [0.0, 0.0]),
            "frequencies must be distinct, got 1.0 rad/s more than once",
        ),
        (
            lambda: Multisine([1.0], [-1.0], [0.0]),
            "amplitudes must be >= 0 (shift the phase by pi instead), got -1.0 at index 0",
        ),
        (
            lambda: Multisine([1.0, 1.5], [1.0, 1.0], [0.0, 0.0], measurement_time=2 * np.pi),
            "frequency 1.5 rad/s at index 1 is 1.500000 times that",
        ),
        (lambda: Multisine([], [], []), "frequencies must have at least 1 entries, got 0"),
        (
            lambda: multisine_frequencies(10, 10.0, 1.0, 5.0),
            "cannot place 10 harmonics of 2*pi/measurement_time = 0.628319 rad/s between "
            "low = 1.0 and high = 5.0 rad/s (harmonics 2 to 7)",
        ),
        (lambda: multisine_frequencies(3, 10.0, 5.0, 1.0), "high must be > low = 5.0 rad/s"),
        (lambda: multisine_frequencies(3, -10.0, 1.0, 5.0), "measurement_time must be > 0"),
        (lambda: interleaved_harmonics(5, 10.0, 1.0, 5.0), "cannot place 5 harmonics"),
        (lambda: amplitude_profile([1.0], 0.0), "bandwidth must be > 0, got 0.0"),
        (
            lambda: design_multisine(
                2, 10.0, 1.0, 1.0, 0.5, 2.0, np.random.default_rng(0), harmonics=[1, 9]
            ),
            "harmonics must be integers in [1, 3] (the band [0.5, 2.0] rad/s), got [1.0, 9.0]",
        ),
        (lambda: example().scaled_to_variance(-1.0), "variance must be > 0, got -1.0"),
        (
            lambda: design_multisine(3, 10.0, 1.0, 0.0, 0.5, 5.0, np.random.default_rng(0)),
            "variance must be > 0, got 0.0",
        ),
        (
            lambda: Multisine([1.0], [1.0], [0.0]).crest_factor(),
            "crest_factor needs a duration when measurement_time is None",
        ),
        (
            lambda: Multisine([1.0], [1.0], [0.0]).harmonics,
            "harmonics need a measurement_time; this Multisine has None",
        ),
        (
            lambda: realisations(example(), 5, np.random.default_rng(0), n_candidates=3),
            "n_candidates must be >= 5, got 3",
        ),
        (
            lambda: realisations(example(), 2, np.random.default_rng(0), select="highest"),
            "select must be one of 'lowest', got 'highest'",
        ),
        (
            lambda: realisations(example(), 2, np.random.default_rng(0), select=0.5),
            "select (target crest factor) must lie in [1, inf], got 0.5",
        ),
        (lambda: example().sample(0.0, 0.01), "duration must be > 0, got 0.0"),
        (lambda: example().sample(1.0, 0.0), "dt must be > 0, got 0.0"),
        (
            lambda: forcing_preset("vanderel"),
            "forcing preset must be one of 'vanderel-bw4', 'popovici2017', "
            "'schiess-roland1975', 'plaetinck2018', 'boer-kenyon1998', "
            "'boer-kenyon1998-postview', 'boer-kenyon1998-critical', got 'vanderel'",
        ),
        (
            lambda: forcing_preset("popovici2017", 5),
            "realisation must lie in [0, 4] for forcing preset 'popovici2017', got 5",
        ),
        (
            lambda: forcing_preset("plaetinck2018", -1),
            "realisation must lie in [0, 0] for forcing preset 'plaetinck2018', got -1",
        ),
        (lambda: preset_realisation_count("nope"), "forcing preset must be one of"),
        (lambda: SampledSignal([1.0], 0.01), "values must have at least 2 entries, got 1"),
        (lambda: SampledSignal([1.0, 2.0], -0.01), "dt must be > 0, got -0.01"),
        (
            lambda: SampledSignal([1.0, np.inf], 0.01),
            "values must be finite, found 1 infinite or NaN value(s)",
        ),
        (lambda: SampledSignal([1.0, 2.0], 0.01)(np.nan), "t must be finite"),
        (lambda: example()(np.array([0.0, np.nan])), "t must be finite"),
        (
            lambda: band_limited_noise(100, 0.01, 60.0, 1.0, np.random.default_rng(0)),
            "cutoff_hz must lie in [1, 50], got 60.0",
        ),
        (
            lambda: band_limited_noise(100, 0.01, 0.5, 1.0, np.random.default_rng(0)),
            "cutoff_hz must lie in [1, 50], got 0.5",
        ),
        (
            lambda: band_limited_noise(100, 0.01, 5.0, -1.0, np.random.default_rng(0)),
            "std must be >= 0, got -1.0",
        ),
        (
            lambda: ForcingPair(None, None, "x", -1),
            "realisation must be >= 0, got -1",
        ),
    ],
)
def test_bad_input_raises_value_error_with_message(build, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        build()


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (
            lambda: band_limited_noise(100, 0.01, 5.0, 1.0, np.random),
            "rng must be a numpy.random.Generator",
        ),
        (
            lambda: design_multisine(3, 10.0, 1.0, 1.0, 0.5, 5.0, 42),
            "rng must be a numpy.random.Generator (numpy.random.default_rng(seed)), got 42",
        ),
        (
            lambda: ForcingPair([1.0], None),
            "target must be a Multisine, a BandLimitedNoise or None, got [1.0]",
        ),
        (
            lambda: realisations([1.0], 2, np.random.default_rng(0)),
            "base must be a Multisine, got [1.0]",
        ),
        (lambda: ForcingPair(None, None, ""), "name must be a non-empty string, got ''"),
        (lambda: forcing_preset("plaetinck2018", 0.0), "realisation must be an integer, got 0.0"),
        (
            lambda: Multisine.from_dict({"kind": "multisine", "frequencies": [1.0], "amps": [1]}),
            "Multisine.from_dict got unknown key(s) 'amps'",
        ),
        (lambda: SampledSignal([1.0, 2.0], 0.1, periodic="yes"), "periodic must be True or False"),
    ],
)
def test_bad_types_raise_type_error_with_message(build, message):
    with pytest.raises(TypeError, match=re.escape(message)):
        build()


def test_multisine_from_dict_rejects_other_kinds():
    with pytest.raises(ValueError, match=re.escape("Multisine.from_dict kind must be one of")):
        Multisine.from_dict({"kind": "sine", "frequencies": [1.0]})
