"""Input devices a person flies a task with, and the action they give the environment.

Every device reports one stick position in ``[-1, 1]``, sampled once per step by
:func:`~manualcontrol.human.realtime.fly`, through one shaping path
(:meth:`InputDevice.shape`) so that a scripted stick and a real one are treated alike:

1. the raw reading (mouse pixels from the window's centre, a joystick axis value, a
   scripted number) is divided by the device's calibrated ``range``, the raw value that
   gives full deflection;
2. the result is clipped to ``[-1, 1]``: a hand cannot push a stick past its stop;
3. a dead zone ``d`` sets ``|x| <= d`` to zero and maps the rest linearly onto the
   remaining travel, ``sign(x) (|x| - d) / (1 - d)``, so the stick is continuous at the
   edge of the dead zone and full deflection still gives 1.

With ``range=1`` and no dead zone the path is the identity, bit for bit.

==================  ==================================================================
device              raw reading
==================  ==================================================================
:class:`Mouse       horizontal position of the pointer (px) from the window's centre;
Input`              full deflection by default 40 % of the window's width from the
                    centre (240 px of 600), where the display puts three forcing
                    standard deviations: the hand moves about as far as the marker
:class:`Keyboard    left/right arrows drive the stick at :data:`KEYBOARD_RATE` per
Input`              second towards the stop; released, it returns to the centre at
                    the same rate (a spring-centred stick)
:class:`Joystick    one axis of a joystick or gamepad (pygame's ``[-1, 1]``); dead zone
Input`              by default 0.05 against the drift of a sprung stick at rest
:class:`Scripted    a sequence of stick positions, one per step: tests, and a model's
Input`              output fed as stick events through the same path a person's takes
==================  ==================================================================

A device's :attr:`~InputDevice.calibration` (device, name, axis, range and its unit,
dead zone) is stored in the recording's metadata (``"input"``), so a run says how its
stick was read.

:class:`DeviceAction` turns the stick into the environment's action: full deflection
gives ``scale`` action units (:func:`default_action_scale` chooses one per environment
and says why). A person, a pilot model and an RL agent then act through the same
observation and action spaces: the wrapped environment's action space is the stick's,
``Box(-1, 1, (1,))``.

pygame is imported only when a device that needs it is opened (:func:`load_pygame`,
``pip install 'manualcontrol[render]'``); :class:`ScriptedInput` needs none.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterable, Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

__all__ = [
    "CROSSOVER_FREQUENCY",
    "DEFAULT_DEAD_ZONE",
    "FORCING_HEADROOM",
    "KEYBOARD_RATE",
    "MOUSE_RANGE_FRACTION",
    "DeviceAction",
    "DeviceLost",
    "InputDevice",
    "InputDeviceError",
    "JoystickInput",
    "KeyboardInput",
    "MouseInput",
    "NoInputDevice",
    "ScriptedInput",
    "default_action_scale",
    "draw_stick_gauge",
    "joystick_count",
    "load_pygame",
    "make_device",
]

FloatArray = NDArray[np.float64]

#: Stick travel per second while an arrow key is held (and back to the centre once it
#: is released): full deflection in 1/3 s. Of the order of a person's own response
#: time (0.2-0.3 s), so the ramp does not slow a response down much, yet slow enough
#: that the length of a key press grades the stick instead of slamming it to a stop.
KEYBOARD_RATE = 3.0
#: Default dead zone of a joystick axis, as a fraction of full deflection: a sprung
#: stick or gamepad at rest reads a few percent off zero, and that drift would be
#: flown as a steady input.
DEFAULT_DEAD_ZONE = 0.05
#: Mouse full deflection, as a fraction of the window's width measured from its centre
#: (the tracking displays draw three forcing standard deviations at 40 % of the width).
MOUSE_RANGE_FRACTION = 0.4
#: Crossover frequency (rad/s) at which :func:`default_action_scale` reads the
#: controlled element: people cross over at about 2-5 rad/s on these elements.
CROSSOVER_FREQUENCY = 3.0
#: Forcing standard deviations full deflection covers (see :func:`default_action_scale`).
FORCING_HEADROOM = 3.0
# lane keeping: full deflection about twice the peak action of the nominal cybernetic
# driver on the zhao2019 road (4.9 N m of torque, 0.23 rad of wheel angle)
_LANE_KEEPING_SCALE = {"torque": 10.0, "angle": 0.5}
_DEVICES = ("mouse", "keyboard", "joystick")
# width (px) of every display of this package, for a mouse opened without a window
_DISPLAY_WIDTH = 600


class InputDeviceError(RuntimeError):
    """A problem with an input device; see :class:`NoInputDevice` and :class:`DeviceLost`."""


class NoInputDevice(InputDeviceError):  # noqa: N818 - reads as what happened
    """The requested device is not there (no joystick plugged in, say)."""


class DeviceLost(InputDeviceError):  # noqa: N818 - reads as what happened
    """The device went away during a run (a joystick unplugged)."""


def load_pygame() -> Any:
    """The ``pygame`` module, imported on first use.

    pygame is optional (the ``render`` extra, ``pip install 'manualcontrol[render]'``):
    the devices that read a mouse, keyboard or joystick and the session's screens call
    this when they open, so that importing this package needs none. Raises
    ``gymnasium.error.DependencyNotInstalled`` when pygame is not installed.
    """
    try:
        import pygame
    except ImportError as error:  # pragma: no cover - pygame is a dev dependency
        raise gym.error.DependencyNotInstalled(
            "input devices need pygame: pip install 'manualcontrol[render]'"
        ) from error
    return pygame


def draw_stick_gauge(surface: Any, stick: float) -> None:
    """Draw the stick's gauge along the bottom of ``surface`` (a pygame surface).

    A grey bar 60 px in from each side with a tick at the centre, and a blue dot at
    ``stick`` (``[-1, 1]``, full deflection at the bar's ends): what the start and
    instruction screens show while the mouse or joystick is centred. The caller
    flips the display.
    """
    pygame = load_pygame()
    width, height = surface.get_size()
    row = height - 30
    pygame.draw.line(surface, (150, 150, 150), (60, row), (width - 60, row), 2)
    pygame.draw.line(surface, (150, 150, 150), (width // 2, row - 8), (width // 2, row + 8))
    x = width // 2 + stick * (width // 2 - 60)
    pygame.draw.circle(surface, (80, 200, 255), (int(x), row), 7)


def _check_range(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"range must be a number > 0, got {value!r}")
    value = float(value)
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"range must be a finite number > 0, got {value!r}")
    return value


def _check_dead_zone(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"dead_zone must be a number in [0, 1), got {value!r}")
    value = float(value)
    if not 0.0 <= value < 1.0:
        raise ValueError(
            f"dead_zone must lie in [0, 1) (a fraction of full deflection), got {value!r}"
        )
    return value


class InputDevice:
    """A stick read once per step, shaped to ``[-1, 1]`` (see the module docstring).

    Subclasses give :meth:`_raw` (the reading in device units) and may react to the
    pygame events :func:`~manualcontrol.human.realtime.fly` pumps each step
    (:meth:`handle_event`). Use: ``open(env)``, then ``read()`` once per step, then
    ``close()``.

    Parameters
    ----------
    range
        Raw reading that gives full deflection (> 0), in the device's unit.
    dead_zone
        Fraction of full deflection read as zero, in ``[0, 1)``.
    """

    #: Short name of the kind of device, as ``--input`` spells it.
    kind: str = "device"
    #: Unit of the raw reading and of :attr:`range`.
    unit: str = ""
    #: What is read.
    axis: str = ""

    def __init__(self, *, range: float = 1.0, dead_zone: float = 0.0) -> None:
        self.range = _check_range(range)
        self.dead_zone = _check_dead_zone(dead_zone)
        self.name = self.kind
        self.dt: float | None = None

    def open(self, env: gym.Env) -> None:
        """Get ready to fly ``env`` (its window, if any, is open by now)."""
        self.dt = float(env.unwrapped.dt)

    def handle_event(self, event: Any) -> None:
        """React to one pygame event of this step; may raise :class:`DeviceLost`."""

    def read(self) -> float:
        """The stick now, in ``[-1, 1]``; called once per step."""
        return self.shape(self._raw())

    def _raw(self) -> float:
        raise NotImplementedError

    def shape(self, raw: float) -> float:
        """``raw`` through range, stop and dead zone (the one path of every device)."""
        x = float(raw) / self.range
        if x != x:
            raise ValueError(f"{self.kind} gave a stick reading that is not a number: {raw!r}")
        x = 1.0 if x > 1.0 else -1.0 if x < -1.0 else x
        d = self.dead_zone
        magnitude = abs(x)
        if magnitude <= d:
            return 0.0
        return math.copysign((magnitude - d) / (1.0 - d), x)

    @property
    def calibration(self) -> dict[str, Any]:
        """How the stick is read, for the recording's metadata (JSON-able)."""
        return {
            "device": self.kind,
            "name": self.name,
            "axis": self.axis,
            "range": self.range,
            "range_unit": self.unit,
            "dead_zone": self.dead_zone,
        }

    def close(self) -> None:
        """Release the device; :meth:`open` may be called again for another run."""

    def __repr__(self) -> str:
        return f"{type(self).__name__}(range={self.range!r}, dead_zone={self.dead_zone!r})"


class ScriptedInput(InputDevice):
    """Stick positions given in advance, one per step: for tests and models' outputs.

    The values go through the same shaping as a real device's readings (range, stop,
    dead zone; with the defaults the identity), so a scripted run tests the play path
    end to end. Reading past the end raises ``RuntimeError``: a script shorter than
    the run is a mistake, not a stick at rest.

    Parameters
    ----------
    values
        The raw stick positions, one per step (finite numbers).
    range, dead_zone
        As for :class:`InputDevice` (defaults 1 and 0).
    name
        Name stated in the calibration (default ``"scripted"``).
    """

    kind = "scripted"
    unit = "stick"
    axis = "scripted stick positions, one per step"

    def __init__(
        self,
        values: Iterable[float],
        *,
        range: float = 1.0,
        dead_zone: float = 0.0,
        name: str = "scripted",
    ) -> None:
        super().__init__(range=range, dead_zone=dead_zone)
        array = np.asarray(values if isinstance(values, np.ndarray) else list(values), float)
        if array.ndim != 1:
            raise ValueError(f"values must be one stick position per step (1-D), got {array.shape}")
        if not np.all(np.isfinite(array)):
            raise ValueError("values must be finite stick positions")
        self.values = array.tolist()
        self.name = str(name)
        self.position = 0

    def open(self, env: gym.Env) -> None:
        """Start again from the first value."""
        super().open(env)
        self.position = 0

    def _raw(self) -> float:
        i = self.position
        if i >= len(self.values):
            raise RuntimeError(f"ScriptedInput ran out of values after {len(self.values)} steps")
        self.position = i + 1
        return self.values[i]

    @property
    def calibration(self) -> dict[str, Any]:  # noqa: D102
        return {**super().calibration, "values": len(self.values)}

    def __repr__(self) -> str:
        return (
            f"ScriptedInput({len(self.values)} values, range={self.range!r}, "
            f"dead_zone={self.dead_zone!r})"
        )


class MouseInput(InputDevice):
    """The pointer's horizontal position in the window, from its centre.

    The position follows pygame's ``MOUSEMOTION`` events. While flying, the pointer is
    hidden and kept inside the window (pygame's grab), so the hand cannot leave the
    display and leave the stick at its last position; it starts at the centre (stick
    zero). Press Escape to abort a run: the grab keeps the pointer off the window's
    close button.

    Parameters
    ----------
    range
        Pixels from the centre for full deflection; default :data:`MOUSE_RANGE_FRACTION`
        of the window's width (240 px of the 600-px displays).
    dead_zone
        Default 0: a mouse rests where it is put.
    grab
        Hide the pointer and keep it in the window while flying (default True).
    """

    kind = "mouse"
    unit = "px"
    axis = "horizontal position from the window's centre"

    def __init__(
        self, *, range: float | None = None, dead_zone: float = 0.0, grab: bool = True
    ) -> None:
        super().__init__(range=1.0 if range is None else range, dead_zone=dead_zone)
        self._range_given = range is not None
        self.grab = bool(grab)
        self.centre = 0.0
        self.x = 0.0
        self._grabbed = False

    def open(self, env: gym.Env) -> None:
        """Find the window's centre, put the pointer there and (by default) grab it."""
        super().open(env)
        pygame = load_pygame()
        surface = pygame.display.get_surface() if pygame.display.get_init() else None
        width = surface.get_width() if surface is not None else _DISPLAY_WIDTH
        self.centre = width / 2.0
        self.x = self.centre
        if not self._range_given:
            self.range = MOUSE_RANGE_FRACTION * width
        if surface is not None:
            pygame.mouse.set_pos((int(self.centre), surface.get_height() // 2))
            if self.grab:
                pygame.event.set_grab(True)
                pygame.mouse.set_visible(False)
                self._grabbed = True

    def handle_event(self, event: Any) -> None:  # noqa: D102
        pygame = load_pygame()
        if event.type == pygame.MOUSEMOTION:
            self.x = float(event.pos[0])

    def _raw(self) -> float:
        return self.x - self.centre

    def close(self) -> None:
        """Release the pointer."""
        if self._grabbed:
            pygame = load_pygame()
            if pygame.display.get_init():
                pygame.event.set_grab(False)
                pygame.mouse.set_visible(True)
            self._grabbed = False


class KeyboardInput(InputDevice):
    """Left and right arrows push the stick at a rate; released, it springs back.

    Each step the stick moves ``rate * dt`` towards the stop of the arrow held (both
    or none held: back towards the centre at the same rate, not past it). A key gives
    only on or off; ramping turns how long it is held into a graded stick, as a
    rate-limited stick would. See :data:`KEYBOARD_RATE` for the default rate.

    Parameters
    ----------
    rate
        Stick travel per second (full deflection is 1), > 0.
    dead_zone
        Default 0.
    """

    kind = "keyboard"
    unit = "stick"
    axis = "left/right arrow keys, ramped"

    def __init__(self, *, rate: float = KEYBOARD_RATE, dead_zone: float = 0.0) -> None:
        super().__init__(range=1.0, dead_zone=dead_zone)
        if isinstance(rate, bool) or not isinstance(rate, numbers.Real) or not rate > 0.0:
            raise ValueError(f"rate must be a number > 0 (stick travel per second), got {rate!r}")
        if not math.isfinite(rate):
            raise ValueError(f"rate must be finite, got {rate!r}")
        self.rate = float(rate)
        self.left = False
        self.right = False
        self.position = 0.0

    def open(self, env: gym.Env) -> None:  # noqa: D102
        super().open(env)
        self.left = self.right = False
        self.position = 0.0

    def handle_event(self, event: Any) -> None:  # noqa: D102
        pygame = load_pygame()
        if event.type in (pygame.KEYDOWN, pygame.KEYUP):
            pressed = event.type == pygame.KEYDOWN
            if event.key == pygame.K_LEFT:
                self.left = pressed
            elif event.key == pygame.K_RIGHT:
                self.right = pressed

    def _raw(self) -> float:
        step = self.rate * (self.dt if self.dt is not None else 0.01)
        direction = int(self.right) - int(self.left)
        x = self.position
        if direction:
            x = min(max(x + direction * step, -1.0), 1.0)
        elif x > 0.0:
            x = max(x - step, 0.0)
        else:
            x = min(x + step, 0.0)
        self.position = x
        return x

    @property
    def calibration(self) -> dict[str, Any]:  # noqa: D102
        return {**super().calibration, "rate_per_s": self.rate}


def joystick_count() -> int:
    """How many joysticks and gamepads pygame sees now."""
    pygame = load_pygame()
    pygame.joystick.init()
    return int(pygame.joystick.get_count())


class JoystickInput(InputDevice):
    """One axis of a joystick or gamepad.

    Calibration is explicit, and stored in the recording: ``range`` is the axis value
    that gives full deflection (1, or less for a stick that does not reach its
    nominal end), ``dead_zone`` the fraction around the centre read as zero. Unplugging
    the device during a run raises :class:`DeviceLost` (pygame's
    ``JOYDEVICEREMOVED``); opening it when none is plugged in raises
    :class:`NoInputDevice`.

    Parameters
    ----------
    axis
        Axis index (0 is usually the left stick's horizontal axis).
    dead_zone
        Default :data:`DEFAULT_DEAD_ZONE`.
    range
        Axis value for full deflection, default 1.
    index
        Which joystick, when several are plugged in (default the first).
    """

    kind = "joystick"
    unit = "axis value"

    def __init__(
        self,
        axis: int = 0,
        *,
        dead_zone: float = DEFAULT_DEAD_ZONE,
        range: float = 1.0,
        index: int = 0,
    ) -> None:
        super().__init__(range=range, dead_zone=dead_zone)
        for label, value in (("axis", axis), ("index", index)):
            if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 0:
                raise ValueError(f"joystick {label} must be a whole number >= 0, got {value!r}")
        self.axis_index = int(axis)
        self.index = int(index)
        self.axis = f"axis {self.axis_index}"
        self._joystick: Any = None
        self._instance_id: int | None = None

    def open(self, env: gym.Env) -> None:
        """Find the joystick; raise :class:`NoInputDevice` if it is not there."""
        super().open(env)
        pygame = load_pygame()
        count = joystick_count()
        if count == 0:
            raise NoInputDevice(
                "no joystick or gamepad found (pygame sees 0); plug one in or use "
                "--input mouse/keyboard"
            )
        if self.index >= count:
            raise NoInputDevice(
                f"joystick {self.index} asked for, but pygame sees {count} "
                f"(indices 0 to {count - 1})"
            )
        joystick = pygame.joystick.Joystick(self.index)
        axes = joystick.get_numaxes()
        if self.axis_index >= axes:
            raise NoInputDevice(
                f"{joystick.get_name()!r} has {axes} axes (0 to {axes - 1}); "
                f"axis {self.axis_index} is not one of them"
            )
        self._joystick = joystick
        self._instance_id = joystick.get_instance_id()
        self.name = str(joystick.get_name())

    def handle_event(self, event: Any) -> None:  # noqa: D102
        pygame = load_pygame()
        if event.type == pygame.JOYDEVICEREMOVED and event.instance_id == self._instance_id:
            self._joystick = None
            raise DeviceLost(f"the joystick {self.name!r} was unplugged")

    def _raw(self) -> float:
        if self._joystick is None:
            raise DeviceLost(f"the joystick {self.name!r} is not open")
        return float(self._joystick.get_axis(self.axis_index))

    @property
    def calibration(self) -> dict[str, Any]:  # noqa: D102
        return {**super().calibration, "joystick_index": self.index}

    def close(self) -> None:  # noqa: D102
        self._joystick = None


def make_device(
    kind: str,
    *,
    dead_zone: float | None = None,
    range: float | None = None,
    joystick_axis: int = 0,
) -> InputDevice:
    """A device by its ``--input`` name (``mouse``, ``keyboard``, ``joystick``).

    ``dead_zone`` and ``range`` None take each device's default.
    """
    if kind not in _DEVICES:
        raise ValueError(f"input must be one of {', '.join(_DEVICES)}, got {kind!r}")
    zone: dict[str, float] = {} if dead_zone is None else {"dead_zone": dead_zone}
    if kind == "mouse":
        return MouseInput(range=range, **zone)
    if kind == "keyboard":
        if range is not None:
            raise ValueError("range applies to the mouse and the joystick, not the keyboard")
        return KeyboardInput(**zone)
    return JoystickInput(joystick_axis, range=1.0 if range is None else range, **zone)


# ---------------------------------------------------------------- the action


def _forcing_std(base: Any) -> tuple[float | None, float | None]:
    """Standard deviations of the target and the disturbance forcing (None if absent)."""
    pair = getattr(base, "forcing", None)  # a tracking task has one from construction on
    if pair is None:
        return None, None

    def std(signal: Any) -> float | None:
        if signal is None:
            return None
        return math.sqrt(float(signal.variance))

    return std(pair.target), std(pair.disturbance)


def _smallest_element_gain(base: Any, omega: float) -> float:
    """``min_t |H_c(j omega, t)|`` over the episode: where the stick has to do most."""
    element = base.element
    if element.is_time_varying:
        times = np.asarray(base.times)
        times = times[np.linspace(0, len(times) - 1, min(len(times), 200)).astype(int)]
    else:
        times = np.zeros(1)
    gains = [abs(complex(element.frequency_response([omega], float(t))[0])) for t in times]
    return float(min(gains))


def default_action_scale(env: gym.Env) -> tuple[float, str]:
    """The action full stick deflection gives in ``env``, and the rule that chose it.

    Tracking tasks: a loop that crosses over near :data:`CROSSOVER_FREQUENCY` needs a
    stick of about ``sigma / |H_c(j omega_c)|`` to follow (or cancel) a forcing of
    standard deviation ``sigma`` (a disturbance at the element's input: ``sigma``
    itself, the stick cancels it directly); full deflection gives
    :data:`FORCING_HEADROOM` times the largest of these, so the peaks of a multisine
    (a crest factor of about 3) fit within the stick's travel, without making the
    stick so coarse that a small hand movement is a large action. For a time-varying
    element the smallest ``|H_c|`` of the episode counts. SI 1.5/s on
    ``vanderel-bw4`` gives 6 (the typical precision pilot's peak stick is 3.7), DI
    5/s^2 5.4 (peak 4.1). Lane keeping: 10 N m of torque or 0.5 rad of wheel angle,
    about twice the nominal cybernetic driver's peaks on the ``zhao2019`` road. Never
    more than the env's action bound (beyond it actions are clipped); other
    environments: the bound itself.
    """
    base = env.unwrapped
    bound = float(np.max(np.abs(np.asarray(env.action_space.high, dtype=np.float64))))
    if getattr(base, "steering", None) in _LANE_KEEPING_SCALE:
        value = _LANE_KEEPING_SCALE[base.steering]
        rule = (
            f"lane keeping, {base.steering} steering: {value:g} at full deflection, about "
            "twice the nominal driver's peak on the zhao2019 road"
        )
    elif hasattr(base, "element"):
        target, disturbance = _forcing_std(base)
        gain = _smallest_element_gain(base, CROSSOVER_FREQUENCY)
        needs = []
        if target is not None:
            needs.append(target / gain)
        if disturbance is not None:
            at_input = getattr(base, "disturbance_at", "output") == "input"
            needs.append(disturbance if at_input else disturbance / gain)
        if not needs or not math.isfinite(max(needs)) or max(needs) <= 0.0:
            return bound, "the env's action bound (no forcing or element gain to size it by)"
        value = FORCING_HEADROOM * max(needs)
        rule = (
            f"{FORCING_HEADROOM:g} forcing std / |H_c(j {CROSSOVER_FREQUENCY:g} rad/s)| "
            f"(|H_c| = {gain:.4g})"
        )
    else:
        return bound, "the env's action bound"
    if value > bound:
        return bound, f"the env's action bound ({rule} would be {value:.4g})"
    return float(value), rule


class DeviceAction(gym.ActionWrapper, gym.utils.RecordConstructorArgs):
    """The env acted on with a stick in ``[-1, 1]``: the action is ``scale * stick``.

    The wrapped environment's action space is ``Box(-1, 1, (1,), float64)``, so a
    person (through :func:`~manualcontrol.human.realtime.fly`), a pilot model (its
    action divided by ``scale``: :meth:`stick_for`) and an RL agent act through the same
    spaces. A stick outside ``[-1, 1]`` is clipped to it, as a stick's stops would.

    Parameters
    ----------
    env
        A tracking or lane-keeping environment (possibly wrapped), one action.
    scale
        Action at full deflection (> 0), or None for :func:`default_action_scale`.
    """

    def __init__(self, env: gym.Env, scale: float | None = None) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, scale=scale)
        gym.ActionWrapper.__init__(self, env)
        space = env.action_space
        if not isinstance(space, spaces.Box) or space.shape != (1,):
            raise TypeError(f"DeviceAction needs a one-action Box action space, got {space}")
        if scale is None:
            value, rule = default_action_scale(env)
        else:
            if isinstance(scale, bool) or not isinstance(scale, numbers.Real):
                raise TypeError(f"scale must be a number > 0, got {scale!r}")
            value, rule = float(scale), "given"
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"scale must be a finite number > 0, got {scale!r}")
        self.scale = value
        self.scale_rule = rule
        self.action_space = spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float64)

    def action(self, action: Any) -> FloatArray:
        """The env's action for the stick ``action[0]`` (clipped to ``[-1, 1]``)."""
        stick = float(np.asarray(action, dtype=np.float64).reshape(-1)[0])
        if not math.isfinite(stick):
            raise ValueError(f"stick must be finite, got {action!r}")
        stick = 1.0 if stick > 1.0 else -1.0 if stick < -1.0 else stick
        return np.array([self.scale * stick])

    def stick_for(self, action: Any) -> FloatArray:
        """The stick that gives ``action`` (array-like): ``action / scale``.

        ``scale * (action / scale)`` is ``action`` to within one rounding (exactly when
        ``scale`` is a power of two).
        """
        return np.asarray(action, dtype=np.float64) / self.scale

    def describe(self) -> Mapping[str, Any]:
        """The action scale for a recording's metadata."""
        return {"scale": self.scale, "rule": self.scale_rule}
