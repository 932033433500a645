"""The real-time loop under a manual clock: the recording a stick gives, the schedule
and its timing figures, aborted runs, and a pilot flown through the play path giving
the very recording (and identification) of the pilot flown directly."""

import math

import gymnasium as gym
import numpy as np
import pytest

import manualcontrol.envs  # noqa: F401 - registers the environments
from manualcontrol.estimators import make_estimator
from manualcontrol.human.devices import DeviceAction, JoystickInput, ScriptedInput
from manualcontrol.human.realtime import (
    Clock,
    Flight,
    ManualClock,
    RealClock,
    RunAborted,
    Timing,
    fly,
)
from manualcontrol.pilots import Pilot

COMPENSATORY = "ManualControl/CompensatoryTracking-v0"
DT = 0.01


def compensatory(measurement_time=10.0, **options):
    return gym.make(COMPENSATORY, measurement_time=measurement_time, **options)


def stick_values(count, seed=0):
    rng = np.random.default_rng(seed)
    return np.clip(np.cumsum(rng.normal(0.0, 0.05, count)), -1.2, 1.2)


# ------------------------------------------------------------------ the recording


def test_a_scripted_stick_gives_its_values_through_the_action_scale():
    values = stick_values(1000)
    env = compensatory()
    flight = fly(env, ScriptedInput(values), clock=ManualClock(), render=False, seed=0)
    assert isinstance(flight, Flight)
    recording = flight.recording
    scale = flight.action_scale
    assert scale == pytest.approx(6.0)
    expected = DeviceAction(compensatory(), scale).action
    applied = np.array([expected([v])[0] for v in values])
    np.testing.assert_array_equal(recording.u, applied)  # bit for bit
    np.testing.assert_array_equal(recording.u, scale * np.clip(values, -1.0, 1.0))
    assert len(recording) == env.unwrapped.episode_steps == 1000
    np.testing.assert_array_equal(recording.t, env.unwrapped.times[:1000])
    np.testing.assert_allclose(np.diff(recording.t), DT, rtol=0, atol=1e-12)
    meta = recording.metadata
    assert dict(meta["input"]) == ScriptedInput(values).calibration
    assert dict(meta["action_scale"])["scale"] == scale
    assert meta["timing"]["steps"] == 1000
    assert meta["timing"]["clock"] == "ManualClock"
    assert meta["timing"]["good_enough_for_identification"] is True
    assert meta["task"] == "compensatory"  # the env's own description is kept
    assert flight.ended == "truncated"
    assert flight.good_enough_for_identification and flight.warning is None


def test_dead_zone_and_range_reach_the_recording():
    values = np.linspace(-2.0, 2.0, 200)
    device = ScriptedInput(values, range=1.6, dead_zone=0.1)
    flight = fly(compensatory(2.0), device, clock=ManualClock(), render=False, scale=2.0)
    x = np.clip(values / 1.6, -1.0, 1.0)
    shaped = np.where(np.abs(x) <= 0.1, 0.0, np.sign(x) * (np.abs(x) - 0.1) / 0.9)
    np.testing.assert_allclose(flight.recording.u, 2.0 * shaped, rtol=0, atol=1e-15)
    calibration = flight.recording.metadata["input"]
    assert (calibration["range"], calibration["dead_zone"]) == (1.6, 0.1)


def test_a_device_action_env_keeps_its_scale():
    env = DeviceAction(compensatory(1.0), scale=3.0)
    flight = fly(env, ScriptedInput(np.full(100, 0.5)), clock=ManualClock(), render=False)
    assert np.all(flight.recording.u == 1.5)
    with pytest.raises(ValueError, match=r"scale=4\.0 disagrees"):
        fly(env, ScriptedInput(np.zeros(100)), clock=ManualClock(), render=False, scale=4.0)


def test_max_steps_on_ready_and_on_step():
    seen, ready = [], []
    flight = fly(
        compensatory(),
        ScriptedInput(np.zeros(1000)),
        clock=ManualClock(),
        render=False,
        max_steps=25,
        on_ready=ready.append,
        on_step=seen.append,
    )
    assert len(flight.recording) == 25 and flight.ended == "max_steps"
    assert len(ready) == 1 and isinstance(ready[0], DeviceAction)
    assert [report.index for report in seen] == list(range(1, 26))
    assert seen[-1].info["t"] == pytest.approx(0.25)


def test_rgb_array_frames_are_drawn_each_step():
    frames = []
    fly(
        compensatory(render_mode="rgb_array"),
        ScriptedInput(np.zeros(3)),
        clock=ManualClock(),
        max_steps=3,
        on_step=lambda report: frames.append(report.frame.shape),
    )
    assert frames == [(400, 600, 3)] * 3


def test_loss_of_control_ends_the_flight():
    env = compensatory(30.0, controlled_element="critical-task")
    flight = fly(env, ScriptedInput(np.ones(3000)), clock=ManualClock(), render=False)
    assert flight.ended == "terminated"
    assert len(flight.recording) < 3000


