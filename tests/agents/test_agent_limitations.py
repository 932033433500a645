"""The optimal control model's limitations as wrappers: schedules, scaled noise, effort, memory.

Each limitation is checked against an answer computed here by other means: the delayed
commands by interpolation, the neuromuscular filter by integrating its ODE, the noise
levels by their statistics over long runs, the effort cost by hand.
"""

import json
import re
import warnings

import gymnasium as gym
import numpy as np
import pytest
import scipy.integrate
from gymnasium.utils.env_checker import check_env

import manualcontrol.envs  # noqa: F401
from manualcontrol.agents.training import TrainingConfig, make_env
from manualcontrol.agents.wrappers import (
    ActionDelay,
    EffortCost,
    MotorNoise,
    NeuromuscularFilter,
    ObservationHistory,
    ObservationNoise,
    apply_wrappers,
)
from manualcontrol.envs.schedules import Ramp, Sigmoid, Sine, Step

DT = 0.01


def base(task="Compensatory", **kwargs):
    options = {"run_in": 0.0, "measurement_time": 5.0, **kwargs}
    return gym.make(f"ManualControl/{task}Tracking-v0", **options)


def run(env, commands, seed=0):
    """Step ``commands``; the reset observation, then each step's (observation, reward, info)."""
    first, reset_info = env.reset(seed=seed)
    steps = [env.step(np.array([command])) for command in commands]
    observations = np.array([first] + [step[0] for step in steps])
    rewards = np.array([step[1] for step in steps])
    return observations, rewards, [reset_info] + [step[4] for step in steps]


# ----------------------------------------------------------------------------- delay


