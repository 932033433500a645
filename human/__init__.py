"""A person at the controls: input devices, the real-time loop, experiment sessions.

:mod:`~manualcontrol.human.devices` reads a mouse, keyboard, joystick or a scripted
stick and turns it into an environment's action (:class:`DeviceAction`);
:mod:`~manualcontrol.human.realtime` flies an episode in real time (:func:`fly`) and
says whether its timing is good enough for identification; :mod:`~manualcontrol.human.cli`
is the ``manualcontrol play`` command. Each public name is imported from its module
when first used (:mod:`manualcontrol.envs._lazy`): importing the package loads neither
pygame nor the loop.
"""

from typing import TYPE_CHECKING

# importing envs first, as every subpackage does: it registers the Gymnasium ids and
# refreshes the compiled kernels' caches before any kernel here is loaded
from manualcontrol.envs._lazy import lazy_exports

if TYPE_CHECKING:  # what tools read; at run time each name is imported on first use
    from manualcontrol.human.devices import (
        DeviceAction,
        DeviceLost,
        InputDevice,
        InputDeviceError,
        JoystickInput,
        KeyboardInput,
        MouseInput,
        NoInputDevice,
        ScriptedInput,
        default_action_scale,
        make_device,
    )
    from manualcontrol.human.realtime import (
        Clock,
        Flight,
        ManualClock,
        RealClock,
        RunAborted,
        StepReport,
        Timing,
        fly,
    )

__all__ = [
    "Clock",
    "DeviceAction",
    "DeviceLost",
    "Flight",
    "InputDevice",
    "InputDeviceError",
    "JoystickInput",
    "KeyboardInput",
    "ManualClock",
    "MouseInput",
    "NoInputDevice",
    "RealClock",
    "RunAborted",
    "ScriptedInput",
    "StepReport",
    "Timing",
    "default_action_scale",
    "fly",
    "make_device",
]

__getattr__, __dir__ = lazy_exports(
    globals(),
    {
        "manualcontrol.human.devices": (
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
            "make_device",
        ),
        "manualcontrol.human.realtime": (
            "Clock",
            "Flight",
            "ManualClock",
            "RealClock",
            "RunAborted",
            "StepReport",
            "Timing",
            "fly",
        ),
    },
)