def test_a_human_window_cannot_be_hidden_and_keeps_its_pacing_afterwards(pygame):
    env = compensatory(1.0, render_mode="human")
    with pytest.raises(ValueError, match="render=False needs an env made without"):
        fly(env, ScriptedInput(np.zeros(100)), clock=ManualClock(), render=False)
    fly(env, ScriptedInput(np.zeros(100)), clock=ManualClock())
    # the env's own frame pacing is back for use outside fly()
    assert isinstance(env.unwrapped._clock, pygame.time.Clock)
    env.close()


# ------------------------------------------------------------------ timing


def schedule(lateness, dt=DT):
    """Deadlines and starts by the documented rule, for lateness injected per step."""
    deadline, deadlines, starts = 0.0, [], []
    for late in lateness:
        start = deadline + late
        deadlines.append(deadline)
        starts.append(start)
        deadline = deadline + dt if late <= dt / 2 else start + dt
    return np.array(deadlines), np.array(starts)


def flown_with(lateness, steps=1000):
    return fly(
        compensatory(steps * DT),
        ScriptedInput(np.zeros(steps)),
        clock=ManualClock(lateness=list(lateness)),
        render=False,
    )


def test_injected_lateness_gives_the_timing_figures():
    rng = np.random.default_rng(7)
    lateness = rng.uniform(0.0, 0.002, 1000)
    late = rng.choice(1000, 8, replace=False)
    lateness[late] = rng.uniform(0.006, 0.03, 8)
    flight = flown_with(lateness)
    timing = flight.timing
    np.testing.assert_allclose(flight.lateness, lateness, rtol=0, atol=1e-12)
    assert timing.steps == 1000 and timing.late_steps == 8
    assert timing.max_lateness == pytest.approx(lateness.max(), abs=1e-12)
    assert timing.median_lateness == pytest.approx(np.median(lateness), abs=1e-12)
    assert timing.p99_lateness == pytest.approx(np.percentile(lateness, 99), abs=1e-12)
    _, starts = schedule(lateness)
    jitter = np.abs(np.diff(starts) - DT)
    assert timing.median_jitter == pytest.approx(np.median(jitter), abs=1e-12)
    assert timing.p99_jitter == pytest.approx(np.percentile(jitter, 99), abs=1e-12)
    assert timing.late_threshold == pytest.approx(0.005)
    # 0.8 % late and p99 within a step: good enough
    assert flight.good_enough_for_identification and flight.warning is None
    assert flight.recording.metadata["timing"] == timing.as_metadata()


def test_more_than_one_percent_late_steps_warns():
    lateness = np.zeros(1000)
    lateness[::50] = 0.007  # 20 steps, 2 %, each under a step
    flight = flown_with(lateness)
    assert flight.timing.late_steps == 20
    assert not flight.good_enough_for_identification
    assert "20 of 1000 steps (2.0 %) started more than half a step (5 ms) late" in flight.warning
    assert "99th percentile" not in flight.warning
    assert flight.recording.metadata["timing"]["good_enough_for_identification"] is False


def test_a_99th_percentile_beyond_a_step_warns():
    lateness = np.zeros(1000)
    lateness[100:111] = 0.025  # 11 steps 2.5 samples late
    flight = flown_with(lateness)
    assert flight.timing.p99_lateness > DT
    assert "the 99th percentile of lateness is 25 ms, more than one step (10 ms)" in (
        flight.warning
    )


def test_exactly_one_percent_is_still_good_enough():
    lateness = np.zeros(1000)
    lateness[::100] = 0.009
    assert flown_with(lateness).good_enough_for_identification


def test_a_late_step_slips_the_schedule_but_not_the_recording():
    small = np.zeros(50)
    small[3] = 0.004  # under half a step: absorbed by the grid
    clock = ManualClock(lateness=list(small))
    fly(compensatory(0.5), ScriptedInput(np.zeros(50)), clock=clock, render=False)
    assert clock.now() == pytest.approx(49 * DT + 0.0)
    large = np.zeros(50)
    large[3] = 0.03  # three samples late: later steps keep to a schedule moved by it
    clock = ManualClock(lateness=list(large))
    flight = fly(compensatory(0.5), ScriptedInput(np.zeros(50)), clock=clock, render=False)
    assert clock.now() == pytest.approx(49 * DT + 0.03)
    assert flight.timing.late_steps == 1
    np.testing.assert_allclose(flight.lateness[4:], 0.0, atol=1e-12)  # no rush to catch up
    assert len(flight.recording) == 50
    np.testing.assert_allclose(np.diff(flight.recording.t), DT, rtol=0, atol=1e-12)