def test_ramp_delay_reads_the_commands_at_t_minus_tau():
    # the run-in makes the env's time start at -1 s: the schedule runs on the env's clock
    delay = Ramp(start=0.05, end=0.3, t_start=-0.5, t_end=2.0)
    env = ActionDelay(base(run_in=1.0, measurement_time=3.0), delay)
    n = 400
    commands = np.random.default_rng(0).uniform(-1, 1, n)
    _, _, infos = run(env, commands)
    sticks = env.unwrapped.recording(include_run_in=True).u
    times = env.unwrapped.times[:n]
    assert times[0] == pytest.approx(-1.0)
    # c(t - tau(t)) with the commands joined linearly between samples, zero before the start
    expected = np.interp(np.arange(n) - delay(times) / DT, np.arange(n), commands, left=0.0)
    np.testing.assert_allclose(sticks, expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose([info["delay"] for info in infos[1:]], delay(times), atol=1e-15)


def test_rising_delay_keeps_a_queue_for_its_maximum():
    env = ActionDelay(base(measurement_time=30.0), Ramp(0.2, 0.3, 0.0, 20.0))
    assert env.observation_space.shape == (1 + 30,)  # ceil(0.3 / dt) queued commands
    observations, _, _ = run(env, [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(observations[-1][1:4], [0.3, 0.2, 0.1])  # newest first
    np.testing.assert_array_equal(observations[-1][4:], 0.0)


def test_a_schedule_given_as_its_dict_acts_as_the_schedule():
    commands = np.random.default_rng(1).uniform(-1, 1, 300)
    delay = Sine(mean=0.2, amplitude=0.05, period=1.0)
    as_object = ActionDelay(base(), delay)
    as_dict = apply_wrappers(base(), [{"kind": "action_delay", "delay": delay.to_dict()}])
    run(as_object, commands)
    run(as_dict, commands)
    np.testing.assert_array_equal(
        as_object.unwrapped.recording().u, as_dict.unwrapped.recording().u
    )


# ----------------------------------------------------------------- neuromuscular filter


def _filter_by_ode(commands, times, omega, zeta):
    """The stick of p' = v, v' = w^2 (c - p) - 2 z w v, integrated sample by sample.

    Command and parameters are held over each sample at their values at its start (the
    wrapper's definition); the stick over sample k is the position at its start.
    """
    x = np.zeros(2)
    sticks = []
    for k, command in enumerate(commands):
        sticks.append(x[0])
        w, z = omega(times[k]), zeta(times[k])

        def rhs(_, state, w=w, z=z, c=command):
            return [state[1], w * w * (c - state[0]) - 2.0 * z * w * state[1]]

        solution = scipy.integrate.solve_ivp(
            rhs, (times[k], times[k] + DT), x, method="DOP853", rtol=1e-12, atol=1e-14
        )
        x = solution.y[:, -1]
    return np.array(sticks)


@pytest.mark.parametrize(
    ("omega", "zeta"),
    [
        (Step(before=12.0, after=6.0, t_step=1.0), 0.35),  # omega_nms falls abruptly
        (Sigmoid(start=14.0, end=7.0, t_mid=1.0, transition_time=1.0), Ramp(0.3, 0.6, 0, 2)),
    ],
)
def test_scheduled_neuromuscular_filter_integrates_its_ode(omega, zeta):
    n = 250
    commands = np.random.default_rng(2).uniform(-1, 1, n)
    env = NeuromuscularFilter(base(), omega, zeta)
    run(env, commands)
    sticks = env.unwrapped.recording().u
    zeta_schedule = zeta if not isinstance(zeta, float) else (lambda t: zeta)
    reference = _filter_by_ode(commands, env.unwrapped.times, omega, zeta_schedule)
    # DOP853 at rtol 1e-12 per sample, 250 samples of a stable filter whose stick stays
    # below ~1.5: the accumulated integration error is a few 1e-11
    np.testing.assert_allclose(sticks, reference, rtol=0, atol=1e-9)


def test_a_step_in_omega_nms_moves_the_stick_on_without_a_jump():
    env = NeuromuscularFilter(base(), Step(12.0, 4.0, 1.0), 0.5)
    run(env, np.ones(200))
    sticks = env.unwrapped.recording().u
    jumps = np.abs(np.diff(sticks))
    assert jumps[99] < 2.0 * max(jumps[97], jumps[98])  # 1 s: only the dynamics change


# ------------------------------------------------------------------------------ noise


def _window_variance(values, size=500):
    """np.var of the last ``size`` values up to each sample (the samples so far early on)."""
    return np.array([np.var(values[max(0, k - size + 1) : k + 1]) for k in range(len(values))])


def _sine_run(env, n):
    """A slow sine on the stick for ``n`` steps: the observations, the clean error, the noise."""
    commands = 0.5 * np.sin(np.arange(n) * DT * 1.3)
    observations, _, infos = run(env, commands, seed=7)
    clean = np.array([info["e"] for info in infos])
    noise = np.array([0.0] + [info["observation_noise"][0] for info in infos[1:]])
    np.testing.assert_array_equal(observations[:, 0], clean + noise)
    return observations, clean, noise


def test_observation_noise_follows_a_doubling_ratio_of_the_signal_variance():
    ratio = Step(before=0.01, after=0.02, t_step=60.0)  # -20 dB, then -17 dB
    env = ObservationNoise(base(measurement_time=120.0), ratio=ratio)
    n = 12000
    observations, clean, noise = _sine_run(env, n)
    assert observations[0, 0] == clean[0]  # nothing to scale to yet
    # the OCM's intensity pi rho var per sample is the variance pi rho var / dt, so
    # noise^2 dt / (pi var) has the mean rho; noise^2 / (its variance) is chi-square(1):
    # over 5500 samples its mean has a standard deviation sqrt(2/5500) = 1.9 %; 8 % is four
    normalised = noise**2 * DT / (np.pi * _window_variance(clean)[: n + 1].clip(1e-300))
    t = env.unwrapped.times[: n + 1]
    for low, high, value in ((5.0, 60.0, 0.01), (65.0, 120.0, 0.02)):
        part = (t >= low) & (t < high)
        assert np.mean(normalised[part]) == pytest.approx(value, rel=0.08), (low, value)


def test_absolute_observation_noise_keeps_its_std():
    env = ObservationNoise(base("Pursuit", measurement_time=60.0), std=Step(0.05, 0.1, 30.0))
    observations, _, infos = run(env, np.zeros(6000), seed=3)
    noise = observations[1:] - np.array([[info["ft"], info["y"]] for info in infos[1:]])
    # 2 x 3000 Gaussian values per half: the sample std is within 1.3 % (1 sd); 5 % is ~4
    assert np.std(noise[:2999]) == pytest.approx(0.05, rel=0.05)
    assert np.std(noise[3000:]) == pytest.approx(0.1, rel=0.05)


def test_band_limited_observation_noise_keeps_the_white_noise_power_in_band():
    omega_r = 10.0
    white = ObservationNoise(base("Pursuit", measurement_time=600.0), std=0.1)
    band = ObservationNoise(base("Pursuit", measurement_time=600.0), std=0.1, omega_r=omega_r)
    n = 60000
    spectra = {}
    for name, env in (("white", white), ("band", band)):
        observations, _, infos = run(env, np.zeros(n), seed=5)
        noise = observations[1:, 0] - np.array([info["ft"] for info in infos[1:]])
        # std keeps its meaning: the noise's standard deviation (60,000 correlated
        # samples, about 950 independent ones at 10 rad/s: 2.3 %; 10 % is four)
        assert np.std(noise) == pytest.approx(0.1, rel=0.1), name
        segments = noise[: n // 100 * 100].reshape(100, -1)
        power = np.mean(np.abs(np.fft.rfft(segments, axis=1)) ** 2, axis=0) * DT / segments.shape[1]
        omega = 2 * np.pi * np.fft.rfftfreq(segments.shape[1], DT)
        spectra[name] = (omega, power)
        if name == "band":
            # the exact step's autocorrelation at one sample is exp(-omega_r dt)
            lag_one = np.corrcoef(noise[:-1], noise[1:])[0, 1]
            assert lag_one == pytest.approx(np.exp(-omega_r * DT), abs=0.01)
    omega, white_power = spectra["white"]
    band_power = spectra["band"][1]
    low = (omega > 0) & (omega < 2.0)
    # at the same std the densities are var dt (white) and 2 var / omega_r (first order,
    # V omega_r / 2 = var): the band-limited noise puts 2 / (omega_r dt) = 20 times more
    # of its power in band
    expected = 2.0 / (omega_r * DT)
    # 100 segments averaged, 2-3 bins below 2 rad/s: about 6 %; 20 % is three
    assert np.mean(band_power[low]) / np.mean(white_power[low]) == pytest.approx(expected, rel=0.2)
    high = omega > 100.0
    assert np.mean(band_power[high]) < 0.1 * np.mean(white_power[high])


def test_band_limited_ocm_noise_has_the_white_noise_intensity_in_band():
    # ratio mode: the same intensity pi rho var(y) below omega_r, its variance omega_r/2 of it
    ratio, omega_r = 0.01, 10.0
    env = ObservationNoise(base(measurement_time=120.0), ratio=ratio, omega_r=omega_r)
    n = 12000
    _, clean, noise = _sine_run(env, n)
    variance = _window_variance(clean)[: n + 1]
    t = env.unwrapped.times[: n + 1]
    part = t >= 5.0
    # the noise's variance over the signal's: pi rho omega_r / 2 (0.157), not pi rho / dt
    # (3.1); 115 s with a 0.1-s correlation time hold ~1,150 independent values: 4 %
    measured = np.mean(noise[part] ** 2) / np.mean(variance[part])
    assert measured == pytest.approx(np.pi * ratio * omega_r / 2.0, rel=0.15)


def test_motor_noise_follows_a_doubling_power_ratio():
    ratio = Step(before=0.15, after=0.3, t_step=60.0)
    env = MotorNoise(base(measurement_time=120.0), power_ratio=ratio, omega_r=30.0)
    n = 12000
    # a sine of 4 periods per 5-s variance window: the command variance is 0.5 throughout
    commands = np.sin(2.0 * np.pi * np.arange(n) * DT / 1.25)
    _, _, infos = run(env, commands, seed=4)
    noise = np.array([info["remnant"] for info in infos[1:]])
    t = env.unwrapped.times[:n]
    for low, high, value in ((5.0, 60.0, 0.15), (65.0, 120.0, 0.3)):
        part = (t >= low) & (t < high)
        measured = np.var(noise[part]) / (np.var(noise[part]) + np.var(commands[part]))
        # noise of 30 rad/s bandwidth over 55 s: its variance is known to about
        # sqrt(2 / (55 * 30)) = 3.5 %, the ratio to less; 12 % is 3.5 of those
        assert measured == pytest.approx(value, rel=0.12), (low, value)


def test_motor_noise_at_the_ocms_ratio_has_the_ocms_intensity():
    """``ratio`` is the OCM's rho_u: white noise of intensity pi rho_u var(command) per
    rad/s (as the OCM pilot's V_u), so through omega_r/(s + omega_r) its variance is
    (pi rho_u omega_r / 2) var(command): 5 % of the command's at -25 dB and 10 rad/s, not
    the 0.3 % that -25 dB read as a share of the power gives. A doubling ratio (a
    schedule) doubles it."""
    rho = Step(before=10**-2.5, after=2 * 10**-2.5, t_step=60.0)
    env = MotorNoise(base(measurement_time=120.0), ratio=rho, omega_r=10.0)
    assert env.ratio is rho and env.power_ratio is None
    n = 12000
    commands = np.sin(2.0 * np.pi * np.arange(n) * DT / 1.25)  # variance 0.5 per window
    _, _, infos = run(env, commands, seed=4)
    noise = np.array([info["remnant"] for info in infos[1:]])
    t = env.unwrapped.times[:n]
    for low, high, value in ((5.0, 60.0, 10**-2.5), (65.0, 120.0, 2 * 10**-2.5)):
        part = (t >= low) & (t < high)
        measured = np.var(noise[part]) / np.var(commands[part])
        # 10 rad/s noise over 55 s: its variance is known to about sqrt(2 / 550) = 6 %;
        # 20 % is over 3 of those, where the power-ratio reading is 16 times off
        assert measured == pytest.approx(np.pi * value * 10.0 / 2.0, rel=0.2), (low, value)


def test_white_motor_noise_at_the_ocms_ratio_has_the_ocms_intensity_below_the_sample_rate():
    """With ``omega_r=None`` the noise is white, held over each sample, of variance
    V_u / dt: below the sample rate its one-sided spectrum is the OCM's 2 V_u per Hz,
    V_u = pi rho_u var(command), which a limb inside the wrapper then shapes (the OCM's
    lag shapes its white v_u)."""
    import scipy.signal

    rho = 10**-2.5
    env = MotorNoise(base(measurement_time=300.0), ratio=rho, omega_r=None)
    assert env.omega_r is None
    n = 29990  # the episode's 30,000 steps but a few, for one more step below
    commands = np.sin(2.0 * np.pi * np.arange(n) * DT / 1.25)  # variance 0.5 per window
    _, _, infos = run(env, commands, seed=5)
    noise = np.array([info["remnant"] for info in infos[501:]])
    intensity = np.pi * rho * 0.5
    # 29,489 samples of one variance: known to about sqrt(2 / 29489) = 0.8 %
    assert np.var(noise) == pytest.approx(intensity / DT, rel=0.05)
    frequencies, spectrum = scipy.signal.welch(noise, fs=1.0 / DT, nperseg=2048)
    # white: flat at 2 V_u per Hz below 10 Hz (Welch over 28 segments: a few % each bin,
    # 5 % on the mean of 200 bins), where omega_r = 10 rad/s has fallen tenfold by 2.5 Hz
    band = (frequencies > 0.5) & (frequencies < 10.0)
    assert spectrum[band].mean() == pytest.approx(2.0 * intensity, rel=0.05)
    assert spectrum[frequencies > 25.0].mean() == pytest.approx(2.0 * intensity, rel=0.1)
    # the hidden state is the next sample's unit draw
    state = env.hidden_state()[0]
    *_, info = env.step(np.array([0.0]))
    assert info["remnant"] == pytest.approx(
        state * np.sqrt(np.pi * rho / DT * np.var(env._window)), rel=1e-12
    )


def test_motor_noise_at_an_absolute_level_does_not_follow_the_commands():
    """``std``: the noise's own spread, whatever the agent commands, so an agent cannot
    quieten it by commanding less (as it can a noise scaled to its commands)."""
    spreads = []
    for amplitude in (0.1, 1.0):
        env = MotorNoise(base(measurement_time=60.0), std=0.2, omega_r=10.0)
        commands = amplitude * np.sin(2.0 * np.pi * np.arange(6000) * DT / 1.25)
        _, _, infos = run(env, commands, seed=4)
        spreads.append(np.std([info["remnant"] for info in infos[501:]]))
    # 10 rad/s noise over 55 s: its spread is known to about 3 %
    np.testing.assert_allclose(spreads, 0.2, rtol=0.1)
    assert env.std == 0.2 and env.power_ratio is None and env.ratio is None


def test_motor_noise_takes_one_level():
    with pytest.raises(
        ValueError, match=re.escape("one level: a power_ratio (the noise's share of the stick's")
    ):
        MotorNoise(base(), power_ratio=0.1, ratio=0.003)
    with pytest.raises(ValueError, match=re.escape("got ratio=0.003 and std=0.1")):
        MotorNoise(base(), ratio=0.003, std=0.1)
    with pytest.raises(ValueError, match=re.escape("ratio must be >= 0, got -0.001")):
        MotorNoise(base(), ratio=-0.001)
    with pytest.raises(ValueError, match=re.escape("std must be >= 0, got -0.1")):
        MotorNoise(base(), std=-0.1)
    with pytest.raises(TypeError, match=r"omega_r must be a real number .*got 'white', or None"):
        MotorNoise(base(), ratio=0.003, omega_r="white")
    # the default level is a power ratio of 0.3, as before the other forms existed
    default = MotorNoise(base())
    assert default.power_ratio == 0.3 and default.ratio is None and default.std is None


def test_a_silenced_spec_zeroes_the_level_it_gives_and_leaves_the_unused_ones():
    from manualcontrol.agents.training import _silenced

    spec = {"kind": "motor_noise", "power_ratio": None, "ratio": 0.0032, "std": None}
    quiet = _silenced(spec)
    assert quiet == {"kind": "motor_noise", "power_ratio": None, "ratio": 0.0, "std": None}
    apply_wrappers(base(), [quiet])  # one level given, so it builds


def test_a_silenced_motor_noise_adds_nothing():
    """A noise-free evaluation sets the wrapper's own level to zero, whichever it is."""
    from manualcontrol.agents.training import _silenced

    for level in ("ratio", "std"):
        spec = {"kind": "motor_noise", level: 0.0032, "omega_r": 10.0}
        assert _silenced(spec) == {"kind": "motor_noise", level: 0.0, "omega_r": 10.0}
        env = apply_wrappers(base(), [_silenced(spec)])
        _, _, infos = run(env, np.sin(np.arange(300) * 0.05), seed=1)
        assert all(info["remnant"] == 0.0 for info in infos[1:])


def test_scheduled_stack_is_reproducible_per_seed():
    def episode(seed):
        env = apply_wrappers(
            base(measurement_time=3.0),
            [
                {"kind": "observation_noise", "ratio": Step(0.01, 0.02, 1.0)},
                {"kind": "neuromuscular", "omega_nms": Ramp(12.0, 8.0, 0.0, 3.0)},
                {"kind": "motor_noise", "power_ratio": Ramp(0.1, 0.2, 0.0, 3.0)},
                {"kind": "action_delay", "delay": Ramp(0.2, 0.3, 0.0, 3.0)},
                {"kind": "effort_cost", "rate_weight": 0.1},
                {"kind": "observation_history", "length": 3},
            ],
        )
        commands = np.sin(np.arange(300) * 0.05)
        observations, rewards, _ = run(env, commands, seed=seed)
        return observations, rewards

    first, again, other = episode(11), episode(11), episode(12)
    np.testing.assert_array_equal(first[0], again[0])
    np.testing.assert_array_equal(first[1], again[1])
    assert not np.array_equal(first[0], other[0])


# ----------------------------------------------------------------------------- effort


def test_effort_cost_is_the_normalised_stick_rate_and_stick_by_hand():
    commands = np.random.default_rng(5).uniform(-3, 3, 200)
    _, plain, _ = run(base(), commands)
    rate_weight = Step(before=0.3, after=0.6, t_step=1.0)
    _, rewards, infos = run(EffortCost(base(), rate_weight, stick_weight=0.05), commands)
    bound = 10.0  # the tracking env's default action_bound
    previous = np.concatenate([[0.0], commands[:-1]])
    weights = np.where(np.arange(200) * DT >= 1.0, 0.6, 0.3)
    effort = weights * ((commands - previous) / (bound * DT)) ** 2 + 0.05 * (commands / bound) ** 2
    np.testing.assert_allclose(rewards, plain - effort, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose([info["effort"] for info in infos[1:]], effort, rtol=1e-13)


def test_effort_cost_weighs_the_stick_that_moves_the_element():
    # outside a neuromuscular filter, the cost is on the filtered stick, not the command
    env = EffortCost(NeuromuscularFilter(base(), 10.0, 0.7), rate_weight=1.0)
    _, _, infos = run(env, np.ones(50))
    sticks = env.unwrapped.recording().u
    rates = np.diff(np.concatenate([[0.0], sticks])) / (10.0 * DT)
    np.testing.assert_allclose([info["effort"] for info in infos[1:]], rates**2, rtol=1e-12)
    assert infos[1]["effort"] == 0.0  # the arm has not moved over the first sample


def test_effort_cost_on_the_commanded_stick_leaves_the_motor_noise_out():
    """``stick="commanded"``: the cost on the stick before the motor noise (here the
    limb's output, the noise joining after it), so the noise's rate, which the agent
    cannot change, stays out of its reward; on the applied stick it is in."""
    limb_then_noise = NeuromuscularFilter(MotorNoise(base(), std=0.3, omega_r=10.0), 10.0, 0.7)
    commanded = EffortCost(limb_then_noise, rate_weight=1.0, stick="commanded")
    commands = np.sin(np.arange(300) * 0.05)
    _, _, infos = run(commanded, commands, seed=3)
    # the limb's output: what the applied stick is with the noise taken out
    limb = np.array([info["u"] - info["remnant"] for info in infos[1:]])
    before = np.array([info["stick_before_noise"] for info in infos[1:]])
    np.testing.assert_allclose(before, limb, rtol=0, atol=1e-12)  # (a + n) - n: rounding
    limb = before
    assert not np.allclose(limb, commands)  # the limb's output, not the raw command
    rates = np.diff(np.concatenate([[0.0], limb])) / (10.0 * DT)
    np.testing.assert_allclose([info["effort"] for info in infos[1:]], rates**2, rtol=1e-12)
    applied = EffortCost(
        NeuromuscularFilter(MotorNoise(base(), std=0.3, omega_r=10.0), 10.0, 0.7),
        rate_weight=1.0,
    )
    _, _, noisy = run(applied, commands, seed=3)
    # the same episode: the noise's rate is most of the applied stick's cost
    assert sum(i["effort"] for i in noisy[1:]) > 10 * sum(i["effort"] for i in infos[1:])
    for without_noise in (base(), NeuromuscularFilter(base(), 10.0, 0.7)):
        with pytest.raises(TypeError, match=re.escape("a MotorNoise wrapped inside sets")):
            run(EffortCost(without_noise, rate_weight=1.0, stick="commanded"), commands[:2])
    with pytest.raises(ValueError, match="stick must be one of"):
        EffortCost(base(), rate_weight=1.0, stick="noisy")


# ---------------------------------------------------------------------------- history


def test_observation_history_stacks_the_latest_observations_newest_first():
    env = ObservationHistory(ActionDelay(base(), 0.02), length=3)
    assert env.observation_space.shape == (9,)
    observations, _, infos = run(env, [0.1, 0.2, 0.3])
    errors = [info["e"] for info in infos]
    first = [errors[0], 0.0, 0.0]
    np.testing.assert_array_equal(observations[0], first * 3)  # padded with the first
    np.testing.assert_array_equal(
        observations[3], [errors[3], 0.3, 0.2, errors[2], 0.2, 0.1, errors[1], 0.1, 0.0]
    )


def test_full_stack_with_schedules_passes_check_env():
    env = apply_wrappers(
        base("Preview", available_preview=0.3),
        [
            {"kind": "observation_noise", "ratio": 0.01},
            {"kind": "neuromuscular", "omega_nms": Ramp(12.0, 8.0, 0.0, 5.0)},
            {"kind": "action_delay", "delay": Ramp(0.2, 0.3, 0.0, 5.0)},
            {"kind": "motor_noise", "power_ratio": 0.003},
            {"kind": "effort_cost", "rate_weight": 0.1},
            {"kind": "observation_history", "length": 2},
        ],
    )
    assert env.observation_space.shape == (2 * (31 + 1 + 2 + 30),)
    with warnings.catch_warnings():
        warnings.filterwarnings(
            "ignore", message=".*(normalized space|infinity|unwrapped version).*"
        )
        check_env(env, skip_render_check=True)


# -------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("build", "error", "message"),
    [
        (
            lambda: ActionDelay(base(), Ramp(0.2, -0.1, 0.0, 4.0)),
            ValueError,
            "delay must lie in [0, 2], got -0.1 at t = 4 s of the schedule "
            "ramp(0.2 -> -0.1 from 0 to 4 s)",
        ),
        (
            lambda: NeuromuscularFilter(base(), omega_nms=Sine(5.0, 8.0, 4.0)),
            ValueError,
            "omega_nms must be > 0, got -3.0 at t = 3 s of the schedule sine(",
        ),
        (
            lambda: MotorNoise(base(), power_ratio=Ramp(0.5, 1.0, 0.0, 2.0)),
            ValueError,
            "power_ratio must lie in [0, 1), got 1.0 at t = 2 s",
        ),
        (
            lambda: ObservationNoise(base(), ratio=Step(0.01, -0.01, 1.0)),
            ValueError,
            "ratio must be >= 0, got -0.01 at t = 1 s",
        ),
        (
            lambda: ObservationNoise(base(), ratio=0.01, std=0.1),
            ValueError,
            "give ObservationNoise a ratio (scaled to the signal) or a std (absolute), not both",
        ),
        (
            lambda: ObservationNoise(base(), ratio=0.01, omega_r=0.0),
            ValueError,
            "omega_r must be > 0, got 0.0",
        ),
        (
            lambda: ObservationNoise(base(), 0.05),
            TypeError,
            "takes 2 positional arguments but 3 were given",
        ),
        (
            lambda: EffortCost(base(), rate_weight=-1.0),
            ValueError,
            "rate_weight must be >= 0, got -1.0",
        ),
        (
            lambda: ActionDelay(base(), "0.2"),
            TypeError,
            "delay must be a real number or a schedule (manualcontrol.envs.schedules), got '0.2'",
        ),
        (
            lambda: ActionDelay(base(), {"kind": "ramp", "start": 0.2}),
            TypeError,
            "delay: Ramp.from_dict is missing key(s) end, t_start, t_end",
        ),
        (
            lambda: ObservationHistory(base(), length=0),
            ValueError,
            "length must be >= 1, got 0",
        ),
    ],
)
def test_bad_limitations_are_rejected(build, error, message):
    with pytest.raises(error, match=re.escape(message)):
        build()


# ---------------------------------------------------------------------- configuration


def scheduled_config():
    return TrainingConfig(
        env_kwargs={"measurement_time": 5.0},
        wrappers=(
            {"kind": "action_delay", "delay": Ramp(0.2, 0.3, 0.0, 20.0)},
            {"kind": "neuromuscular", "omega_nms": Sigmoid(12.0, 8.0, 2.0, 2.0)},
        ),
        observation_noise_ratio=Step(0.01, 0.02, 2.5),
        effort_rate_weight=0.1,
        history_length=4,
    )


def test_configuration_round_trip_keeps_the_schedules():
    config = scheduled_config()
    data = json.loads(json.dumps(config.to_dict()))
    assert data["observation_noise_ratio"] == {
        "kind": "step",
        "before": 0.01,
        "after": 0.02,
        "t_step": 2.5,
    }
    assert data["wrappers"][0]["delay"]["kind"] == "ramp"
    again = TrainingConfig.from_dict(data)
    assert again == config and again.to_dict() == data
    assert again.observation_noise_ratio == Step(0.01, 0.02, 2.5)
    assert [spec["kind"] for spec in again.limitations] == [
        "observation_noise",
        "action_delay",
        "neuromuscular",
        "effort_cost",
        "observation_history",
    ]
    env = make_env(again)
    # the queue holds the largest delay of the 5-s episode, 0.225 s: 23 commands
    assert env.observation_space.shape == (4 * (1 + 23 + 2),)


def test_an_older_config_loads_with_the_limitations_off():
    old = {  # a config.json written before the OCM fields existed
        "task": "compensatory",
        "env_kwargs": {"measurement_time": 5.0},
        "wrappers": [{"kind": "action_delay", "delay": 0.2}],
        "algorithm": "sac",
        "total_timesteps": 300,
        "n_envs": 1,
        "seed": 0,
        "algorithm_kwargs": {},
        "policy_kwargs": {},
        "checkpoint_every": None,
    }
    config = TrainingConfig.from_dict(old)
    assert config.limitations == ({"kind": "action_delay", "delay": 0.2},)
    assert not config.deterministic
    env = make_env(config)
    reference = ActionDelay(base(), 0.2)
    assert env.observation_space == reference.observation_space
    commands = np.sin(np.arange(100) * 0.1)
    np.testing.assert_array_equal(run(env, commands)[0], run(reference, commands)[0])


def test_noise_free_environment_for_deterministic_evaluation():
    config = TrainingConfig(
        env_kwargs={"measurement_time": 5.0},
        wrappers=({"kind": "motor_noise", "power_ratio": 0.3},),
        observation_noise_ratio=0.01,
        deterministic=True,
    )
    commands = np.sin(np.arange(200) * 0.05)
    quiet, _, infos = run(make_env(config, noise=False), commands)
    np.testing.assert_array_equal(quiet[:, 0], [info["e"] for info in infos])
    assert all(info["remnant"] == 0.0 for info in infos[1:])
    noisy, _, _ = run(make_env(config), commands)
    assert not np.array_equal(noisy, quiet)


@pytest.mark.parametrize(
    ("kwargs", "error", "message"),
    [
        (
            {
                "observation_noise_ratio": 0.01,
                "wrappers": ({"kind": "observation_noise", "std": 0.1},),
            },
            ValueError,
            "observation_noise_ratio and a wrappers entry of kind 'observation_noise'",
        ),
        (
            {"observation_noise_ratio": -0.01},
            ValueError,
            "observation_noise_ratio must be >= 0, got -0.01",
        ),
        (
            {"effort_rate_weight": "high"},
            TypeError,
            "effort_rate_weight must be a real number or a schedule, got 'high'",
        ),
        ({"history_length": 0}, ValueError, "history_length must be >= 1, got 0"),
        ({"deterministic": "yes"}, TypeError, "deterministic must be True or False"),
        (
            {"wrappers": ({"kind": "action_delay", "delay": Ramp(0.2, 2.5, 0.0, 1.0)},)},
            ValueError,
            "delay must lie in [0, 2], got 2.5 at t = 1 s",
        ),
    ],
)
def test_bad_limitation_fields_fail_before_training(kwargs, error, message):
    with pytest.raises(error, match=re.escape(message)):
        TrainingConfig(env_kwargs={"measurement_time": 2.0}, **kwargs)


def test_a_delay_ramp_ending_on_a_whole_sample_stays_inside_its_queue():
    # 0.2 -> 0.3 s at 100 Hz: values a hair above 30 samples once asked for a 31st
    env = ActionDelay(
        gym.make("ManualControl/CompensatoryTracking-v0", measurement_time=80.0, run_in=30.0),
        Ramp(0.2, 0.3, 30.0, 50.0),
        observe_queue=False,
    )
    env.reset(seed=0)
    commands = np.sin(np.arange(11000) * 0.01)
    for command in commands:
        _, _, _, _, info = env.step(np.array([command]))
    assert info["delay"] == pytest.approx(0.3)
    assert info["u"] == pytest.approx(commands[-31], abs=1e-9)
