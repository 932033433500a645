"""Input devices: the one shaping path (range, stops, dead zone), each device's reading,
its calibration, the missing and the lost joystick, and the action a stick gives."""

import math
import sys

import gymnasium as gym
import numpy as np
import pytest

import manualcontrol.envs  # noqa: F401 - registers the environments
from manualcontrol.human.devices import (
    DEFAULT_DEAD_ZONE,
    KEYBOARD_RATE,
    DeviceAction,
    DeviceLost,
    InputDevice,
    JoystickInput,
    KeyboardInput,
    MouseInput,
    NoInputDevice,
    ScriptedInput,
    default_action_scale,
    load_pygame,
    make_device,
)

NO_JOYSTICK = (
    "no joystick or gamepad found (pygame sees 0); plug one in or use --input mouse/keyboard"
)


def compensatory(**options):
    return gym.make("ManualControl/CompensatoryTracking-v0", measurement_time=2.0, **options)


def read_all(device, env, count):
    device.open(env)
    return [device.read() for _ in range(count)]


# ------------------------------------------------------------------ shaping


def test_defaults_pass_the_stick_through_bit_for_bit():
    values = np.random.default_rng(3).uniform(-1.0, 1.0, 500)
    values[:3] = (0.0, -1.0, 1.0)
    device = ScriptedInput(values)
    assert read_all(device, compensatory(), 500) == values.tolist()


def test_range_and_dead_zone_map_as_documented():
    # range 2: raw 2 is full deflection; dead zone 0.1 of it; beyond, linear to the stop
    device = ScriptedInput([0.1, 0.2, 0.3, 1.1, -1.1, 2.0, 5.0, -3.0], range=2.0, dead_zone=0.1)
    got = read_all(device, compensatory(), 8)
    expected = [0.0, 0.0, (0.15 - 0.1) / 0.9, (0.55 - 0.1) / 0.9, -(0.55 - 0.1) / 0.9, 1, 1, -1]
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-15)
    # continuous at the edge of the dead zone, monotonic, odd
    half = np.linspace(0.0, 3.0, 301)
    raw = np.concatenate([-half[::-1], half])
    shaped = np.array([device.shape(r) for r in raw])
    assert np.all(np.diff(shaped) >= 0.0)
    np.testing.assert_array_equal(shaped, -shaped[::-1])
    assert device.shape(0.2 + 1e-9) == pytest.approx(0.0, abs=1e-8)


def test_the_shaping_is_the_same_for_every_device():
    scripted = ScriptedInput([0.0], range=0.8, dead_zone=0.2)
    joystick = JoystickInput(0, range=0.8, dead_zone=0.2)
    mouse = MouseInput(range=0.8, dead_zone=0.2)
    for raw in np.linspace(-1.0, 1.0, 41):
        assert scripted.shape(raw) == joystick.shape(raw) == mouse.shape(raw)


@pytest.mark.parametrize(
    ("keywords", "message"),
    [
        ({"range": 0.0}, "range must be a finite number > 0, got 0.0"),
        ({"range": math.inf}, "range must be a finite number > 0"),
        ({"dead_zone": 1.0}, "dead_zone must lie in [0, 1)"),
        ({"dead_zone": -0.1}, "dead_zone must lie in [0, 1)"),
    ],
)
def test_bad_calibration_is_refused(keywords, message):
    with pytest.raises(ValueError) as error:
        ScriptedInput([0.0], **keywords)
    assert message in str(error.value)


def test_a_script_must_be_finite_and_long_enough():
    with pytest.raises(ValueError, match="finite"):
        ScriptedInput([0.0, math.nan])
    device = ScriptedInput([0.5, 0.25])
    assert read_all(device, compensatory(), 2) == [0.5, 0.25]
    with pytest.raises(RuntimeError, match="ran out of values after 2 steps"):
        device.read()
    # opened again, it starts over
    assert read_all(device, compensatory(), 1) == [0.5]


def test_the_base_device_needs_a_reading():
    device = InputDevice()
    device.open(compensatory())
    with pytest.raises(NotImplementedError):
        device.read()


def test_calibration_states_device_range_and_dead_zone():
    calibration = ScriptedInput([0.0, 0.1], range=0.5, dead_zone=0.02).calibration
    assert calibration == {
        "device": "scripted",
        "name": "scripted",
        "axis": "scripted stick positions, one per step",
        "range": 0.5,
        "range_unit": "stick",
        "dead_zone": 0.02,
        "values": 2,
    }


# ------------------------------------------------------------------ devices


def test_keyboard_ramps_at_its_rate_and_springs_back(pygame):
    env = compensatory()
    device = KeyboardInput()
    device.open(env)
    step = KEYBOARD_RATE * 0.01
    device.handle_event(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_RIGHT))
    pushed = [device.read() for _ in range(40)]
    np.testing.assert_allclose(pushed[:3], [step, 2 * step, 3 * step])
    assert pushed[-1] == 1.0  # at the stop after 1/rate s
    device.handle_event(pygame.event.Event(pygame.KEYUP, key=pygame.K_RIGHT))
    released = [device.read() for _ in range(40)]
    assert released[0] == pytest.approx(1.0 - step)
    assert released[-1] == 0.0  # back at the centre, not past it
    device.handle_event(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_LEFT))
    assert device.read() == pytest.approx(-step)
    device.handle_event(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_RIGHT))
    assert device.read() == 0.0  # both held: back to the centre
    assert device.calibration["rate_per_s"] == KEYBOARD_RATE