def test_timing_of_frames_and_wall_time():
    timing = Timing.from_steps(
        0.01, [0.0, 0.01, 0.02], [0.001, 0.0105, 0.02], [0.002, 0.003, 0.004], "X"
    )
    assert timing.median_frame_time == pytest.approx(0.003)
    assert timing.max_frame_time == pytest.approx(0.004)
    assert timing.wall_time == pytest.approx(0.024)
    assert timing.median_jitter == pytest.approx(0.0005)
    assert "3 steps, 0 late" in timing.summary()


def test_clocks_follow_the_protocol():
    assert isinstance(RealClock(), Clock) and isinstance(ManualClock(), Clock)
    clock = RealClock()
    target = clock.now() + 0.002
    clock.sleep_until(target)
    # the upper bound catches a clock that oversleeps by whole frames, and leaves room
    # for a loaded machine's scheduling
    assert target <= clock.now() < target + 1.0
    manual = ManualClock(start=1.0, lateness=lambda i: 0.5 * i)
    manual.sleep_until(2.0)
    manual.sleep_until(2.5)
    assert manual.now() == 3.0 and manual.sleeps == 2
    manual.advance(0.25)
    assert manual.now() == 3.25
    with pytest.raises(ValueError, match="spin"):
        RealClock(spin=-1.0)


# ------------------------------------------------------------------ aborted runs


def test_closing_the_window_aborts_with_the_step_reached(pygame):
    env = compensatory(render_mode="human")

    def close_at_five(report):
        if report.index == 5:
            pygame.event.post(pygame.event.Event(pygame.QUIT))

    with pytest.raises(RunAborted) as error:
        fly(env, ScriptedInput(np.zeros(1000)), clock=ManualClock(), on_step=close_at_five)
    aborted = error.value
    assert aborted.reason == "the window was closed"
    assert (aborted.steps, aborted.total) == (5, 1000)
    assert aborted.elapsed == pytest.approx(0.05)
    assert len(aborted.recording) == 5
    assert "the window was closed at step 5 of 1000" in str(aborted)
    env.close()


def test_escape_aborts(pygame):
    env = compensatory(render_mode="human")

    def escape(report):
        pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_ESCAPE))

    with pytest.raises(RunAborted, match="Escape was pressed at step 1"):
        fly(env, ScriptedInput(np.zeros(1000)), clock=ManualClock(), on_step=escape)
    env.close()


def test_an_unplugged_joystick_aborts_with_the_reason(fake_joystick, pygame):
    env = compensatory(render_mode="human")

    def unplug_at_ten(report):
        if report.index == 10:
            pygame.event.post(pygame.event.Event(pygame.JOYDEVICEREMOVED, instance_id=7))

    with pytest.raises(RunAborted) as error:
        fly(env, JoystickInput(), clock=ManualClock(), on_step=unplug_at_ten)
    assert error.value.reason == "the joystick 'Test pad' was unplugged"
    assert error.value.steps == 10
    env.close()


# ------------------------------------------------------------------ the play path


def pilot_run(seed=1):
    """A precision pilot (remnant included) flying the env directly: its recording."""
    env = compensatory(90.0).unwrapped
    observation, _ = env.reset(seed=0)
    pilot = Pilot.typical("precision", "SI", remnant="popovici2017")
    pilot.reset(seed, env=env)
    done = False
    while not done:
        observation, _, terminated, truncated, _ = env.step(pilot.act(observation))
        done = terminated or truncated
    return env.recording()


def played(recording, scale=None):
    """The pilot's actions as stick events, flown through fly() on a fresh env."""
    env = DeviceAction(compensatory(90.0), scale)
    sticks = env.stick_for(recording.u)
    assert np.max(np.abs(sticks)) < 1.0  # within the stick's travel
    device = ScriptedInput(sticks)
    return fly(env, device, clock=ManualClock(), render=False, seed=0).recording


def final_estimates(recording):
    estimator = make_estimator({"name": "dekf", "model": "precision", "ce": "SI"})
    result = estimator.estimate(recording)
    return dict(zip(result.parameter_names, result.mean[-1], strict=True))


@pytest.fixture(scope="module")
def simulated():
    return pilot_run()


def test_the_play_path_adds_no_error_of_its_own(simulated):
    flown = played(simulated)
    assert len(flown) == len(simulated) == 9000
    for name in ("u", "e", "y", "ft", "fd", "t"):
        np.testing.assert_allclose(flown[name], simulated[name], rtol=0, atol=1e-12)
    # u = scale * (u / scale) is u to one rounding; the filter carries that ulp along
    # (5e-10 relative seen), far below any estimate's uncertainty
    ours, theirs = final_estimates(flown), final_estimates(simulated)
    for name, value in theirs.items():
        assert ours[name] == pytest.approx(value, rel=1e-7, abs=1e-12), name


def test_with_a_power_of_two_scale_the_played_run_is_the_simulated_one(simulated):
    flown = played(simulated, scale=8.0)
    for name in ("u", "e", "y"):
        np.testing.assert_array_equal(flown[name], simulated[name])
    assert final_estimates(flown) == final_estimates(simulated)
    assert all(math.isfinite(v) for v in final_estimates(flown).values())