def test_mouse_reads_the_horizontal_offset_from_the_window_centre(pygame, monkeypatch):
    grabs = []
    monkeypatch.setattr(pygame.event, "set_grab", grabs.append)
    env = compensatory(render_mode="human")
    env.reset(seed=0)  # opens the (dummy) 600 x 400 window
    device = MouseInput()
    device.open(env)
    assert device.range == 240.0  # 40 % of the width
    assert device.read() == 0.0  # starts at the centre
    device.handle_event(pygame.event.Event(pygame.MOUSEMOTION, pos=(420, 10), rel=(0, 0)))
    assert device.read() == 0.5
    device.handle_event(pygame.event.Event(pygame.MOUSEMOTION, pos=(0, 10), rel=(0, 0)))
    assert device.read() == -1.0  # beyond the range: the stop
    assert grabs == [True]  # the pointer stays in the window while flying
    device.close()
    assert grabs == [True, False]
    assert device.calibration["range_unit"] == "px"
    env.close()


def test_joystick_reads_its_axis_through_range_and_dead_zone(fake_joystick):
    fake_joystick.axes = [0.0, 0.03]
    device = JoystickInput(1, range=0.9)
    device.open(compensatory())
    assert device.read() == 0.0  # within the default dead zone
    fake_joystick.axes[1] = -0.9
    assert device.read() == -1.0
    fake_joystick.axes[1] = 0.45
    assert device.read() == pytest.approx((0.5 - DEFAULT_DEAD_ZONE) / (1 - DEFAULT_DEAD_ZONE))
    assert device.calibration == {
        "device": "joystick",
        "name": "Test pad",
        "axis": "axis 1",
        "range": 0.9,
        "range_unit": "axis value",
        "dead_zone": DEFAULT_DEAD_ZONE,
        "joystick_index": 0,
    }


def test_no_joystick_is_a_clear_error(no_joystick):
    with pytest.raises(NoInputDevice) as error:
        JoystickInput().open(compensatory())
    assert str(error.value) == NO_JOYSTICK


def test_a_missing_axis_is_a_clear_error(fake_joystick):
    with pytest.raises(NoInputDevice, match="'Test pad' has 2 axes"):
        JoystickInput(5).open(compensatory())


def test_unplugging_the_joystick_loses_it(fake_joystick, pygame):
    device = JoystickInput()
    device.open(compensatory())
    other = pygame.event.Event(pygame.JOYDEVICEREMOVED, instance_id=99)
    device.handle_event(other)  # another device: no matter
    with pytest.raises(DeviceLost, match="'Test pad' was unplugged"):
        device.handle_event(pygame.event.Event(pygame.JOYDEVICEREMOVED, instance_id=7))


def test_pygame_is_loaded_when_asked_and_its_absence_names_the_extra(monkeypatch):
    import pygame

    assert load_pygame() is pygame
    monkeypatch.setitem(sys.modules, "pygame", None)  # as if it were not installed
    with pytest.raises(gym.error.DependencyNotInstalled, match=r"manualcontrol\[render\]"):
        load_pygame()
    with pytest.raises(gym.error.DependencyNotInstalled, match="need pygame"):
        make_device("mouse").open(compensatory())


def test_make_device_by_input_name():
    assert isinstance(make_device("mouse"), MouseInput)
    assert isinstance(make_device("keyboard"), KeyboardInput)
    joystick = make_device("joystick", dead_zone=0.1, range=0.8, joystick_axis=2)
    assert (joystick.axis_index, joystick.dead_zone, joystick.range) == (2, 0.1, 0.8)
    with pytest.raises(ValueError, match="input must be one of mouse, keyboard, joystick"):
        make_device("trackball")
    with pytest.raises(ValueError, match="not the keyboard"):
        make_device("keyboard", range=2.0)


# ------------------------------------------------------------------ the action


def test_device_action_gives_scale_times_stick_in_a_stick_space():
    env = DeviceAction(compensatory(), scale=4.0)
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (1,), np.float64)
    assert env.action([0.25])[0] == 1.0
    assert env.action(np.array([3.0]))[0] == 4.0  # clipped at the stop
    assert env.action([-2.0])[0] == -4.0
    assert env.stick_for([2.0, -1.0]).tolist() == [0.5, -0.25]
    assert env.describe() == {"scale": 4.0, "rule": "given"}
    with pytest.raises(ValueError, match="stick must be finite"):
        env.action([math.nan])
    for bad in (0.0, -1.0, math.inf):
        with pytest.raises(ValueError, match="scale must be a finite number > 0"):
            DeviceAction(compensatory(), scale=bad)


def test_default_scales_follow_the_forcing_and_the_element():
    si, rule = default_action_scale(compensatory())
    assert si == pytest.approx(6.0)  # 3 std / |1.5/(3j)|
    assert "3 forcing std" in rule
    assert default_action_scale(compensatory(controlled_element="DI"))[0] == pytest.approx(5.4)
    # the popovici2017 lag element needs more than the bound: the bound
    scale, rule = default_action_scale(
        compensatory(controlled_element="popovici2017", forcing="popovici2017")
    )
    assert scale == 10.0 and "action bound" in rule
    lane = gym.make("ManualControl/LaneKeeping-v0", measurement_time=2.0)
    assert default_action_scale(lane)[0] == 10.0
    angle = gym.make("ManualControl/LaneKeeping-v0", measurement_time=2.0, steering="angle")
    assert default_action_scale(angle)[0] == 0.5


def test_a_pilot_and_a_stick_act_through_the_same_spaces():
    raw = compensatory()
    wrapped = DeviceAction(compensatory())
    assert wrapped.observation_space == raw.observation_space
    wrapped.reset(seed=0)
    raw.reset(seed=0)
    a = wrapped.step(wrapped.stick_for([1.5]))[0]
    b = raw.step(np.array([1.5]))[0]
    np.testing.assert_array_equal(a, b)
